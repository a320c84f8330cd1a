"""Environment: hook order, stepping, episode ends, auto-reset, keys, errors."""

import copy
import dataclasses
import inspect
import math
import warnings

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer import environment as environment_lib
from mjx_composer.runtime import auto_reset as auto_reset_lib
from tests import conftest

# -- hook scheduling (inventory 8.1) ------------------------------------------

_DEVICE_HOOKS = (
    'initialize_episode',
    'before_step',
    'before_substep',
    'after_substep',
    'after_step',
)
_H = {name: i for i, name in enumerate(_DEVICE_HOOKS)}
_PHYSICS_TIMESTEP = 0.002
_CONTROL_TIMESTEP = 0.01  # 5 sub-steps
_N = 5


def _check_and_count(physics, row, hook):
  """Checks composer's invariants for one hook call, then counts it.

  The task state holds `counts[row, hook]` and a `violations` counter; every
  failed check adds one violation, so the test asserts on it afterwards.
  """
  counts = physics.task_state['counts']
  mine = counts[row]
  checks = []
  bs, bss, ass, as_ = (
      mine[_H['before_step']],
      mine[_H['before_substep']],
      mine[_H['after_substep']],
      mine[_H['after_step']],
  )
  if hook == 'before_step':
    checks += [as_ == bs, ass == bss]
  elif hook in ('before_substep', 'after_substep'):
    checks += [as_ == bs - 1]
    if hook == 'after_substep':
      checks += [ass == bss - 1]
  elif hook == 'after_step':
    checks += [bss == bs * _N]
  if hook != 'initialize_episode':
    checks.append(mine[_H['initialize_episode']] == 1)
  # Physics time counts exactly the sub-steps taken this episode.
  substeps = jnp.round(physics.time() / _PHYSICS_TIMESTEP).astype(jnp.int32)
  checks.append(substeps == bss)
  # Dispatch order: the previous participant has already run this hook.
  if row > 0:
    checks.append(counts[row - 1, _H[hook]] == mine[_H[hook]] + 1)
  violations = physics.task_state['violations'] + sum(
      jnp.logical_not(c).astype(jnp.int32) for c in checks
  )
  counts = counts.at[row, _H[hook]].add(1)
  return physics.update_task_state(counts=counts, violations=violations)


class HookEntity(conftest.SpecEntity):
  """An entity that counts its hooks; the root one has 4 motors."""

  def _build(self, name, row, host_log, n_motors=0):
    spec = self._new_spec(name)
    body = spec.worldbody.add_body(name='body')
    body.add_geom(
        type=mujoco.mjtGeom.mjGEOM_SPHERE,
        size=[0.05, 0, 0],
        contype=0,
        conaffinity=0,
    )
    for i in range(n_motors):
      joint = body.add_joint(
          name=f'j{i}', type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[1, 0, 0]
      )
      spec.add_actuator(
          name=f'm{i}', target=joint.name, trntype=mujoco.mjtTrn.mjTRN_JOINT
      )
    self.row = row
    self.host_log = host_log

  def initialize_episode_mjcf(self, random_state):
    self.host_log.append((self.row, 'initialize_episode_mjcf'))

  def after_compile(self, physics, random_state):
    self.host_log.append((self.row, 'after_compile'))

  def initialize_episode(self, physics, key):
    return _check_and_count(physics, self.row, 'initialize_episode')

  def before_step(self, physics, key):
    return _check_and_count(physics, self.row, 'before_step')

  def before_substep(self, physics, key):
    return _check_and_count(physics, self.row, 'before_substep')

  def after_substep(self, physics, key):
    return _check_and_count(physics, self.row, 'after_substep')

  def after_step(self, physics, key):
    return _check_and_count(physics, self.row, 'after_step')


class HookTask(composer.Task):
  """Row 0 is the task, rows 1..9 the entities, row 10 the extra hooks."""

  def __init__(self, host_log):
    self.host_log = host_log
    # The 9-entity tree 0->{1->{4->{8}, 5}, 2->{6, 7}, 3} of composer's test.
    entities = [
        HookEntity(f'e{i}', 0, host_log, n_motors=4 if i == 0 else 0)
        for i in range(9)
    ]
    for parent, children in (
        (0, (1, 2, 3)),
        (1, (4, 5)),
        (4, (8,)),
        (2, (6, 7)),
    ):
      for child in children:
        entities[parent].attach(entities[child])
    self.entities = entities
    for row, entity in enumerate(entities[0].iter_entities(), start=1):
      entity.row = row
    self.set_timesteps(_CONTROL_TIMESTEP, _PHYSICS_TIMESTEP)

  @property
  def root_entity(self):
    return self.entities[0]

  def initial_task_state(self):
    return {
        'counts': jnp.zeros((11, len(_DEVICE_HOOKS)), jnp.int32),
        'violations': jnp.zeros((), jnp.int32),
    }

  def initialize_episode_mjcf(self, random_state):
    self.host_log.append((0, 'initialize_episode_mjcf'))

  def after_compile(self, physics, random_state):
    self.host_log.append((0, 'after_compile'))

  def initialize_episode(self, physics, key):
    return _check_and_count(physics, 0, 'initialize_episode')

  def before_step(self, physics, action, key):
    physics = super().before_step(physics, action, key)
    return _check_and_count(physics, 0, 'before_step')

  def before_substep(self, physics, action, key):
    return _check_and_count(physics, 0, 'before_substep')

  def after_substep(self, physics, key):
    return _check_and_count(physics, 0, 'after_substep')

  def after_step(self, physics, key):
    return _check_and_count(physics, 0, 'after_step')

  def get_reward(self, physics):
    return 0.0


