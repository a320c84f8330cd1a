"""The walk task: Playground's HumanoidWalk reward, on composer's features.

One environment (2 worlds, a push every 2 steps, episodes of 6 steps) is
compiled once for the module; the tests read one short trajectory of it.
"""

from dm_control.utils import rewards
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_composer import environment
from mjx_composer.runtime.state import StepType
from mjx_composer.suite.tasks import registry
from mjx_composer.suite.tasks import walk

_WORLDS = 2
_STEPS = 6  # The time limit, in control steps.
_PUSH_INTERVAL = 2


@pytest.fixture(scope='module')
def run():
  """(env, [state after reset, after step 1, ..., after step 6], actions)."""
  task = walk.Walk(push_interval=_PUSH_INTERVAL)
  env = environment.Environment(
      task,
      time_limit=_STEPS * task.control_timestep,
      options=environment.ExecutionOptions(auto_reset='same_step'),
  )
  states = [
      jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), _WORLDS))
  ]
  step = jax.jit(jax.vmap(env.step))
  actions = np.random.default_rng(0).uniform(-1, 1, (_STEPS, _WORLDS, 21))
  for action in actions:
    states.append(step(states[-1], jnp.asarray(action, jnp.float32)))
  return env, step, jax.device_get(states), actions


def _slices(env, group):
  """Where each observable sits in a flattened group's vector."""
  observables = env.task.observables
  physics = env.initial_physics()
  slices, offset = {}, 0
  for key in env.task.observation_groups()[group].keys:
    obs = observables[key]
    shape = jax.eval_shape(obs.raw_observation_callable(physics)).shape
    size = (obs.buffer_size or 1) * int(np.prod(shape))
    slices[key] = slice(offset, offset + size)
    offset += size
  assert offset == env.observation_spec()[group].shape[0]
  return slices


# -- the reference: dm_control's own `rewards.tolerance` ----------------------


def _playground_reward(model, data, world):
  head = model.body('humanoid/head').id
  torso = model.body('humanoid/torso').id
  sensor = model.sensor('humanoid/torso_subtreelinvel')
  com_velocity = data.sensordata[world, sensor.adr[0] : sensor.adr[0] + 3]
  standing = rewards.tolerance(
      data.xpos[world, head, 2],
      bounds=(1.4, np.inf),
      margin=1.4 / 4,
      sigmoid='gaussian',
      value_at_margin=0.1,
  )
  upright = rewards.tolerance(
      data.xmat[world, torso].reshape(3, 3)[2, 2],
      bounds=(0.9, np.inf),
      margin=1.9,
      sigmoid='linear',
      value_at_margin=0,
  )
  control = rewards.tolerance(
      data.ctrl[world],
      bounds=(0, 0),
      margin=1,
      sigmoid='quadratic',
      value_at_margin=0,
  ).mean()
  speed = np.linalg.norm(com_velocity[:2])
  move = rewards.tolerance(
      speed,
      bounds=(1.0, np.inf),
      margin=1.0,
      sigmoid='linear',
      value_at_margin=0,
  )
  return standing * upright * (4 + control) / 5 * (5 * move + 1) / 6


def test_reward_is_playgrounds(run):
  env, _, states, actions = run
  values = []
  for i, state in enumerate(states[1:_STEPS], start=1):
    # The control is the action, as written (not clipped).
    np.testing.assert_allclose(state.data.ctrl, actions[i - 1], rtol=1e-6)
    for world in range(_WORLDS):
      want = _playground_reward(env.mj_model, state.data, world)
      assert state.reward[world] == pytest.approx(want, rel=1e-5, abs=1e-6)
      values.append(want)
  assert 0 < min(values) and max(values) < 1  # Not a trivial reward.


def test_time_limit_truncates(run):
  _, _, states, _ = run
  for state in states[1:_STEPS]:
    assert np.all(state.step_type == StepType.MID)
    assert not np.any(state.terminated)  # Nobody fell in 0.15 s.
  last = states[_STEPS]
  assert np.all(last.truncated) and not np.any(last.terminated)
  assert np.all(last.discount == 1.0)
  np.testing.assert_array_equal(last.metrics['episode_length'], _STEPS)
  # Same-step auto-reset: the next episode has started.
  np.testing.assert_array_equal(last.task_state['step'], 0)


def test_a_fall_terminates(run):
  env, step, states, actions = run
  state = states[2]
  qpos = np.array(state.data.qpos)
  qpos[:, 2] = 0.15  # The torso on the floor, lying on its back.
  qpos[:, 3:7] = [np.sqrt(0.5), 0.0, np.sqrt(0.5), 0.0]
  fallen = state.replace(data=state.data.replace(qpos=jnp.asarray(qpos)))
  after = jax.device_get(step(fallen, jnp.asarray(actions[2], jnp.float32)))
  assert np.all(after.terminated) and not np.any(after.truncated)
  assert np.all(after.step_type == StepType.LAST)
  np.testing.assert_array_equal(after.discount, 0.0)


