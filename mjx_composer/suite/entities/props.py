"""Props built in code with MjSpec: primitives with frame sensors, and `Ball`.

`Primitive(geom_type, size, ...)` is dm_control's `entities.props.Primitive`:
one geom in the prop's worldbody (so it sits in the attachment frame, which
`Arena.add_free_entity` makes free) and `framepos`, `framequat`,
`framelinvel` and `frameangvel` sensors on that geom, exposed through
`FrameSensorObservables` (a `FreePropObservableMixin`; `Ball`'s too). `Sphere`, `Box`,
`Capsule`, `Cylinder` and `Ellipsoid` are its shapes with named sizes, as in
`dm_control.manipulation.props.primitive`.

    box = props.Box(half_lengths=(0.03, 0.03, 0.03), mass=0.1, name='box_0')
    arena.add_free_entity(box)
    box.observables.position.enabled = True     # the geom's world position
"""

import mujoco
import numpy as np

from mjx_composer import define
from mjx_composer import entity
from mjx_composer.observation import observable

_GEOM_TYPES = {
    'sphere': mujoco.mjtGeom.mjGEOM_SPHERE,
    'capsule': mujoco.mjtGeom.mjGEOM_CAPSULE,
    'ellipsoid': mujoco.mjtGeom.mjGEOM_ELLIPSOID,
    'cylinder': mujoco.mjtGeom.mjGEOM_CYLINDER,
    'box': mujoco.mjtGeom.mjGEOM_BOX,
}
# How many size numbers each shape takes (MuJoCo's geom `size`).
_SIZE_LENGTHS = {
    'sphere': 1,
    'capsule': 2,
    'cylinder': 2,
    'ellipsoid': 3,
    'box': 3,
}


def _geom_type_name(geom_type) -> str:
  if isinstance(geom_type, str):
    name = geom_type.lower()
  else:
    names = {v: k for k, v in _GEOM_TYPES.items()}
    name = names.get(geom_type)
  if name not in _GEOM_TYPES:
    raise ValueError(
        f'Unsupported primitive geom type {geom_type!r}; choose '
        f'from {sorted(_GEOM_TYPES)}.'
    )
  return name


# A free prop's pose and velocity sensors, in `FrameSensorObservables` order.
_FRAME_SENSORS = (
    mujoco.mjtSensor.mjSENS_FRAMEPOS,
    mujoco.mjtSensor.mjSENS_FRAMEQUAT,
    mujoco.mjtSensor.mjSENS_FRAMELINVEL,
    mujoco.mjtSensor.mjSENS_FRAMEANGVEL,
)


def _add_frame_sensors(spec, objtype, objname, names):
  """The four frame sensors of one object, world frame, named `names`."""
  return tuple(
      spec.add_sensor(name=name, type=kind, objtype=objtype, objname=objname)
      for name, kind in zip(names, _FRAME_SENSORS, strict=True)
  )


class FrameSensorObservables(
    observable.Observables, observable.FreePropObservableMixin
):
  """A prop's pose and velocity, from its four frame sensors.

  The entity's `frame_sensors`: `framepos`, `framequat`, `framelinvel` and
  `frameangvel` of one object, in the world frame.
  """

  @define.observable
  def position(self):
    return observable.MJCFFeature('sensordata', self._entity.frame_sensors[0])

  @define.observable
  def orientation(self):
    return observable.MJCFFeature('sensordata', self._entity.frame_sensors[1])

  @define.observable
  def linear_velocity(self):
    return observable.MJCFFeature('sensordata', self._entity.frame_sensors[2])

  @define.observable
  def angular_velocity(self):
    return observable.MJCFFeature('sensordata', self._entity.frame_sensors[3])


# Composer's names of the two props' observables, one class now.
PrimitiveObservables = FrameSensorObservables
BallObservables = FrameSensorObservables


class _FrameSensedProp(entity.Entity):
  """An entity of one spec, one geom and four frame sensors of one object.

  Subclasses set `_spec`, `_geom` and `_sensors` (from `_add_frame_sensors`)
  in `_build`.
  """

  def _build_observables(self):
    return FrameSensorObservables(self)

  @property
  def mjcf_model(self):
    return self._spec

  @property
  def geom(self):
    """The prop's geom (e.g. to bind its friction or colour)."""
    return self._geom

  @property
  def frame_sensors(self):
    """`framepos`, `framequat`, `framelinvel` and `frameangvel`, world
    frame."""
    return self._sensors