def test_hook_scheduling_counts_order_and_time():
  host_log = []
  task = HookTask(host_log)
  env = composer.Environment(task, time_limit=math.inf)
  for name in (
      'initialize_episode',
      'before_step',
      'before_substep',
      'after_substep',
      'after_step',
  ):

    def extra(physics, *args, _name=name):
      return _check_and_count(physics, 10, _name)

    env.add_extra_hook(name, extra)
  # Build-time hooks ran once each, task first, then entities in
  # depth-first attachment order.
  order = [row for row, hook in host_log if hook == 'initialize_episode_mjcf']
  assert order == list(range(10))
  assert [h for _, h in host_log] == (
      ['initialize_episode_mjcf'] * 10 + ['after_compile'] * 10
  )
  assert [e.name for e in task.root_entity.iter_entities()] == [
      'e0',
      'e1',
      'e4',
      'e8',
      'e5',
      'e2',
      'e6',
      'e7',
      'e3',
  ]

  reset, step = jax.jit(env.reset), jax.jit(env.step)
  num_steps = 7
  action = jnp.array([0.1, 0.2, 0.3, 0.4])
  for episode in range(2):
    state = reset(jax.random.key(episode))
    for _ in range(num_steps):
      state = step(state, action)
    counts = np.asarray(state.task_state['counts'])
    expected = np.array(
        [1, num_steps, num_steps * _N, num_steps * _N, num_steps]
    )
    np.testing.assert_array_equal(counts, np.tile(expected, (11, 1)))
    assert int(state.task_state['violations']) == 0
    assert float(state.data.time) == pytest.approx(
        num_steps * _CONTROL_TIMESTEP, rel=1e-5
    )
    # The default Task.before_step copies the action into ctrl.
    np.testing.assert_allclose(np.asarray(state.data.ctrl), action)


def test_hook_checks_can_fail():
  """The invariant checks above detect a wrongly ordered call."""
  host_log = []
  env = composer.Environment(HookTask(host_log))
  state = jax.jit(env.reset)(jax.random.key(0))
  physics = env.physics(state)
  # Calling entity row 3's hook before row 2's breaks the order invariant.
  physics = _check_and_count(physics, 3, 'before_step')
  assert int(physics.task_state['violations']) > 0


def test_build_hooks_see_untouched_time():
  env = conftest.make_swing_env()
  assert env.n_sub_steps == 2
  assert env.control_timestep() == pytest.approx(0.01)


# -- stepping and episode ends -------------------------------------------------


def _leaf_values(x):
  if jnp.issubdtype(x.dtype, jax.dtypes.prng_key):
    return np.asarray(jax.random.key_data(x))
  return np.asarray(x)


def assert_trees_equal(a, b, select=lambda x: x, select_b=None):
  """Bitwise equality of two pytrees (PRNG keys compared by their data)."""
  select_b = select_b or select
  jax.tree.map(
      lambda x, y: np.testing.assert_array_equal(
          select(_leaf_values(x)), select_b(_leaf_values(y))
      ),
      a,
      b,
  )


def assert_trees_close(a, b, select=lambda x: x, select_b=None):
  """Equality of two pytrees to float32 rounding (integers exactly)."""
  select_b = select_b or select
  jax.tree.map(
      lambda x, y: np.testing.assert_allclose(
          select(_leaf_values(x)),
          select_b(_leaf_values(y)),
          rtol=1e-5,
          atol=1e-6,
      ),
      a,
      b,
  )


def _rollout(step, state, actions):
  states = []
  for action in actions:
    state = step(state, action)
    states.append(state)
  return states


def test_observation_is_taken_at_end_of_control_step(swing_env, swing_fns):
  state = swing_fns['reset'](jax.random.key(3))
  physics = swing_env.physics(state)
  np.testing.assert_allclose(
      state.observation['tip'][0],
      physics.bind(swing_env.task.pendulum.tip).xpos,
  )
  for _ in range(3):
    state = swing_fns['step'](state, jnp.array([0.5]))
    physics = swing_env.physics(state)
    np.testing.assert_array_equal(
        state.observation['tip'][0],
        physics.bind(swing_env.task.pendulum.tip).xpos,
    )


def test_time_limit_truncates_with_task_discount(swing_env, swing_fns):
  # time_limit 0.05 s at 0.01 s per control step: LAST after 5 steps.
  state = swing_fns['reset'](jax.random.key(0))
  assert state.first()
  states = _rollout(swing_fns['step'], state, [jnp.zeros(1)] * 6)
  step_types = [int(s.step_type) for s in states]
  assert step_types == [1, 1, 1, 1, 2, 0]
  last = states[4]
  assert bool(last.truncated) and not bool(last.terminated)
  assert float(last.discount) == 1.0
  assert int(last.metrics['episode_length']) == 5
  # The step after LAST starts a new episode (the action is ignored).
  assert float(states[5].data.time) == 0.0
  assert int(states[5].steps) == 0


def test_termination_is_not_truncation():
  env = conftest.make_swing_env(terminate_above=-10.0, time_limit=0.05)
  state = jax.jit(env.reset)(jax.random.key(0))
  state = jax.jit(env.step)(state, jnp.zeros(1))
  assert state.last()
  assert bool(state.terminated) and not bool(state.truncated)
  assert float(state.discount) == 0.0


def test_same_step_auto_reset():
  env = conftest.make_swing_env(
      time_limit=0.02,
      options=composer.ExecutionOptions(auto_reset='same_step'),
  )
  reset, step = jax.jit(env.reset), jax.jit(env.step)
  state = reset(jax.random.key(1))
  state = step(state, jnp.array([1.0]))
  assert state.mid()
  last = step(state, jnp.array([1.0]))
  assert last.last() and bool(last.truncated)
  assert int(last.metrics['episode_length']) == 2
  # The state already holds the new episode: time 0, fresh observation.
  assert float(last.data.time) == 0.0 and int(last.steps) == 0
  physics = env.physics(last)
  np.testing.assert_array_equal(
      last.observation['tip'][0], physics.bind(env.task.pendulum.tip).xpos
  )
  assert not np.allclose(last.final_observation['tip'], last.observation['tip'])
  following = step(last, jnp.array([1.0]))
  assert following.mid() and int(following.steps) == 1


# -- keys, batches, divergence --------------------------------------------------


def test_same_key_same_episode(swing_fns):
  actions = [jnp.array([a]) for a in (0.3, -0.7, 1.0, 0.2, -0.1, 0.5, 0.5)]
  runs = []
  for _ in range(2):
    state = swing_fns['reset'](jax.random.key(42))
    runs.append(_rollout(swing_fns['step'], state, actions))
  for a, b in zip(*runs):
    assert_trees_equal(a, b)
  other = swing_fns['reset'](jax.random.key(43))
  assert float(other.task_state['target']) != float(
      swing_fns['reset'](jax.random.key(42)).task_state['target']
  )