def test_pushes_come_every_k_steps(run):
  env, _, states, actions = run
  pushes = np.stack([s.task_state['push'] for s in states[1:_STEPS]])
  # Step i applies a push when i - 1 steps are done and divisible by k.
  for i in range(1, _STEPS):
    pushed = (i - 1) > 0 and (i - 1) % _PUSH_INTERVAL == 0
    size = np.linalg.norm(pushes[i - 1], axis=-1)
    if pushed:
      assert np.all((size >= 0.1 - 1e-6) & (size <= 0.5 + 1e-6)), (i, size)
      np.testing.assert_array_equal(pushes[i - 1][:, 2], 0.0)
    else:
      np.testing.assert_array_equal(size, 0.0)
  # The push is a change of the torso's velocity, in the step's first hook.
  task = env.task

  @jax.jit
  @jax.vmap
  def before_step(state, action, key):
    physics = env.physics(state)
    after = task.before_step(physics, action, key)
    return physics.data.qvel, after.data.qvel, after.task_state['push']

  keys = jax.random.split(jax.random.key(3), _WORLDS)
  for index, due in ((1, False), (2, True)):  # 1 or 2 steps done.
    before, after, push = jax.device_get(
        before_step(states[index], jnp.asarray(actions[index]), keys)
    )
    np.testing.assert_allclose(after[:, :3] - before[:, :3], push, atol=1e-6)
    np.testing.assert_array_equal(after[:, 3:], before[:, 3:])
    assert np.all(np.linalg.norm(push, axis=-1) > 0) == due


def test_policy_sees_noisy_late_history_critic_sees_clean_current(run):
  env, _, states, _ = run
  policy, critic = _slices(env, 'policy'), _slices(env, 'critic')
  joints = lambda s: s.data.qpos[:, 7:]
  head = env.mj_model.body('humanoid/head').id
  k = 4
  state = states[k]
  clean = state.observation['critic']
  noisy = state.observation['policy']
  np.testing.assert_allclose(
      clean[:, critic['privileged_joint_positions']], joints(state), atol=1e-6
  )
  np.testing.assert_allclose(
      clean[:, critic['privileged_head_height']],
      state.data.xpos[:, head, 2:],
      atol=1e-6,
  )
  # The policy's joint angles: control steps k-2 and k-1 (one sample of
  # latency), oldest first, with noise of at most 0.03 rad.
  seen = noisy[:, policy['humanoid/joint_positions']].reshape(_WORLDS, 2, 21)
  for slot, earlier in enumerate((states[k - 2], states[k - 1])):
    error = np.abs(seen[:, slot] - joints(earlier))
    assert np.all(error <= 0.03 + 1e-5) and np.any(error > 1e-3)
  # The head height has latency but no noise.
  np.testing.assert_allclose(
      noisy[:, policy['humanoid/head_height']],
      states[k - 1].data.xpos[:, head, 2:],
      atol=1e-6,
  )


def test_every_world_and_episode_is_randomized(run):
  env, _, states, _ = run
  model, first = env.mj_model, states[0]
  fields = first.model_fields
  ground = model.geom('ground').id
  friction = fields['geom_friction'][:, ground, 0]
  assert np.all((friction >= 0.7 - 1e-6) & (friction <= 1.3 + 1e-6))
  gear_ratio = fields['actuator_gear'][:, :, 0] / model.actuator_gear[:, 0]
  assert np.all(np.abs(gear_ratio - 1) <= 0.1 + 1e-5)
  torso = model.body('humanoid/torso').id
  mass_ratio = fields['body_mass'][:, torso] / model.body_mass[torso]
  assert np.all(np.abs(mass_ratio - 1) <= 0.1 + 1e-5)
  for values in (friction, gear_ratio[:, 0], mass_ratio):
    assert len(np.unique(values)) == _WORLDS
  # Initial pose: a heading each, joints near (and within) their ranges.
  quats = first.data.qpos[:, 3:7]
  assert not np.allclose(quats[0], quats[1])
  spread = np.abs(first.data.qpos[:, 7:] - model.qpos0[7:])
  assert np.all(spread <= 0.1 + 1e-6) and np.any(spread > 0.01)
  # Auto-reset drew a new episode: new masses for the same world.
  restarted = states[_STEPS].model_fields['body_mass'][:, torso]
  assert not np.allclose(restarted, fields['body_mass'][:, torso])


def test_playground_equivalent_settings_switch_everything_off():
  task = walk.Walk(**walk.PLAYGROUND_EQUIVALENT)
  env = environment.Environment(task, time_limit=1.0)
  # HumanoidWalk's observation: 21 + 1 + 12 + 3 + 3 + 27.
  assert env.observation_spec()['policy'].shape == (67,)
  assert not task.variator.bindings and task.pushes.interval == 0
  assert not jax.eval_shape(env.reset, jax.random.key(0)).model_fields


def test_the_command_line_builds_it():
  env = registry.make_environment('walk', time_limit=walk.EPISODE_SECONDS)
  assert isinstance(env.task, walk.Walk) and env.step_limit == 1000
  assert set(env.observation_spec()) == {'policy', 'critic'}
  assert env.action_spec().shape == (21,)