class Primitive(_FrameSensedProp):
  """A prop made of one primitive geom, with position and velocity sensors.

  Args:
    geom_type: 'sphere', 'box', 'capsule', 'cylinder' or 'ellipsoid' (or the
      `mujoco.mjtGeom` value).
    size: the geom's size, up to 3 numbers by type: sphere `[radius]`, box
      `[x, y, z half-lengths]`, capsule and cylinder `[radius, half-length]`,
      ellipsoid `[x, y, z radii]`.
    name: the prop's name (the prefix of its compiled names).
    **geom_kwargs: further geom attributes of `MjsGeom` (e.g. `mass`,
      `rgba`, `friction`, `contype`).
  """

  def _build(self, geom_type, size, name=None, **geom_kwargs):
    type_name = _geom_type_name(geom_type)
    size = np.reshape(np.asarray(size, float), -1)
    if size.size != _SIZE_LENGTHS[type_name]:
      raise ValueError(
          f'A {type_name} takes {_SIZE_LENGTHS[type_name]} size '
          f'numbers, got {size.tolist()}.'
      )
    # composer's manipulation props take `mass=None` to mean the default.
    geom_kwargs = {k: v for k, v in geom_kwargs.items() if v is not None}
    spec = mujoco.MjSpec()
    spec.modelname = name or type_name
    padded = np.zeros(3)
    padded[: size.size] = size
    self._geom = spec.worldbody.add_geom(
        name='geom', type=_GEOM_TYPES[type_name], size=padded, **geom_kwargs
    )
    self._sensors = _add_frame_sensors(
        spec,
        mujoco.mjtObj.mjOBJ_GEOM,
        'geom',
        ('position', 'orientation', 'linear_velocity', 'angular_velocity'),
    )
    self._spec = spec

  @property
  def position(self):
    """The `framepos` sensor of the geom (world frame)."""
    return self._sensors[0]

  @property
  def orientation(self):
    """The `framequat` sensor of the geom (world frame, w x y z)."""
    return self._sensors[1]

  @property
  def linear_velocity(self):
    """The `framelinvel` sensor of the geom (world frame)."""
    return self._sensors[2]

  @property
  def angular_velocity(self):
    """The `frameangvel` sensor of the geom (world frame)."""
    return self._sensors[3]


class Sphere(Primitive):
  """A sphere prop. Args: radius, then as `Primitive` (mass, rgba, ...)."""

  def _build(self, radius=0.05, name='sphere', **geom_kwargs):
    super()._build('sphere', [radius], name=name, **geom_kwargs)


class Box(Primitive):
  """A box prop. Args: half_lengths (x, y, z), then as `Primitive`."""

  def _build(self, half_lengths=(0.05, 0.1, 0.15), name='box', **geom_kwargs):
    super()._build('box', half_lengths, name=name, **geom_kwargs)


class Capsule(Primitive):
  """A capsule prop along z. Args: radius, half_length, then as `Primitive`."""

  def _build(self, radius=0.05, half_length=0.1, name='capsule', **geom_kwargs):
    super()._build('capsule', [radius, half_length], name=name, **geom_kwargs)


class Cylinder(Primitive):
  """A cylinder prop along z. Args: radius, half_length, then as `Primitive`."""

  def _build(
      self, radius=0.05, half_length=0.1, name='cylinder', **geom_kwargs
  ):
    super()._build('cylinder', [radius, half_length], name=name, **geom_kwargs)


class Ellipsoid(Primitive):
  """An ellipsoid prop. Args: radii (x, y, z), then as `Primitive`."""

  def _build(self, radii=(0.05, 0.1, 0.15), name='ellipsoid', **geom_kwargs):
    super()._build('ellipsoid', radii, name=name, **geom_kwargs)


class Ball(_FrameSensedProp):
  """A sphere with frame sensors; attach it with `Arena.add_free_entity`.

  Args:
    radius: metres. mass: kilograms. rgba: colour. name: entity name.
  """

  def _build(
      self, radius=0.05, mass=0.2, rgba=(0.2, 0.6, 0.9, 1.0), name='ball'
  ):
    spec = mujoco.MjSpec()
    spec.modelname = name
    body = spec.worldbody.add_body(name='body')
    self._geom = body.add_geom(
        name='geom',
        type=mujoco.mjtGeom.mjGEOM_SPHERE,
        size=[radius, 0, 0],
        mass=mass,
        rgba=rgba,
    )
    body.add_site(name='center', size=[0.01, 0, 0])
    self._sensors = _add_frame_sensors(
        spec,
        mujoco.mjtObj.mjOBJ_SITE,
        'center',
        ('pos', 'quat', 'linvel', 'angvel'),
    )
    self._spec = spec

  @property
  def sensors(self):
    """`frame_sensors` (the name it had first)."""
    return self._sensors