def test_world_does_not_depend_on_batch_size(swing_fns):
  keys = jax.random.split(jax.random.key(7), 5)
  actions = jax.random.uniform(
      jax.random.key(8), (6, 5, 1), minval=-1, maxval=1
  )
  big = swing_fns['vreset'](keys)
  small = swing_fns['vreset'](keys[2:3])
  for t in range(6):
    big = swing_fns['vstep'](big, actions[t])
    small = swing_fns['vstep'](small, actions[t, 2:3])
  assert_trees_equal(big, small, select=lambda x: x[2:3], select_b=lambda x: x)
  # And a single un-batched world agrees too.
  single = swing_fns['reset'](keys[2])
  for t in range(6):
    single = swing_fns['step'](single, actions[t, 2])
  assert_trees_equal(small, single, select=lambda x: x[0], select_b=lambda x: x)


def test_staggered_auto_resets_match_single_worlds(swing_fns):
  # Under vmap, resets are computed only at steps where some world is done
  # (a batching rule); with staggered episodes that path and the skipped
  # one must both give each world exactly its own trajectory: bit for bit
  # what the same batched program gives it among other worlds (here, copies
  # of itself, all resetting together), and its single-world trajectory to
  # float32 rounding (XLA may order a batched dot product differently).
  keys = jax.random.split(jax.random.key(11), 3)
  actions = jax.random.uniform(
      jax.random.key(12), (8, 3, 1), minval=-1, maxval=1
  )
  singles = [swing_fns['reset'](k) for k in keys]
  singles[0] = swing_fns['step'](singles[0], jnp.zeros(1))  # one step ahead
  stack = lambda states: jax.tree.map(lambda *xs: jnp.stack(xs), *states)
  batch = stack(singles)
  alone = [stack([s] * 3) for s in singles]
  for t in range(8):
    batch = swing_fns['vstep'](batch, actions[t])
    alone = [
        swing_fns['vstep'](b, jnp.stack([actions[t, i]] * 3))
        for i, b in enumerate(alone)
    ]
    singles = [
        swing_fns['step'](s, actions[t, i]) for i, s in enumerate(singles)
    ]
  assert int(batch.metrics['episode_length'][0]) != int(
      batch.metrics['episode_length'][1]
  )
  for i, (single, among_copies) in enumerate(zip(singles, alone)):
    assert_trees_equal(
        batch, among_copies, select=lambda x, i=i: x[i], select_b=lambda x: x[0]
    )
    assert_trees_close(
        batch, single, select=lambda x, i=i: x[i], select_b=lambda x: x
    )


def test_divergence_is_isolated_and_reset(swing_fns):
  keys = jax.random.split(jax.random.key(0), 4)
  states = swing_fns['vreset'](keys)
  reference = swing_fns['vstep'](states, jnp.zeros((4, 1)))
  # A NaN velocity in world 1 (a NaN action would run as zeros, flagged
  # apart: tests/runtime/test_nonfinite.py).
  qvel = states.data.qvel.at[1].set(jnp.nan)
  poisoned = swing_fns['vstep'](
      states.replace(data=states.data.replace(qvel=qvel)), jnp.zeros((4, 1))
  )
  diverged = np.asarray(poisoned.metrics['diverged'])
  np.testing.assert_array_equal(diverged, [0.0, 1.0, 0.0, 0.0])
  # 'jax' has no fixed buffers to overflow, diverged or not.
  np.testing.assert_array_equal(poisoned.metrics['overflow'], 0.0)
  assert not np.isfinite(np.asarray(poisoned.data.qacc[1])).all()
  np.testing.assert_array_equal(np.asarray(poisoned.step_type), [1, 2, 1, 1])
  assert float(poisoned.reward[1]) == 0.0
  assert float(poisoned.discount[1]) == 0.0
  assert bool(poisoned.terminated[1])
  for i in (0, 2, 3):
    assert_trees_equal(poisoned, reference, select=lambda x, i=i: x[i])
  # The next step resets the diverged world; the others keep going.
  after = swing_fns['vstep'](poisoned, jnp.zeros((4, 1)))
  np.testing.assert_array_equal(np.asarray(after.step_type), [1, 0, 1, 1])
  assert np.isfinite(np.asarray(after.data.qpos)).all()
  assert np.isfinite(np.asarray(after.data.qacc)).all()


# -- specs and errors -----------------------------------------------------------


def test_specs(swing_env):
  spec = swing_env.action_spec()
  assert spec.shape == (1,)
  assert spec.name == 'pendulum/motor'
  np.testing.assert_array_equal(spec.minimum, [-1.0])
  np.testing.assert_array_equal(spec.maximum, [1.0])
  assert swing_env.reward_spec().shape == ()
  assert swing_env.discount_spec().maximum == 1.0
  assert swing_env.observation_spec()['tip'].shape == (1, 3)


def test_wrong_action_shape_is_a_clear_error(swing_env, swing_fns):
  state = swing_fns['reset'](jax.random.key(0))
  with pytest.raises(ValueError, match=r'Expected an action of shape \(1,\)'):
    swing_env.step(state, jnp.zeros(3))


def test_non_integer_timestep_ratio():
  task = conftest.SwingTask()
  with pytest.raises(ValueError, match='integer multiple of physics timestep'):
    task.set_timesteps(control_timestep=0.015, physics_timestep=0.01)
  with pytest.raises(ValueError, match='integer multiple of physics timestep'):
    task.control_timestep = 0.0123


def test_unknown_element_is_a_clear_error(swing_env, swing_fns):
  stranger = conftest.Pendulum(name='stranger')
  physics = swing_env.physics(swing_fns['reset'](jax.random.key(0)))
  with pytest.raises(ValueError, match='not part of the compiled model'):
    physics.bind(stranger.tip).xpos
  with pytest.raises(KeyError, match="No site named 'nope'"):
    physics.named.data.site_xpos['nope']
  with pytest.raises(AttributeError, match='has no attribute'):
    physics.bind(swing_env.task.pendulum.tip).qpos


