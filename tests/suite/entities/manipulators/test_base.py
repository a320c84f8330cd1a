"""RobotArm's joint sampling and `set_site_to_xpos` (dm_control's rules)."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.suite.entities.manipulators import base as manipulators
from mjx_composer.suite.tasks import reach


@pytest.fixture(scope='module')
def arm_world():
  task = reach.Reach(randomize=False)
  env = composer.Environment(task)
  return env, task.arm, env.physics(jax.jit(env.reset)(jax.random.key(0)))


def test_randomized_joints_stay_in_their_sampling_bounds(arm_world):
  env, arm, physics = arm_world
  qpos = jax.jit(
      jax.vmap(lambda k: arm.randomize_arm_joints(physics, k).data.qpos)
  )(jax.random.split(jax.random.key(1), 256))
  qpos = np.asarray(qpos)
  yaw, shoulder, elbow = qpos[:, 0], qpos[:, 1], qpos[:, 2]
  # The yaw hinge is unlimited: [0, 2 pi), as dm_control samples it.
  assert yaw.min() >= 0 and yaw.max() < 2 * np.pi and np.ptp(yaw) > 5.0
  low, high = env.mj_model.jnt_range[1:3].T
  assert np.all((shoulder >= low[0]) & (shoulder <= high[0]))
  assert np.all((elbow >= low[1]) & (elbow <= high[1]))
  # The other joints (the ball's) are untouched.
  others = np.asarray(physics.data.qpos[3:])
  np.testing.assert_array_equal(
      qpos[:, 3:], np.broadcast_to(others, qpos[:, 3:].shape)
  )


def test_set_site_to_xpos_reaches_targets_within_the_joint_bounds(arm_world):
  env, arm, physics = arm_world
  targets = jnp.asarray(
      [[0.3, 0.2, 0.4], [-0.3, -0.3, 0.3], [0.1, -0.4, 0.2], [0.0, 0.5, 0.5]]
  )
  keys = jax.random.split(jax.random.key(2), len(targets))

  @jax.jit
  @jax.vmap
  def place(target, key):
    placed, success = arm.set_site_to_xpos(physics, key, arm.hand, target)
    return placed.data.qpos, success

  qpos, success = place(targets, keys)
  assert np.all(np.asarray(success))
  model = env.mj_model
  data = mujoco.MjData(model)
  low, high = model.jnt_range[1:3].T
  for q, target in zip(np.asarray(qpos), np.asarray(targets)):
    assert 0 <= q[0] < 2 * np.pi  # whole turns into the yaw's bounds
    assert np.all((q[1:3] >= low) & (q[1:3] <= high))
    data.qpos[:] = q
    mujoco.mj_kinematics(model, data)
    np.testing.assert_allclose(
        data.site_xpos[model.site('arm/hand').id], target, atol=2e-5
    )
  # An unreachable target fails after every attempt.
  _, unreachable = place(jnp.asarray([[2.0, 0.0, 0.3]]), keys[:1])
  assert not np.asarray(unreachable)[0]


class SlideArm(manipulators.RobotArm):
  """One unlimited slide joint: it cannot be sampled."""

  def _build(self):
    spec = mujoco.MjSpec()
    spec.modelname = 'slide_arm'
    body = spec.worldbody.add_body(name='carriage')
    self._joint = body.add_joint(
        name='rail', type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[1, 0, 0]
    )
    body.add_geom(size=[0.05, 0, 0])
    self._site = body.add_site(name='tip')
    self._spec = spec

  @property
  def mjcf_model(self):
    return self._spec

  @property
  def joints(self):
    return (self._joint,)

  @property
  def wrist_site(self):
    return self._site

  @property
  def actuators(self):
    return ()


class SlideTask(composer.Task):

  def __init__(self):
    self.arena = composer.Arena()
    self.arm = SlideArm()
    self.arena.attach(self.arm)

  @property
  def root_entity(self):
    return self.arena

  def get_reward(self, physics):
    return jnp.zeros(())


def test_an_unlimited_slide_joint_is_refused():
  task = SlideTask()
  env = composer.Environment(task)
  physics = env.physics(jax.jit(env.reset)(jax.random.key(0)))
  with pytest.raises(
      ValueError, match="non-hinge joint needs limits.*'slide_arm/rail'"
  ):
    task.arm.randomize_arm_joints(physics, jax.random.key(0))
