"""The joystick task: Playground's Go1 joystick rewards, on composer's features.

One environment (flat ground, 2 worlds, commands resampled every 2 steps, a
push every 3, episodes of 6 steps) is compiled once for the module; the
tests read one short trajectory of it.
"""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from mjx_composer import environment
from mjx_composer.runtime.state import StepType
from mjx_composer.suite.entities import go1
from mjx_composer.suite.tasks import joystick
from mjx_composer.suite.tasks import registry

_WORLDS = 2
_STEPS = 6  # The time limit, in control steps.
_COMMAND_INTERVAL = 2
_PUSH_INTERVAL = 3


@pytest.fixture(scope='module')
def run():
  """(env, step, [state after reset, after step 1, ...], actions)."""
  task = joystick.Joystick(
      command_interval=_COMMAND_INTERVAL, push_interval=_PUSH_INTERVAL
  )
  env = environment.Environment(
      task,
      time_limit=_STEPS * task.control_timestep,
      options=environment.ExecutionOptions(auto_reset='same_step'),
  )
  states = [
      jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), _WORLDS))
  ]
  step = jax.jit(jax.vmap(env.step))
  actions = np.random.default_rng(0).uniform(-0.3, 0.3, (_STEPS, _WORLDS, 12))
  for action in actions:
    states.append(step(states[-1], jnp.asarray(action, jnp.float32)))
  return env, step, jax.device_get(states), actions


@pytest.fixture(scope='module')
def before_step(run):
  """The task's `before_step` on one world, batched over keys (jitted)."""
  env = run[0]

  @jax.jit
  def call(state, action, keys):
    physics = env.physics(state)
    after = jax.vmap(lambda k: env.task.before_step(physics, action, k))(keys)
    return physics.data.qvel, after.data.qvel, after.task_state

  return call


def _world(state, world):
  return jax.tree.map(lambda x: x[world], state)


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


def _sensor(model, data, world, name):
  sensor = model.sensor('go1/' + name)
  start = sensor.adr[0]
  return data.sensordata[world, start : start + sensor.dim[0]]


def test_actions_are_pd_targets_around_home(run):
  env, _, states, actions = run
  home = env.task.go1.home_joint_positions
  for i in range(1, _STEPS):
    np.testing.assert_allclose(
        states[i].data.ctrl, home + 0.5 * actions[i - 1], atol=1e-6
    )
  assert env.action_spec().shape == (12,)
  np.testing.assert_array_equal(env.action_spec().minimum, -1.0)


def test_feet_bookkeeping_follows_playground(run):
  env, _, states, _ = run
  model, dt = env.mj_model, env.control_timestep()
  air = np.zeros((_WORLDS, 4))
  peak = np.zeros((_WORLDS, 4))
  contact = np.zeros((_WORLDS, 4), bool)
  feet = [model.site(f'go1/{f}').id for f in go1.FEET]
  for state in states[1:_STEPS]:
    now = np.stack(
        [
            np.concatenate(
                [
                    _sensor(model, state.data, w, f'{f}_contact')
                    for f in go1.FEET
                ]
            )
            > 0
            for w in range(_WORLDS)
        ]
    )
    # Playground's order: filter, first contact, air time, swing peak.
    air = air * ~contact
    first = (air > 0) & (now | contact)
    air = air + dt
    peak = np.maximum(peak * ~contact, state.data.site_xpos[:, feet, 2])
    np.testing.assert_array_equal(state.task_state['contact'], now)
    np.testing.assert_array_equal(state.task_state['first_contact'], first)
    np.testing.assert_allclose(state.task_state['air_time'], air, atol=1e-6)
    np.testing.assert_allclose(state.task_state['swing_peak'], peak, atol=1e-6)
    contact = now