def test_hook_must_return_physics():
  class Forgetful(conftest.SwingTask):

    def after_step(self, physics, key):
      physics.bind(self.pendulum.joint).set(qpos=0.0)  # result dropped

  env = composer.Environment(Forgetful())
  # Raised while tracing, no need to compile or run anything: by the reset,
  # which traces the step hooks to find the model fields they write.
  with pytest.raises(TypeError, match='must return the \\(new\\) Physics'):
    jax.eval_shape(env.reset, jax.random.key(0))


class _Recolour(conftest.SwingTask):
  """Colours the ball after every sub-step by the pendulum's angle: a model
  field that a step hook writes, different in every world."""

  def after_substep(self, physics, key):
    angle = physics.bind(self.pendulum.joint).qpos[0]
    red = jnp.abs(jnp.sin(angle))
    return physics.bind(self.ball.geom).set(
        rgba=jnp.stack([red, 0.0, 0.0, 1.0])
    )


def test_model_writes_in_step_hooks_are_found_and_per_world():
  """A model field written in `after_substep` is per world without being
  declared, and runs as the declared field does, bit for bit."""
  found = composer.Environment(_Recolour())
  declared = composer.Environment(
      _Recolour(),
      options=composer.ExecutionOptions(per_world_model_fields=('geom_rgba',)),
  )
  assert found.per_world_model_fields == {
      'geom_rgba': ('_Recolour.after_substep',)
  }
  assert declared.per_world_model_fields['geom_rgba'] == (
      '_Recolour.after_substep',
      'ExecutionOptions(per_world_model_fields=...)',
  )
  keys = jax.random.split(jax.random.key(2), 3)
  actions = jnp.full((3, 1), 0.5)
  runs = []
  for env in (found, declared):
    states = jax.jit(jax.vmap(env.reset))(keys)
    states = jax.jit(jax.vmap(env.step))(states, actions)
    runs.append(states)
  assert set(runs[0].model_fields) == {'geom_rgba'}
  found_run, declared_run = (
      jax.tree.map(
          lambda x: jax.random.key_data(x)
          if jnp.issubdtype(x.dtype, jax.dtypes.prng_key)
          else x,
          run,
      )
      for run in runs
  )
  jax.tree.map(np.testing.assert_array_equal, found_run, declared_run)
  # Each world's colour is its own last sub-step's angle.
  hinge = found.mj_model.joint(f'{found.task.pendulum.name}/hinge').qposadr[0]
  ball = found.mj_model.geom(f'{found.task.ball.name}/geom').id
  rgba = np.asarray(runs[0].model_fields['geom_rgba'])[:, ball]
  red = np.abs(np.sin(np.asarray(runs[0].data.qpos)[:, hinge]))
  np.testing.assert_allclose(rgba[:, 0], red, rtol=1e-6)
  assert len(np.unique(rgba[:, 0])) == 3


def test_bad_constructor_arguments():
  with pytest.raises(ValueError, match=r'ExecutionOptions\(auto_reset='):
    composer.ExecutionOptions(auto_reset='sometimes')
  with pytest.raises(ValueError, match='ObservationPadding'):
    composer.Environment(conftest.SwingTask(), delayed_observation_padding=0)
  for name in environment_lib.COMPOSER_OPTIONS:
    with pytest.raises(ValueError, match=f'{name}=True.*Pass {name}=False'):
      composer.Environment(conftest.SwingTask(), **{name: True})
    with pytest.raises(ValueError, match='True, False or None'):
      composer.Environment(conftest.SwingTask(), **{name: 1})
  # composer code that sets the options we implement builds as it is.
  composer.Environment(
      conftest.SwingTask(),
      **{name: False for name in environment_lib.COMPOSER_OPTIONS},
  )
  env = conftest.make_swing_env()
  with pytest.raises(ValueError, match='not a valid hook name'):
    env.add_extra_hook('before_everything', lambda *a: None)


def test_reset_accepts_legacy_keys(swing_env, swing_fns):
  new = swing_fns['reset'](jax.random.key(5))
  old = jax.jit(swing_env.reset)(jax.random.PRNGKey(5))  # not op by op: slow
  np.testing.assert_array_equal(new.data.qpos, old.data.qpos)
  with pytest.raises(ValueError, match='one PRNG key'):
    swing_env.reset(jax.random.split(jax.random.key(0), 3))


def test_step_types_match_dm_env():
  import dm_env  # pylint: disable=g-import-not-at-top

  for ours in environment_lib.StepType:
    assert int(ours) == int(dm_env.StepType[ours.name])


# -- state across episodes, initialization failures ----------------------------


class _CountingTask(conftest.SwingTask):
  """Counts each world's episodes in a persistent entry; colours the ball
  once per world (first reset only), from the reset key."""

  def initialize_episode(self, physics, key):
    physics = super().initialize_episode(physics, key)
    episodes = physics.get_persistent('episodes', jnp.zeros((), jnp.int32))
    first = episodes == 0
    ball = physics.bind(self.ball.geom)
    new_red = jax.random.uniform(key)
    red = jnp.where(first, new_red, ball.rgba[0])
    physics = ball.set(rgba=jnp.stack([red, 0.0, 0.0, 1.0]))
    return physics.set_persistent('episodes', episodes + 1)


@pytest.mark.parametrize('auto_reset', ['next_step', 'same_step'])
def test_persistent_state_and_model_fields_survive_auto_reset(auto_reset):
  env = composer.Environment(
      _CountingTask(),
      time_limit=0.02,
      options=composer.ExecutionOptions(auto_reset=auto_reset),
  )
  reset = jax.jit(jax.vmap(env.reset))
  step = jax.jit(jax.vmap(env.step))
  states = reset(jax.random.split(jax.random.key(3), 4))
  red_of = jax.vmap(
      lambda state: env.physics(state).bind(env.task.ball.geom).rgba[0]
  )
  first_red = np.asarray(red_of(states))
  assert len(np.unique(first_red)) == 4  # different worlds, different draws
  ends = 0
  for _ in range(7):
    states = step(states, jnp.zeros((4, 1)))
    ends += int(states.last()[0])
  # Episodes of 2 steps: one reset per LAST (same_step) or per step after a
  # LAST (next_step); the persistent counter saw every one of them.
  episodes = np.asarray(states.persistent['episodes'])
  expected = 1 + (
      ends if auto_reset == 'same_step' else ends - int(states.last()[0])
  )
  np.testing.assert_array_equal(episodes, expected)
  assert expected >= 3
  # The once-per-world colour is still the first draw, per world.
  red = red_of(states)
  np.testing.assert_array_equal(red, first_red)
  # A fresh reset starts the world afresh.
  again = reset(jax.random.split(jax.random.key(3), 4))
  np.testing.assert_array_equal(again.persistent['episodes'], 1)


