"""ToolCenterPointInitializer: inverse kinematics with composer's rejections.

Each outcome is checked against MuJoCo on the host: the solution's joint
angles are copied into an `MjData`, `mj_forward` runs, and its contacts show
what was (or was not) touched.
"""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer import initializers
from mjx_composer.suite.entities import props
from mjx_composer.suite.entities import robots
from mjx_composer.suite.entities.manipulators import base as manipulators
from mjx_composer.variation import deterministic
from mjx_composer.variation import distributions

_FREE = [0.3, 0.0, 0.4]  # in reach, clear of everything
_IN_OBSTACLE = [0.0, 0.4, 0.3]  # the fixed box's centre
_IN_BALL = [-0.4, 0.0, 0.08]  # the free ball's centre
_BELOW_FLOOR = [0.3, 0.0, -0.03]
_TARGETS = (_FREE, _IN_OBSTACLE, _IN_BALL, _BELOW_FLOOR)
_LOW, _HIGH = np.array([0.2, -0.2, 0.3]), np.array([0.4, 0.2, 0.5])


class Gripper(manipulators.RobotHand):
  """Two box fingers at the arm's hand, for the pair rules."""

  def _build(self):
    spec = mujoco.MjSpec()
    spec.modelname = 'gripper'
    palm = spec.worldbody.add_body(name='palm')
    for side in (-1, 1):
      palm.add_geom(
          name=f'finger_{side + 1}',
          type=mujoco.mjtGeom.mjGEOM_BOX,
          size=[0.01, 0.01, 0.03],
          pos=[0.02 * side, 0, 0.03],
      )
    self._tcp = palm.add_site(name='tcp', pos=[0, 0, 0.06])
    self._spec = spec

  @property
  def mjcf_model(self):
    return self._spec

  @property
  def actuators(self):
    return ()

  @property
  def tool_center_point(self):
    return self._tcp

  def set_grasp(self, physics, close_factors):
    return physics


class TcpTask(composer.Task):
  """The arm, a fixed box, a free ball; the wrist placed every episode."""

  def __init__(self, with_gripper=False):
    self.arena = composer.Arena()
    self.arena.mjcf_model.worldbody.add_geom(
        name='floor', type=mujoco.mjtGeom.mjGEOM_PLANE, size=[1, 1, 0.1]
    )
    self.arm = robots.Arm()
    self.arena.attach(self.arm)
    self.gripper = None
    if with_gripper:
      self.gripper = Gripper()
      self.arm.attach(self.gripper, attach_site=self.arm.hand)
    self.obstacle = props.Box(half_lengths=(0.06,) * 3, name='obstacle')
    self.arena.attach(self.obstacle).pos = [0.0, 0.4, 0.3]
    self.ball = props.Sphere(radius=0.08, name='ball')
    self.arena.add_free_entity(self.ball).pos = [-0.4, 0.0, 0.08]
    self.initializer = initializers.ToolCenterPointInitializer(
        self.gripper,
        self.arm,
        position=distributions.Uniform(_LOW, _HIGH),
        quaternion=None,
    )

  @property
  def root_entity(self):
    return self.arena

  def initialize_episode(self, physics, key):
    return self.initializer(physics, key)

  def get_reward(self, physics):
    return jnp.zeros(())


@pytest.fixture(scope='module')
def env():
  return composer.Environment(TcpTask())


def _host(env, qpos):
  model = env.mj_model
  data = mujoco.MjData(model)
  data.qpos[:] = qpos
  mujoco.mj_forward(model, data)
  return model, data


def _touching(model, data, prefix_a, prefix_b):
  """Whether a penetrating contact joins geoms named with these prefixes."""
  for contact in data.contact[: data.ncon]:
    names = [
        mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g)
        for g in (contact.geom1, contact.geom2)
    ]
    for a, b in (names, names[::-1]):
      if (
          a.startswith(prefix_a)
          and b.startswith(prefix_b)
          and contact.dist <= 0
      ):
        return True
  return False