def _playground_reward(env, state, world):
  """Playground's joystick reward, from the state's data and task state."""
  model, data, task_state = env.mj_model, state.data, state.task_state
  home = env.task.go1.home_joint_positions
  sensor = lambda name: _sensor(model, data, world, name)
  pick = lambda key: np.asarray(task_state[key][world], np.float64)
  command = pick('command')
  moving = float(np.linalg.norm(command) > 0.01)
  qpos, qvel = data.qpos[world, 7:], data.qvel[world, 6:]
  torques = data.actuator_force[world]
  lows, highs = model.jnt_range[1:].T
  feet_velocity = np.stack([sensor(f'{f}_global_linvel') for f in go1.FEET])
  feet_xy = feet_velocity[:, :2]
  foot_z = data.site_xpos[
      world, [model.site(f'go1/{f}').id for f in go1.FEET], 2
  ]
  contact, first = pick('contact'), pick('first_contact')
  terms = {
      'tracking_lin_vel': np.exp(
          -np.sum((command[:2] - sensor('local_linvel')[:2]) ** 2) / 0.25
      ),
      'tracking_ang_vel': np.exp(
          -((command[2] - sensor('gyro')[2]) ** 2) / 0.25
      ),
      'lin_vel_z': sensor('global_linvel')[2] ** 2,
      'ang_vel_xy': np.sum(sensor('global_angvel')[:2] ** 2),
      'orientation': np.sum(sensor('upvector')[:2] ** 2),
      'stand_still': np.sum(np.abs(qpos - home)) * (1 - moving),
      'termination': float(state.terminated[world]),
      'pose': np.exp(-np.sum((qpos - home) ** 2 * ([1.0, 1.0, 0.1] * 4))),
      'torques': np.sqrt(np.sum(torques**2)) + np.sum(np.abs(torques)),
      'action_rate': np.sum((pick('action') - pick('previous_action')) ** 2),
      'energy': np.sum(np.abs(qvel) * np.abs(torques)),
      'feet_slip': np.sum(np.sum(feet_xy**2, axis=-1) * contact) * moving,
      'feet_clearance': np.sum(
          np.abs(foot_z - 0.1) * np.sqrt(np.linalg.norm(feet_xy, axis=-1))
      ),
      'feet_height': np.sum((pick('swing_peak') / 0.1 - 1) ** 2 * first)
      * moving,
      'feet_air_time': np.sum((pick('air_time') - 0.1) * first) * moving,
      'dof_pos_limits': np.sum(
          -np.clip(qpos - 0.95 * lows, None, 0)
          + np.clip(qpos - 0.95 * highs, 0, None)
      ),
  }
  scales = {
      'tracking_lin_vel': 1.0,
      'tracking_ang_vel': 0.5,
      'lin_vel_z': -0.5,
      'ang_vel_xy': -0.05,
      'orientation': -5.0,
      'dof_pos_limits': -1.0,
      'pose': 0.5,
      'termination': -1.0,
      'stand_still': -1.0,
      'torques': -0.0002,
      'action_rate': -0.01,
      'energy': -0.001,
      'feet_clearance': -2.0,
      'feet_height': -0.2,
      'feet_slip': -0.1,
      'feet_air_time': 0.1,
  }
  total = sum(scales[k] * v for k, v in terms.items()) * 0.02
  return np.clip(total, 0.0, 10000.0)


def test_reward_is_playgrounds(run):
  env, _, states, _ = run
  rewards = []
  for state in states[1:_STEPS]:
    for world in range(_WORLDS):
      want = _playground_reward(env, state, world)
      assert state.reward[world] == pytest.approx(want, rel=1e-4, abs=1e-6)
      rewards.append(want)
  assert max(rewards) > 0.005  # Not only clipped zeros.


def test_commands_resample_every_k_steps(run, before_step):
  env, _, states, actions = run
  commands = [s.task_state['command'] for s in states[:_STEPS]]
  # Steps 1 and 2 run with the episode's first command (0 and 1 steps
  # done); step 3 may change it (2 done); step 4 keeps step 3's.
  np.testing.assert_array_equal(commands[1], commands[0])
  np.testing.assert_array_equal(commands[2], commands[0])
  np.testing.assert_array_equal(commands[4], commands[3])
  amplitude = np.array(joystick.COMMAND_AMPLITUDE)
  assert np.all(np.abs(commands[0]) <= amplitude)
  keys = jax.random.split(jax.random.key(5), 256)
  for index, due in ((1, False), (2, True)):
    state = _world(states[index], 0)
    old = state.task_state['command']
    _, _, task_state = jax.device_get(
        before_step(state, jnp.asarray(actions[index, 0]), keys)
    )
    new = task_state['command']
    changed = np.any(new != old, axis=-1)
    if not due:
      assert not np.any(changed)
      continue
    # Playground's resampling: half keep the old entry, the rest draw a new
    # one, zeroed with probabilities 1 - (0.9, 0.25, 0.5).
    assert 0.7 < changed.mean() < 0.99
    assert np.all(np.abs(new) <= amplitude)
    zeros = np.mean(new == 0, axis=0)
    assert zeros[1] > zeros[0]  # vy is zeroed most often.


def test_pushes_change_the_trunk_velocity_every_k_steps(run, before_step):
  env, _, states, actions = run
  for i in range(1, _STEPS):
    push = states[i].task_state['push']
    pushed = (i - 1) > 0 and (i - 1) % _PUSH_INTERVAL == 0
    size = np.linalg.norm(push, axis=-1)
    assert np.all((size >= 0.1 - 1e-6) & (size <= 1.0 + 1e-6)) == pushed
  keys = jax.random.split(jax.random.key(6), 4)
  for index, due in ((2, False), (3, True)):
    before, after, task_state = jax.device_get(
        before_step(
            _world(states[index], 1), jnp.asarray(actions[index, 1]), keys
        )
    )
    push = task_state['push']
    # `before` is the world's qvel; `after` one per key.
    np.testing.assert_allclose(after[:, :3] - before[:3], push, atol=1e-6)
    np.testing.assert_array_equal(
        after[:, 3:], np.broadcast_to(before[3:], after[:, 3:].shape)
    )
    assert np.all(np.linalg.norm(push, axis=-1) > 0) == due


