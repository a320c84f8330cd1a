"""Tests for `stored_restart`: auto-resets restored from the first state.

Where every restart of a world is its first reset's function of the
episode's key and what depends on the key needs nothing else, `step`
restores a copy of the world's first state and draws the rest from the
key. These tests hold its episodes to those of the step that runs the reset
(`ExecutionOptions(stored_restart='never')`), check that the step program
then holds no reset, and that the reset runs wherever a restart could
differ from the first state otherwise.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.runtime import stored_restart
from tests import conftest
from tests import jaxprs
from tests.runtime import test_transitions

_WORLDS = 3
_STEPS = 10  # two episodes of 4 control steps and the next one's start


class _FixedPoseSwing(conftest.SwingTask):
  """Every episode starts from one pose; the target height is drawn. Its
  task state holds a key that does not depend on the episode's (a value
  NumPy cannot hold)."""

  def initial_task_state(self):
    return {'target': jnp.zeros(()), 'seed': jax.random.key(7)}

  def initialize_episode(self, physics, key):
    physics = physics.bind(self.pendulum.joint).set(qpos=jnp.array([0.5]))
    physics = self.ball.set_pose(physics, position=jnp.array([0.2, 0.1, 0.3]))
    return physics.update_task_state(
        target=jax.random.uniform(key, (), minval=0.6, maxval=0.9)
    )


class _CountingSwing(conftest.SwingTask):
  """Counts its episodes in a persistent entry, which the reset reads."""

  def initialize_episode(self, physics, key):
    physics = super().initialize_episode(physics, key)
    episodes = physics.get_persistent('episodes', jnp.zeros((), jnp.int32))
    return physics.set_persistent('episodes', episodes + 1)


class _RandomizedFixedPoseSwing(
    test_transitions._RandomizedSwing, _FixedPoseSwing
):
  """`_FixedPoseSwing` with the ball's size drawn per episode: a per-world
  model field."""


def _env(task, auto_reset='same_step', stored='auto', **kwargs):
  return composer.Environment(
      task,
      time_limit=0.04,
      options=composer.ExecutionOptions(
          auto_reset=auto_reset, stored_restart=stored
      ),
      **kwargs,
  )


def _episodes(env):
  """The first state and every stepped state of `_WORLDS` worlds under
  per-world actions, as one batch with a leading step axis (without the
  copies of the first state)."""
  actions = jnp.sin(
      jnp.arange(_STEPS * _WORLDS, dtype=jnp.float32).reshape(
          _STEPS, _WORLDS, 1
      )
  )

  @jax.jit
  def run(keys):
    state = jax.vmap(env.reset)(keys)

    def step(state, action):
      state = jax.vmap(env.step)(state, action)
      return state, state.replace(stored_first=None)

    _, states = jax.lax.scan(step, state, actions)
    first = state.replace(stored_first=None)
    return jax.tree.map(
        lambda f, rest: jnp.concatenate([f[None], rest]), first, states
    )

  states = run(jax.random.split(jax.random.key(5), _WORLDS))
  return jax.tree.map(_plain, states)


def _plain(leaf):
  if jnp.issubdtype(leaf.dtype, jax.dtypes.prng_key):
    leaf = jax.random.key_data(leaf)
  return np.asarray(leaf)


def _assert_same_episodes(restored, run):
  """The same states, but the first state's derived fields that the step
  program's reset recomputes, which may differ in their last bits."""
  paths = jax.tree_util.tree_flatten_with_path(restored)[0]
  for (path, ours), theirs in zip(paths, jax.tree.leaves(run)):
    name = jax.tree_util.keystr(path)
    if ours.dtype.kind == 'f':
      np.testing.assert_allclose(
          ours, theirs, rtol=1e-6, atol=1e-6, err_msg=name
      )
    else:
      np.testing.assert_array_equal(ours, theirs, err_msg=name)


@pytest.mark.parametrize('auto_reset', ['same_step', 'next_step'])
def test_restarts_restore_the_first_state_and_draw_the_rest(auto_reset):
  envs = {
      stored: _env(_FixedPoseSwing(), auto_reset, stored)
      for stored in ('auto', 'never')
  }
  assert envs['auto'].stored_restart
  assert not envs['never'].stored_restart
  restored, run = (_episodes(envs[stored]) for stored in ('auto', 'never'))
  firsts = restored.step_type == composer.StepType.FIRST
  if auto_reset == 'same_step':  # the restarted state is reported as LAST
    firsts = (restored.episode.length == 0) & (
        restored.step_type != composer.StepType.FIRST
    )
    firsts[0] = True
  starts = np.argwhere(firsts.all(axis=1))[:, 0]
  assert len(starts) >= 3, starts  # the first and two restarts
  _assert_same_episodes(restored, run)
  targets = restored.task_state['target'][starts]
  # The pose repeats bit for bit; the target is drawn again.
  for start in starts[1:]:
    np.testing.assert_array_equal(
        restored.data.qpos[start], restored.data.qpos[0]
    )
    np.testing.assert_array_equal(
        restored.data.xpos[start], restored.data.xpos[0]
    )
  assert len(np.unique(targets)) == targets.size