class _SensingPendulum(conftest.Pendulum):
  """The pendulum with an accelerometer and a position sensor at its tip."""

  def _build(self, **kwargs):  # pylint: disable=arguments-differ
    super()._build(**kwargs)
    site = dict(objtype=mujoco.mjtObj.mjOBJ_SITE, objname='tip')
    self.accelerometer = self._spec.add_sensor(
        name='acc', type=mujoco.mjtSensor.mjSENS_ACCELEROMETER, **site
    )
    self.tip_pos = self._spec.add_sensor(
        name='tip_pos', type=mujoco.mjtSensor.mjSENS_FRAMEPOS, **site
    )


class _ReadingTask(conftest.PendulumTask):
  """An `initialize_episode` that reads as composer's hooks may: at the
  reset state, then after moving the pendulum (`qpos`) and a fixed ball
  (its frame's `body_pos`, a model field), with no forward pass between."""

  def __init__(self):
    self.arena = composer.Arena()
    # A limited hinge: MJX computes acceleration sensors only where the
    # model has constraint rows.
    self.pendulum = _SensingPendulum(
        limited=mujoco.mjtLimited.mjLIMITED_TRUE, range=[-2, 2]
    )
    self.arena.attach(self.pendulum)
    self.ball = conftest.Ball(collides=False)
    self.arena.attach(self.ball)

  def initial_task_state(self):
    names = ('acc_at_reset', 'tip', 'tip_sensor', 'acc', 'ball')
    return {name: jnp.zeros(3) for name in names}

  def initialize_episode(self, physics, key):
    acc_at_reset = physics.bind(self.pendulum.accelerometer).sensordata
    angle_key, ball_key = jax.random.split(key)
    physics = physics.bind(self.pendulum.joint).set(
        qpos=jax.random.uniform(angle_key, (1,), minval=-1, maxval=1)
    )
    physics = self.ball.set_pose(
        physics, position=jax.random.uniform(ball_key, (3,))
    )
    return physics.update_task_state(
        acc_at_reset=acc_at_reset,
        tip=physics.bind(self.pendulum.tip).xpos,
        tip_sensor=physics.bind(self.pendulum.tip_pos).sensordata,
        acc=physics.bind(self.pendulum.accelerometer).sensordata,
        ball=physics.bind(self.ball.geom).xpos,
    )

  def get_reward(self, physics):
    return 0.0


def test_reset_hooks_read_what_they_wrote():
  """composer runs the hooks in a reset context whose bindings forward
  lazily: a hook's read sees the reset state and its own writes. Here the
  reads run the forward pass's stage they need; the values are MuJoCo's
  (`mj_forward` on each world's state and model)."""
  env = composer.Environment(_ReadingTask())
  task = env.task
  states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(1), 3))
  model = copy.copy(env.mj_model)
  data = mujoco.MjData(model)
  mujoco.mj_forward(model, data)
  pendulum = f'{task.pendulum.name}/'
  acc_at_reset = data.sensor(pendulum + 'acc').data.copy()
  assert np.linalg.norm(acc_at_reset) > 9.0  # gravity's reaction
  frame = model.body(f'{task.ball.name}/').id
  for world in range(3):
    one = jax.tree.map(lambda x, w=world: x[w], states)
    read = {k: np.asarray(v) for k, v in one.task_state.items()}
    model.body_pos[frame] = np.asarray(one.model_fields['body_pos'][frame])
    data.qpos[:] = np.asarray(one.data.qpos)
    mujoco.mj_forward(model, data)
    expected = {
        'acc_at_reset': acc_at_reset,
        'tip': data.site(pendulum + 'tip').xpos,
        'tip_sensor': data.sensor(pendulum + 'tip_pos').data,
        'acc': data.sensor(pendulum + 'acc').data,
        'ball': data.geom(f'{task.ball.name}/geom').xpos,
    }
    assert not np.allclose(expected['tip'], [0.0, 0.0, 0.5])
    for name, value in expected.items():
      np.testing.assert_allclose(read[name], value, rtol=1e-5, atol=1e-5)


class _MassReadingTask(conftest.PendulumTask):
  """Randomizes a ball's and the pendulum rod's densities (so their masses
  and inertias) every episode composer's way (`initialize_episode_mjcf`),
  then reads their composite inertias (`cinert`, com-based) and the ball's
  position in `initialize_episode`, with no forward pass."""

  def __init__(self):
    self.arena = composer.Arena()
    self.pendulum = conftest.Pendulum()
    self.arena.attach(self.pendulum)
    self.ball = conftest.Ball(density=500.0, collides=False)
    self.arena.attach(self.ball)
    self.variator = composer.variation.MJCFVariator()
    scale = composer.variation.distributions.Uniform(0.5, 2.0)
    for geom in (self.ball.geom, self.pendulum.geom):
      self.variator.bind_attributes(
          geom, density=composer.variation.noises.Multiplicative(scale)
      )

  def initial_task_state(self):
    return {'cinert': jnp.zeros((2, 10)), 'ball': jnp.zeros(3)}

  def initialize_episode_mjcf(self, random_state):
    self.variator.apply_variations(random_state)

  def initialize_episode(self, physics, key):
    del key
    bodies = physics.bind([self.ball.body, self.pendulum.geom.parent])
    return physics.update_task_state(
        cinert=bodies.cinert, ball=physics.bind(self.ball.body).xpos
    )

  def get_reward(self, physics):
    return 0.0


