"""Simple free props built in code with MjSpec."""

import mujoco

from mjx_composer import define
from mjx_composer import entity
from mjx_composer.observation import observable


class BallObservables(observable.Observables,
                      observable.FreePropObservableMixin):
  """Pose and velocity of a ball, from frame sensors."""

  @define.observable
  def position(self):
    return observable.MJCFFeature('sensordata', self._entity.sensors[0])

  @define.observable
  def orientation(self):
    return observable.MJCFFeature('sensordata', self._entity.sensors[1])

  @define.observable
  def linear_velocity(self):
    return observable.MJCFFeature('sensordata', self._entity.sensors[2])

  @define.observable
  def angular_velocity(self):
    return observable.MJCFFeature('sensordata', self._entity.sensors[3])


class Ball(entity.Entity):
  """A sphere with frame sensors; attach it with `Arena.add_free_entity`.

  Args:
    radius: metres. mass: kilograms. rgba: colour. name: entity name.
  """

  def _build(self, radius=0.05, mass=0.2, rgba=(0.2, 0.6, 0.9, 1.),
             name='ball'):
    spec = mujoco.MjSpec()
    spec.modelname = name
    body = spec.worldbody.add_body(name='body')
    self._geom = body.add_geom(name='geom', type=mujoco.mjtGeom.mjGEOM_SPHERE,
                               size=[radius, 0, 0], mass=mass, rgba=rgba)
    site = body.add_site(name='center', size=[0.01, 0, 0])
    obj = mujoco.mjtObj.mjOBJ_SITE
    self._sensors = tuple(
        spec.add_sensor(name=kind, type=sensor_type, objtype=obj,
                        objname='center')
        for kind, sensor_type in (
            ('pos', mujoco.mjtSensor.mjSENS_FRAMEPOS),
            ('quat', mujoco.mjtSensor.mjSENS_FRAMEQUAT),
            ('linvel', mujoco.mjtSensor.mjSENS_FRAMELINVEL),
            ('angvel', mujoco.mjtSensor.mjSENS_FRAMEANGVEL)))
    del site
    self._spec = spec

  def _build_observables(self):
    return BallObservables(self)

  @property
  def mjcf_model(self):
    return self._spec

  @property
  def geom(self):
    return self._geom

  @property
  def sensors(self):
    return self._sensors