def test_falls_terminate_and_time_limit_truncates(run):
  env, step, states, actions = run
  for state in states[1:_STEPS]:
    assert not np.any(state.terminated)
    assert np.all(state.step_type == StepType.MID)
  last = states[_STEPS]
  assert np.all(last.truncated) and np.all(last.discount == 1.0)
  state = states[2]
  qpos = np.array(state.data.qpos)
  qpos[:, 2] = 0.3
  qpos[:, 3:7] = [0.0, 1.0, 0.0, 0.0]  # Upside down.
  flipped = state.replace(data=state.data.replace(qpos=jnp.asarray(qpos)))
  after = jax.device_get(step(flipped, jnp.asarray(actions[2], jnp.float32)))
  assert np.all(after.terminated) and not np.any(after.truncated)
  np.testing.assert_array_equal(after.discount, 0.0)
  assert np.all(after.step_type == StepType.LAST)


def test_policy_sees_noisy_late_history_critic_sees_clean_current(run):
  env, _, states, actions = run
  policy, critic = _slices(env, 'policy'), _slices(env, 'critic')
  k = 4
  state = states[k]
  clean, noisy = state.observation['critic'], state.observation['policy']
  joints = lambda s: s.data.qpos[:, 7:]
  np.testing.assert_allclose(
      clean[:, critic['privileged_joint_positions']], joints(state), atol=1e-6
  )
  np.testing.assert_allclose(
      clean[:, critic['command']], state.task_state['command'], atol=1e-6
  )
  np.testing.assert_allclose(
      noisy[:, policy['last_action']], actions[k - 1], atol=1e-6
  )
  # Three control steps of joint angles, one sample late, noise <= 0.03.
  seen = noisy[:, policy['go1/joint_positions']].reshape(_WORLDS, 3, 12)
  for slot, earlier in enumerate(states[k - 3 : k]):
    error = np.abs(seen[:, slot] - joints(earlier))
    assert np.all(error <= 0.03 + 1e-5) and np.any(error > 1e-3)


def test_every_world_and_episode_is_randomized(run):
  env, _, states, _ = run
  model, first = env.mj_model, states[0]
  fields = first.model_fields
  feet = [model.geom(f'go1/{f}').id for f in go1.FEET]
  friction = fields['geom_friction'][:, feet, 0]
  assert np.all((friction >= 0.4 - 1e-6) & (friction <= 1.0 + 1e-6))
  kp = fields['actuator_gainprm'][:, :, 0]
  assert np.all(np.abs(kp / 35.0 - 1) <= 0.1 + 1e-5)
  np.testing.assert_allclose(fields['actuator_biasprm'][:, :, 1], -kp)
  trunk = model.body('go1/trunk').id
  assert np.all(np.abs(fields['body_mass'][:, trunk] - 5.204) <= 1 + 1e-5)
  calf = model.body('go1/FR_calf').id
  ratio = fields['body_mass'][:, calf] / model.body_mass[calf]
  assert np.all(np.abs(ratio - 1) <= 0.1 + 1e-5)
  shift = fields['body_ipos'][:, trunk] - model.body_ipos[trunk]
  assert np.all(np.abs(shift) <= 0.05 + 1e-6)
  for values in (friction[:, 0], kp[:, 0], ratio, shift[:, 0]):
    assert len(np.unique(values)) == _WORLDS
  # Initial pose: near home, somewhere near the origin, moving a little.
  home = env.task.go1.home_joint_positions
  assert np.all(np.abs(first.data.qpos[:, 7:] - home) <= 0.1 + 1e-6)
  assert np.all(np.abs(first.data.qpos[:, :2]) <= 0.5)
  assert np.all(np.abs(first.data.qvel[:, :6]) <= 0.5 + 1e-6)
  np.testing.assert_allclose(first.data.ctrl, first.data.qpos[:, 7:])


def test_rough_terrain_variant_builds_with_per_world_terrain():
  task = joystick.Joystick(terrain='rough')
  env = environment.Environment(task, time_limit=1.0)
  assert env.mj_model.geom('ground').type == mujoco.mjtGeom.mjGEOM_HFIELD
  shapes = jax.eval_shape(env.reset, jax.random.key(0))
  assert 'hfield_data' in shapes.model_fields
  with pytest.raises(ValueError, match='terrain'):
    joystick.Joystick(terrain='ice')


@pytest.mark.parametrize(
    'name, terrain', [('joystick', 'flat'), ('joystick_rough', 'rough')]
)
def test_the_command_line_builds_it(name, terrain):
  env = registry.make_environment(name, time_limit=joystick.EPISODE_SECONDS)
  assert isinstance(env.task, joystick.Joystick) and env.step_limit == 1000
  assert env.task.arena.ground_geoms[0].type == (
      mujoco.mjtGeom.mjGEOM_PLANE
      if terrain == 'flat'
      else mujoco.mjtGeom.mjGEOM_HFIELD
  )
  assert set(env.observation_spec()) == {'policy', 'critic'}