def test_reset_hooks_read_the_centres_of_mass_of_their_randomized_masses():
  """The reset leaves the com-based quantities of a randomized world to
  the hooks that read them; a read computes them for the world's masses."""
  env = composer.Environment(_MassReadingTask())
  task = env.task
  states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(2), 3))
  model = copy.copy(env.mj_model)
  data = mujoco.MjData(model)
  ids = [
      model.body(f'{task.ball.name}/body').id,
      model.body(f'{task.pendulum.name}/rod').id,
  ]
  mujoco.mj_kinematics(model, data)
  mujoco.mj_comPos(model, data)
  nominal = data.cinert[ids].copy()
  for world in range(3):
    one = jax.tree.map(lambda x, w=world: x[w], states)
    assert 'body_mass' in one.model_fields
    for name, value in one.model_fields.items():  # the world's model
      if name.startswith('body_'):
        getattr(model, name)[:] = np.asarray(value)
    data.qpos[:] = np.asarray(env.mj_model.qpos0)
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    read = np.asarray(one.task_state['cinert'])
    assert not np.allclose(read, nominal, rtol=1e-3)  # the masses varied
    np.testing.assert_allclose(read, data.cinert[ids], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(
        one.task_state['ball'], data.xpos[ids[0]], rtol=1e-6, atol=1e-6
    )


class _FlakyTask(conftest.SwingTask):
  """Fails initialization with probability `p` (per attempt, from its key)."""

  def __init__(self, p):
    super().__init__()
    self.p = p

  def initialize_episode(self, physics, key):
    physics = super().initialize_episode(physics, key)
    draw = jax.random.uniform(jax.random.fold_in(key, 7))
    return physics.fail_initialization(draw < self.p)


def test_failed_initialization_is_retried_and_counted():
  worlds = 256
  env = composer.Environment(_FlakyTask(0.5), max_reset_attempts=20)
  states = jax.jit(jax.vmap(env.reset))(
      jax.random.split(jax.random.key(0), worlds)
  )
  failures = np.asarray(states.metrics['init_failures'])
  # Attempts until success are geometric: failures before success has mean
  # p / (1 - p) = 1; with 20 attempts virtually every world succeeds.
  assert np.all(np.asarray(states.metrics['init_failed']) == 0)
  assert 0.7 < failures.mean() < 1.3
  assert (failures == 0).mean() > 0.35 and failures.max() >= 3
  # Worlds that succeeded at once are the same as without retries.
  single = composer.Environment(_FlakyTask(0.5))
  once = jax.jit(jax.vmap(single.reset))(
      jax.random.split(jax.random.key(0), worlds)
  )
  ok = failures == 0
  np.testing.assert_array_equal(
      np.asarray(once.data.qpos)[ok], np.asarray(states.data.qpos)[ok]
  )
  np.testing.assert_array_equal(
      np.asarray(once.metrics['init_failed']),
      np.asarray(once.metrics['init_failures']),
  )
  # Retried worlds are resampled, not repeated.
  retried = failures > 0
  assert not np.any(
      np.all(
          np.asarray(once.data.qpos)[retried]
          == np.asarray(states.data.qpos)[retried],
          axis=-1,
      )
  )


def test_initialization_that_always_fails_is_bounded_and_flagged():
  env = composer.Environment(
      _FlakyTask(1.1), max_reset_attempts=3, time_limit=0.02
  )
  state = jax.jit(env.reset)(jax.random.key(0))
  assert float(state.metrics['init_failures']) == 3.0
  assert float(state.metrics['init_failed']) == 1.0
  # The failed attempts' poses are never run: the world is as it started.
  np.testing.assert_array_equal(state.data.qpos, env.mj_model.qpos0)
  state = jax.jit(env.step)(state, jnp.zeros(1))
  assert float(state.metrics['init_failed']) == 1.0  # reported all episode
  # Its first step ends it, with nothing to learn from.
  assert bool(state.last()) and bool(state.terminated)
  assert float(state.reward) == 0.0 and float(state.discount) == 0.0
  with pytest.raises(ValueError, match='max_reset_attempts'):
    composer.Environment(_FlakyTask(0.5), max_reset_attempts=0)


def test_step_hooks_cannot_add_persistent_entries():
  class Adds(conftest.SwingTask):

    def after_step(self, physics, key):
      return physics.set_persistent('late', jnp.zeros(()))

  env = composer.Environment(Adds())
  # Raised while tracing: the reset's (the analyses of the step's hooks run
  # on first use) or the step's.
  with pytest.raises(ValueError, match='initialize_episode'):
    state = jax.eval_shape(env.reset, jax.random.key(0))
    jax.eval_shape(env.step, state, jnp.zeros(1))


def test_auto_reset_batch_gives_the_same_trajectories():
  """Resetting the worlds that end 3 at a time, against the whole batch.

  Episodes of 4 control steps whose worlds start at different points of
  them, so that some but not all worlds end at each step. Same-step
  auto-reset, the training loops' mode (next-step passes other operands to
  the same `select_reset`, whose chunks tests/runtime/test_episode.py checks for
  every kind of leaf; one mode here keeps CI's compile time down).
  """
  auto_reset = 'same_step'
  envs = {
      batch: conftest.make_swing_env(
          time_limit=0.04,
          options=composer.ExecutionOptions(
              auto_reset=auto_reset,
              share_reset_forward=False if batch is None else None,
              auto_reset_batch=batch,
          ),
      )
      for batch in (None, 3)
  }
  n = 8
  keys = jax.random.split(jax.random.key(5), n)
  actions = jnp.linspace(-1.0, 1.0, n)[:, None]
  finals = {}
  for batch, env in envs.items():
    states = jax.jit(jax.vmap(env.reset))(keys)
    offsets = jnp.arange(n) % 4
    states = states.replace(
        episode=states.episode.replace(length=offsets),
        key=jax.vmap(jax.random.fold_in)(states.key, offsets),
    )
    step = jax.jit(jax.vmap(env.step))
    trajectory = []
    for _ in range(9):
      states = step(states, actions)
      trajectory.append(states)
    finals[batch] = trajectory
  ends = [int(np.sum(s.last())) for s in finals[None]]
  assert 0 < min(e for e in ends if e) < n and max(ends) >= 2, ends
  for whole, chunked in zip(finals[None], finals[3]):
    for a, b in zip(jax.tree.leaves(whole), jax.tree.leaves(chunked)):
      if jnp.issubdtype(a.dtype, jax.dtypes.prng_key):
        a, b = jax.random.key_data(a), jax.random.key_data(b)
      np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6)


