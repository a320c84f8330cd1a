"""The bundled reach task: per-episode domain randomization, per world."""

import copy

import jax
import mujoco
import numpy as np
import pytest

from mjx_composer import environment
from mjx_composer.suite.tasks import reach


@pytest.fixture(scope='module')
def reach_env():
  return environment.Environment(reach.Reach(), time_limit=0.1)


_WORLDS = 8


@pytest.fixture(scope='module')
def reset_states(reach_env):
  return jax.jit(jax.vmap(reach_env.reset))(
      jax.random.split(jax.random.key(0), _WORLDS)
  )


def test_every_world_draws_its_own_colours_masses_sizes_friction_and_gears(
    reach_env, reset_states
):
  worlds = _WORLDS
  states = reset_states
  model = reach_env.mj_model
  fields = states.model_fields
  ball = model.geom('ball/geom').id
  ground = model.geom('ground').id
  links = [model.body(name).id for name in ('arm/upper', 'arm/lower')]
  gears = fields['actuator_gear'][:, :, 0]
  varied = {
      'ball colour': fields['geom_rgba'][:, ball, :3],
      'ball radius': fields['geom_size'][:, ball, 0],
      'ball friction': fields['geom_friction'][:, ball, 0],
      'floor friction': fields['geom_friction'][:, ground, 0],
      'link masses': fields['body_mass'][:, links],
      'motor gears': gears,
  }
  for name, values in varied.items():
    values = np.asarray(values).reshape(worlds, -1)
    assert len(np.unique(values[:, 0])) == worlds, name
  # Multiplicative ranges around the compiled values.
  np.testing.assert_array_less(
      np.abs(gears / model.actuator_gear[:, 0] - 1), 0.2 + 1e-6
  )
  radius = np.asarray(fields['geom_size'][:, ball, 0])
  assert np.all(
      (radius > 0.7 * model.geom_size[ball, 0] - 1e-6)
      & (radius < 1.3 * model.geom_size[ball, 0] + 1e-6)
  )
  # The ball is placed resting on the floor at its own (varied) radius.
  ball_body = model.body('ball/').id
  z = np.asarray(states.data.xpos[:, ball_body, 2])
  np.testing.assert_allclose(z, radius, rtol=1e-5)
  # Masses follow the varied densities through the compiler's geom inertia.
  upper_mass = np.asarray(fields['body_mass'][:, links[0]])
  assert np.all(
      np.abs(upper_mass / model.body_mass[links[0]] - 1) <= 0.3 + 1e-5
  )


def test_without_randomization_nothing_model_related_is_per_world():
  env = environment.Environment(reach.Reach(randomize=False), time_limit=0.1)
  state = jax.eval_shape(env.reset, jax.random.key(0))
  assert not state.model_fields


def test_reward_matches_mujocos_hand_position_and_the_documented_formula(
    reach_env, reset_states
):
  """`1 - tanh(|hand - target| / 0.3)`, with the hand site's position from
  MuJoCo's C `mj_forward` on the same state and the world's own model."""
  task = reach_env.task
  joints = list(task.arm.joints)
  model = copy.deepcopy(reach_env.mj_model)
  hand = model.site('arm/hand').id
  qposadr = [
      model.jnt_qposadr[model.joint(f'arm/{name}').id]
      for name in ('yaw', 'shoulder', 'elbow')
  ]
  rng = np.random.default_rng(0)
  # A random arm pose per world, inside the joint ranges (the yaw is free),
  # and a target at a random direction from where MuJoCo puts the hand, at
  # distances spread over the reward's range (0 to 0.7 m).
  arm_qpos = rng.uniform(
      [-np.pi, -1.6, -2.5], [np.pi, 1.6, 2.5], (_WORLDS, 3)
  ).astype(np.float32)
  directions = rng.normal(size=(_WORLDS, 3))
  directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
  offsets = np.linspace(0.0, 0.7, _WORLDS)[:, None] * directions
  qpos = np.array(reset_states.data.qpos)
  qpos[:, qposadr] = arm_qpos
  targets = []
  expected = []
  for world in range(_WORLDS):
    for name, values in reset_states.model_fields.items():
      field = getattr(model, name, None)
      if isinstance(field, np.ndarray) and field.shape == values.shape[1:]:
        field[:] = values[world]
    data = mujoco.MjData(model)
    data.qpos[:] = qpos[world]
    mujoco.mj_forward(model, data)
    target = (data.site_xpos[hand] + offsets[world]).astype(np.float32)
    distance = np.linalg.norm(data.site_xpos[hand] - target)
    targets.append(target)
    expected.append(1.0 - np.tanh(distance / 0.3))

  @jax.jit
  def posed_rewards(states, arm_qpos, targets):
    def one(state, arm_qpos, target):
      physics = reach_env.physics(state).bind(joints).set(qpos=arm_qpos)
      physics = physics.kinematics().update_task_state(target=target)
      return task.get_reward(physics)

    return jax.vmap(one)(states, arm_qpos, targets)

  reward = np.asarray(posed_rewards(reset_states, arm_qpos, np.array(targets)))
  expected = np.array(expected)
  # float32 kinematics and tanh against MuJoCo's float64: 1.6e-7 at most
  # (measured over these states); 1e-6 leaves a factor of 6. A wrong site,
  # target or scale moves the reward by 1e-2 or more.
  np.testing.assert_allclose(reward, expected, rtol=0, atol=1e-6)
  # The states spread the reward over its range, from 1 (hand on target).
  assert expected.max() > 0.999 and expected.min() < 0.05, expected
