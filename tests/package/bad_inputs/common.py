"""Helpers the bad-input tests share: an arm entity, an arena, a pendulum."""

import functools

import mujoco

import mjx_composer as composer
from tests import conftest


class Arm(conftest.SpecEntity):
  """A one-joint arm; `edit(spec)` may add a faulty element."""

  def _build(self, edit=None, name='arm'):
    spec = self._new_spec(name)
    body = spec.worldbody.add_body(name='link')
    body.add_joint(name='shoulder', type=mujoco.mjtJoint.mjJNT_HINGE)
    body.add_geom(name='geom', size=[0.1, 0, 0])
    body.add_site(name='tip')
    spec.add_actuator(
        name='motor', target='shoulder', trntype=mujoco.mjtTrn.mjTRN_JOINT
    )
    if edit is not None:
      edit(spec)


def typo_actuator(spec):
  spec.actuators[0].target = 'shoulderr'


def typo_sensor(spec):
  spec.add_sensor(
      name='touch',
      type=mujoco.mjtSensor.mjSENS_TOUCH,
      objtype=mujoco.mjtObj.mjOBJ_SITE,
      objname='tipp',
  )


def in_arena(arm):
  arena = composer.Arena()
  arena.attach(arm)
  return arena


@functools.lru_cache(maxsize=None)
def pendulum_environment():
  arena = composer.Arena()
  arena.attach(conftest.Pendulum())
  return composer.Environment(composer.NullTask(arena), time_limit=0.1)