def test_auto_reset_batch_refusals():
  with pytest.raises(ValueError, match='positive integer'):
    composer.ExecutionOptions(auto_reset_batch=0)
  with pytest.raises(ValueError, match='Set one of them'):
    composer.ExecutionOptions(auto_reset_batch=4, share_reset_forward=True)
  with pytest.raises(ValueError, match="needs impl='jax'"):
    composer.ExecutionOptions(auto_reset_batch=4, impl='warp')
  with pytest.raises(ValueError, match="positive integer, 'auto' or None"):
    composer.ExecutionOptions(auto_reset_batch='half')
  # 'auto' leaves the fused restart and Warp the whole batch's reset.
  composer.ExecutionOptions(auto_reset_batch='auto', share_reset_forward=True)
  composer.ExecutionOptions(auto_reset_batch='auto', impl='warp')


# -- fixed_initial_state -------------------------------------------------------


def _two_episodes(env, length):
  """Observations of a world's first two episodes under the same actions."""
  next_step = env.auto_reset == 'next_step'
  per_episode = length + 1 if next_step else length
  actions = jnp.sin(jnp.arange(per_episode, dtype=jnp.float32))[:, None]
  actions = jnp.concatenate([actions, actions])

  @jax.jit
  def run(key):
    state = env.reset(key)

    def step(state, action):
      state = env.step(state, action)
      return state, (state.observation, state.step_type)

    _, (observations, step_types) = jax.lax.scan(step, state, actions)
    return jax.tree.map(
        lambda first, rest: jnp.concatenate([first[None], rest]),
        (state.observation, state.step_type),
        (observations, step_types),
    )

  observations, step_types = run(jax.random.key(3))
  step_types = np.asarray(step_types)
  first = [i for i, t in enumerate(step_types) if t == 0]
  if not next_step:  # the LAST state holds the next episode's first step
    first = [0] + [i for i, t in enumerate(step_types) if t == 2]
  assert first[:2] == [0, per_episode], step_types
  split = lambda x: (x[:per_episode], x[per_episode : 2 * per_episode])
  return jax.tree.map(split, observations)


@pytest.mark.parametrize('auto_reset', ['same_step', 'next_step'])
def test_fixed_initial_state_repeats_the_first_episode(auto_reset):
  length = 4  # control steps of 0.01 s
  episodes = {
      fixed: _two_episodes(
          conftest.make_swing_env(
              time_limit=0.04,
              fixed_initial_state=fixed,
              options=composer.ExecutionOptions(auto_reset=auto_reset),
          ),
          length,
      )
      for fixed in (True, False)
  }
  for name, (first, second) in episodes[True].items():
    np.testing.assert_array_equal(first, second, err_msg=name)
  # Without it the second episode draws a new pose and target.
  assert any(
      not np.array_equal(first, second)
      for first, second in episodes[False].values()
  )
  assert episodes[True].keys() == episodes[False].keys()


def test_fixed_initial_state_host_environment_resets_alike():
  env = composer.HostEnvironment(
      conftest.make_swing_env(time_limit=0.05, fixed_initial_state=True),
      seed=1,
  )
  first = env.reset().observation
  env.step(np.ones(1))
  second = env.reset().observation
  for name in first:
    np.testing.assert_array_equal(first[name], second[name])


class _CoinTask(conftest.SwingTask):
  """Fails an initialization attempt on a coin toss."""

  def initialize_episode(self, physics, key):
    physics = super().initialize_episode(physics, key)
    heads = jax.random.bernoulli(jax.random.fold_in(key, 7))
    return physics.fail_initialization(heads)


def test_fixed_initial_state_repeats_every_initialization_attempt():
  keys = jax.random.split(jax.random.key(0), 64)
  failures = {}
  for fixed in (True, False):
    env = composer.Environment(
        _CoinTask(), max_reset_attempts=3, fixed_initial_state=fixed
    )
    states = jax.jit(jax.vmap(env.reset))(keys)
    failures[fixed] = set(np.asarray(states.metrics['init_failures']).tolist())
  assert failures[True] == {0, 3}  # the same toss on every attempt
  assert failures[False] >= {0, 1, 2}


# -- ExecutionOptions and the deprecated keywords ------------------------------

# A value for each `ExecutionOptions` field that builds the swing task on the
# CPU, other than the default where one does.
_OPTION_VALUES = {
    'auto_reset': 'same_step',
    'per_world_model_fields': ('geom_rgba',),
    'impl': 'jax',
    'naconmax': 64,
    'njmax': 32,
    'share_reset_forward': False,
    'auto_reset_batch': 2,
    'reset_forward': 'full',
    'substep_sensors': 'all',
    'dirty_forward': 'never',
    'carry_stage': 'never',
    'stored_restart': 'never',
    'branches': 'loop',
}


def test_every_option_field_is_exercised():
  names = {
      field.name for field in dataclasses.fields(composer.ExecutionOptions)
  }
  assert names == set(_OPTION_VALUES)


def test_execution_options_are_frozen_and_hashable():
  options = composer.ExecutionOptions(per_world_model_fields=['geom_rgba'])
  assert options.per_world_model_fields == ('geom_rgba',)
  assert hash(options) == hash(
      composer.ExecutionOptions(per_world_model_fields=('geom_rgba',))
  )
  with pytest.raises(dataclasses.FrozenInstanceError):
    options.impl = 'jax'
  assert dataclasses.replace(options, impl='jax').impl == 'jax'
  with pytest.raises(ValueError, match='sequence of field names'):
    composer.ExecutionOptions(per_world_model_fields='geom_rgba')
  with pytest.raises(ValueError, match='Unknown mjx.Model fields'):
    composer.ExecutionOptions(per_world_model_fields=('no_such_field',))