def test_reset_places_the_wrist_in_every_world(env):
  states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), 4))
  assert not np.any(np.asarray(states.metrics['init_failed']))
  hands = set()
  for qpos in np.asarray(states.data.qpos):
    model, data = _host(env, qpos)
    hand = data.site_xpos[model.site('arm/hand').id]
    assert np.all(hand >= _LOW - 2e-5) and np.all(hand <= _HIGH + 2e-5)
    hands.add(tuple(np.round(hand, 4)))
  assert len(hands) == 4  # each world drew its own target


def _place(env, ignore_collisions):
  """Places the wrist at each of `_TARGETS` from one reset state."""
  physics = env.physics(jax.jit(env.reset)(jax.random.key(1)))
  arm = env.task.arm

  def one(target, key):
    placed = initializers.ToolCenterPointInitializer(
        None,
        arm,
        position=target,
        quaternion=None,
        ignore_collisions=ignore_collisions,
    )(physics, key)
    return placed.data.qpos, placed.initialization_failed

  qpos, failed = jax.jit(jax.vmap(one))(
      jnp.asarray(_TARGETS), jax.random.split(jax.random.key(2), len(_TARGETS))
  )
  return np.asarray(physics.data.qpos), np.asarray(qpos), np.asarray(failed)


def test_collisions_reject_a_solution_as_composer_counts_them(env):
  initial, qpos, failed = _place(env, ignore_collisions=False)
  _, ignored_qpos, ignored_failed = _place(env, ignore_collisions=True)
  # With collisions ignored every target is reached.
  assert not ignored_failed.any()
  for solution, target in zip(ignored_qpos, _TARGETS):
    model, data = _host(env, solution)
    np.testing.assert_allclose(
        data.site_xpos[model.site('arm/hand').id], target, atol=2e-5
    )
  free, obstacle, ball, floor = range(4)
  # Clear of everything: kept.
  assert not failed[free]
  np.testing.assert_array_equal(qpos[free], ignored_qpos[free])
  # Inside the fixed box or below the floor: the solution touches a body
  # without a freejoint, so every sample is rejected and the arm keeps its
  # pose from before the call.
  for case, other in ((obstacle, 'obstacle/'), (floor, 'floor')):
    model, data = _host(env, ignored_qpos[case])
    assert _touching(model, data, 'arm/', other)
    assert failed[case]
    np.testing.assert_array_equal(qpos[case], initial)
  # Inside the free ball: the arm touches it, and the ball touches the floor
  # (not the robot): neither counts.
  model, data = _host(env, qpos[ball])
  assert not failed[ball]
  assert _touching(model, data, 'arm/', 'ball/')
  assert _touching(model, data, 'ball/', 'floor')


def test_relevant_pairs_follow_composers_rule():
  task = TcpTask(with_gripper=True)
  env = composer.Environment(task)
  physics = env.physics(jax.jit(env.reset)(jax.random.key(0)))
  assert task.initializer.tool_center_point is task.gripper.tool_center_point
  model = env.mj_model
  names = lambda g: mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g)
  pairs = {
      tuple(sorted((names(a), names(b))))
      for _, group in task.initializer.pair_groups(physics)
      for a, b in group
  }
  fingers = ('arm/gripper/finger_0', 'arm/gripper/finger_2')
  assert tuple(sorted(fingers)) not in pairs  # hand-hand
  assert not any('ball/' in a or 'ball/' in b for a, b in pairs)  # free body
  for finger in fingers:  # robot against fixed bodies
    assert tuple(sorted((finger, 'floor'))) in pairs
    assert tuple(sorted((finger, 'obstacle/geom'))) in pairs
  assert ('arm/base', 'arm/gripper/finger_0') in pairs  # hand-arm
  assert ('arm/base', 'arm/lower') in pairs  # arm-arm
  assert ('arm/lower', 'floor') in pairs


def test_bad_arguments_are_refused():
  arm = robots.Arm()
  with pytest.raises(ValueError, match='at least 1'):
    initializers.ToolCenterPointInitializer(
        None, arm, position=np.zeros(3), max_ik_attempts=0
    )
  with pytest.raises(ValueError, match='stateful variation'):
    initializers.ToolCenterPointInitializer(
        None, arm, position=deterministic.Sequence([np.zeros(3)])
    )