def test_the_step_program_holds_no_reset():
  env = _env(_FixedPoseSwing())
  separate = composer.Environment(
      _FixedPoseSwing(),
      time_limit=0.04,
      options=composer.ExecutionOptions(
          auto_reset='same_step',
          stored_restart='never',
          share_reset_forward=False,
      ),
  )
  state = jax.eval_shape(env.reset, jax.random.key(0))
  action = jnp.zeros(1)

  def size(step, state):
    jaxpr = jax.make_jaxpr(step)(state, action).jaxpr
    return sum(1 for _ in jaxprs.equations(jaxpr))

  # pylint: disable-next=protected-access
  alone = size(env._transitions.step, state)
  restoring = size(env.step, state)
  running = size(
      separate.step, jax.eval_shape(separate.reset, jax.random.key(0))
  )
  # The restore, a select and the target's draw, against a reset.
  assert restoring - alone < (running - alone) / 10, (alone, restoring, running)


def test_what_the_key_does_not_draw_is_kept_once_on_the_host():
  env = _env(_FixedPoseSwing())
  state = jax.jit(env.reset)(jax.random.key(2))
  plan = env._transitions.stored_restart  # pylint: disable=protected-access
  # The same for every world: no copy in the state.
  assert state.stored_first is None
  leaves = jax.tree.leaves(state)
  for i, value in zip(plan.stored, plan.constants):
    # Keys are kept as their data.
    np.testing.assert_array_equal(
        _plain(leaves[i]), getattr(value, 'data', value)
    )
  # What depends on the key is computed, not kept: the target and the key
  # the next step takes; never the physics.
  paths = [
      jax.tree_util.keystr(path)
      for path, _ in jax.tree_util.tree_flatten_with_path(state)[0]
  ]
  computed = {paths[i] for i in plan.computed}
  assert {".task_state['target']", '.key'} <= computed
  assert not any(path.startswith('.data.') for path in computed)
  np.testing.assert_array_equal(
      _plain(state.task_state['seed']), _plain(jax.random.key(7))
  )


def test_fixed_initial_state_restores_every_leaf():
  # Next-step's restart takes the same restore (the test above); the swing
  # task's step compiles slowly, so one mode here.
  auto_reset = 'same_step'
  envs = {
      stored: composer.Environment(
          conftest.SwingTask(),
          time_limit=0.04,
          fixed_initial_state=True,
          options=composer.ExecutionOptions(
              auto_reset=auto_reset, stored_restart=stored
          ),
      )
      for stored in ('auto', 'never')
  }
  plan = envs['auto']._transitions.stored_restart  # pylint: disable=protected-access
  assert plan is not None and not plan.computed
  # Each world keeps its own first state, drawn from its first key.
  state = jax.jit(envs['auto'].reset)(jax.random.key(2))
  for copy, leaf in zip(
      state.stored_first, jax.tree.leaves(state.replace(stored_first=None))
  ):
    np.testing.assert_array_equal(_plain(copy), _plain(leaf))
  # The swing task draws its pose: without fixed_initial_state it runs.
  assert not conftest.make_swing_env(time_limit=0.04).stored_restart
  restored, run = (_episodes(envs[stored]) for stored in ('auto', 'never'))
  _assert_same_episodes(restored, run)


@pytest.mark.parametrize(
    'task, why',
    [
        (conftest.SwingTask, 'the pose is drawn from the key'),
        (_CountingSwing, 'a persistent entry is carried'),
        (_RandomizedFixedPoseSwing, 'a model field is carried'),
    ],
)
def test_the_reset_runs_where_a_restart_may_differ(task, why):
  env = _env(task())
  assert not env.stored_restart, why
  state = jax.eval_shape(env.reset, jax.random.key(0))
  assert state.stored_first is None


def test_fixed_initial_state_runs_the_reset_where_state_is_carried():
  env = _env(_CountingSwing(), fixed_initial_state=True)
  assert not env.stored_restart
  episodes = jax.jit(env.reset)(jax.random.key(0)).persistent['episodes']
  assert episodes == 1


def test_carries_nothing_reads_the_carried_fields():
  state = jax.eval_shape(
      _env(_FixedPoseSwing()).reset, jax.random.key(0)
  ).replace(stored_first=None)
  assert stored_restart.carries_nothing(state)
  assert not stored_restart.carries_nothing(
      state.replace(persistent={'episodes': jnp.zeros(())})
  )
  assert not stored_restart.carries_nothing(
      state.replace(model_fields={'geom_size': jnp.zeros((3, 3))})
  )


def test_an_unknown_choice_is_refused():
  with pytest.raises(ValueError, match="stored_restart must be 'auto' or"):
    composer.ExecutionOptions(stored_restart='always')


def test_without_a_cpu_backend_the_reset_runs(monkeypatch):
  devices = jax.devices

  def no_cpu(backend=None):
    if backend == 'cpu':
      raise RuntimeError('Unknown backend cpu')  # as with JAX_PLATFORMS=cuda
    return devices(backend)

  env = _env(_FixedPoseSwing())
  monkeypatch.setattr(jax, 'devices', no_cpu)
  assert not env.stored_restart