def test_options_are_resolved_for_the_device():
  with warnings.catch_warnings():
    warnings.simplefilter('error', DeprecationWarning)
    env = conftest.make_swing_env(
        options=composer.ExecutionOptions(naconmax=64, njmax=32)
    )
  # On this CPU the default is 'jax', where Warp's buffer sizes are ignored.
  # The fused restart resets the whole batch: 'auto' resolves to None.
  # What runs once or never is a conditional on a CPU.
  assert env.options == composer.ExecutionOptions(
      impl='jax',
      share_reset_forward=True,
      auto_reset_batch=None,
      branches='cond',
  )
  assert env.impl == env.options.impl
  assert env.share_reset_forward == env.options.share_reset_forward
  assert env.branches == env.options.branches == 'cond'
  assert env.auto_reset == 'next_step' and env.auto_reset_batch is None
  # The separate restart keeps 'auto', resolved by each batch's size.
  separate = conftest.make_swing_env(
      options=composer.ExecutionOptions(share_reset_forward=False)
  )
  assert separate.auto_reset_batch == separate.options.auto_reset_batch
  assert separate.auto_reset_batch == 'auto'


@pytest.mark.parametrize('name', sorted(_OPTION_VALUES))
def test_deprecated_keyword_still_works_and_names_the_new_spelling(name):
  value = _OPTION_VALUES[name]
  with pytest.warns(DeprecationWarning) as record:
    old = conftest.make_swing_env(**{name: value})
  messages = [str(w.message) for w in record]
  assert (
      f'Environment({name}={value!r}) is deprecated: pass '
      f'options=ExecutionOptions({name}={value!r})'
  ) in messages[0], messages
  with warnings.catch_warnings():
    warnings.simplefilter('error', DeprecationWarning)
    new = conftest.make_swing_env(
        options=composer.ExecutionOptions(**{name: value})
    )
  assert old.options == new.options


def test_deprecated_observation_groups_says_to_override_the_task():
  groups = {'tip': composer.ObservationGroup(keys=['tip'])}

  class Grouped(conftest.SwingTask):

    def observation_groups(self):
      return groups

  with pytest.warns(
      DeprecationWarning, match=r'override Task.observation_groups\(\)'
  ):
    old = composer.Environment(conftest.SwingTask(), observation_groups=groups)
  with warnings.catch_warnings():
    warnings.simplefilter('error', DeprecationWarning)
    new = composer.Environment(Grouped())
  assert set(old.observation_spec()) == set(new.observation_spec()) == {'tip'}
  assert old.options == new.options


def test_options_and_a_deprecated_keyword_do_not_mix():
  options = composer.ExecutionOptions(impl='jax')
  with pytest.raises(TypeError, match=r'Environment\(impl=...\) and options'):
    composer.Environment(conftest.SwingTask(), impl='jax', options=options)
  with pytest.raises(TypeError, match='in options=ExecutionOptions'):
    composer.Environment(
        conftest.SwingTask(), auto_reset='same_step', options=options
    )
  with pytest.raises(TypeError, match='takes an ExecutionOptions'):
    composer.Environment(conftest.SwingTask(), options={'impl': 'jax'})


def test_unknown_keyword_names_the_valid_ones():
  with pytest.raises(TypeError, match=r"\['sub_steps'\].*n_sub_steps.*impl"):
    composer.Environment(conftest.SwingTask(), sub_steps=2)


def test_arguments_are_composers_in_composers_order():
  parameters = inspect.signature(composer.Environment).parameters
  assert list(parameters) == [
      'task',
      'time_limit',
      'random_state',
      'n_sub_steps',
      'raise_exception_on_physics_error',
      'strip_singleton_obs_buffer_dim',
      'max_reset_attempts',
      'recompile_mjcf_every_episode',
      'fixed_initial_state',
      'delayed_observation_padding',
      'legacy_step',
      'options',
      'deprecated',
  ]
  assert parameters['options'].kind == inspect.Parameter.KEYWORD_ONLY
  # composer's positional call builds as it would there.
  env = composer.Environment(
      conftest.SwingTask(),
      0.05,
      3,
      None,
      False,
      False,
      2,
      False,
      True,
      composer.ObservationPadding.INITIAL_VALUE,
      False,
  )
  assert env.time_limit == 0.05 and env.fixed_initial_state


# The fused step program of each auto-reset mode (`Transitions`' method).
_FUSED = {'next_step': 'reset_or_step', 'same_step': 'step_and_restart'}


class _Transitions:
  """A stand-in whose step programs say which they are (and whether they
  were asked for conditionals); its restarts run the reset
  (`stored_restart`: None)."""

  stored_restart = None

  def __init__(self, stored_restart_mode='never'):
    self.stored_restart_mode = stored_restart_mode

  def reset_or_step(self, state, action, conditional=False):
    return 'reset_or_step', conditional

  def step_and_restart(self, state, action, conditional=False):
    return 'step_and_restart', conditional


@pytest.mark.parametrize('auto_reset', ['next_step', 'same_step'])
@pytest.mark.parametrize('fuse', [True, False])
@pytest.mark.parametrize('conditional', [True, False])
def test_the_step_program_is_chosen_once(auto_reset, fuse, conditional):
  transitions = _Transitions()
  program = auto_reset_lib.step_program(
      transitions,
      auto_reset=auto_reset,
      fuse=fuse,
      chunk=None,
      conditional=conditional,
  )
  if fuse:
    assert program.func == getattr(transitions, _FUSED[auto_reset])
    assert program(None, None) == (_FUSED[auto_reset], conditional)
  else:
    # pylint: disable=protected-access
    separate = {
        'next_step': auto_reset_lib._step_or_reset,
        'same_step': auto_reset_lib._step_then_restart,
    }
    # pylint: enable=protected-access
    assert program.func is separate[auto_reset]
    assert program.args == (transitions, None, conditional)


@pytest.mark.parametrize('auto_reset', ['next_step', 'same_step'])
def test_a_restart_that_cannot_be_restored_runs_the_reset(auto_reset):
  # stored_restart='auto' asks, when the step is traced, whether the
  # restart may restore the first state; where not, the fused step runs.
  program = auto_reset_lib.step_program(
      _Transitions('auto'), auto_reset=auto_reset, fuse=True, chunk=None
  )
  assert program(None, None) == (_FUSED[auto_reset], False)
