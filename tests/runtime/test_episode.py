"""Episode rules: the step limit, divergence and non-finite values.

`test_environment.py` checks termination, truncation, divergence and both
auto-reset modes through a composed environment; `test_nonfinite.py` the
non-finite flags through one, on both backends.
"""

import math
import re

import jax
import jax.numpy as jnp
import pytest

import mjx_composer as composer
from mjx_composer import physics as physics_lib
from mjx_composer.runtime import episode
from tests import conftest


@pytest.mark.parametrize(
    'time_limit, control_timestep, expected',
    [
        (0.05, 0.01, 5),  # 0.05 / 0.01 is 5.000000000000001 in floats
        (0.051, 0.01, 6),
        (0.001, 0.01, 1),
        (math.inf, 0.01, math.inf),
    ],
)
def test_step_limit_counts_whole_control_steps(
    time_limit, control_timestep, expected
):
  assert episode.step_limit(time_limit, control_timestep) == expected


def test_diverged_flags_any_non_finite_state():
  class Data:
    qpos = jnp.zeros(3)
    qvel = jnp.zeros(2)
    qacc = jnp.zeros(2)
    act = jnp.zeros(0)

  assert not bool(episode.diverged(Data))
  Data.qacc = jnp.array([0.0, jnp.nan])
  assert bool(episode.diverged(Data))
  Data.qacc = jnp.zeros(2)
  Data.qvel = jnp.array([jnp.inf, 0.0])
  assert bool(episode.diverged(Data))


def test_checked_action_zeroes_a_nonfinite_action_as_a_whole():
  action = jnp.array([0.5, -0.25, 1.0])
  checked, bad = episode.checked_action(action)
  assert not bool(bad)
  assert bool(jnp.all(checked == action))
  for value in (jnp.nan, jnp.inf, -jnp.inf):
    checked, bad = episode.checked_action(action.at[1].set(value))
    assert bool(bad)
    assert bool(jnp.all(checked == 0.0))


def test_zero_nonfinite_keeps_finite_entries_and_integers():
  tree = {
      'x': jnp.array([1.5, jnp.nan, -jnp.inf, 2.0]),
      'count': jnp.array([3, 4], jnp.int32),
  }
  assert not bool(episode.finite(tree))
  zeroed = episode.zero_nonfinite(tree)
  assert zeroed['x'].tolist() == [1.5, 0.0, 0.0, 2.0]
  assert zeroed['count'].dtype == jnp.int32
  assert zeroed['count'].tolist() == [3, 4]
  assert bool(episode.finite(zeroed))
  assert bool(episode.finite({}))


def test_nonfinite_initial_state_reads_what_the_physics_starts_from():
  class Data:
    qpos = jnp.zeros(7)
    qvel = jnp.zeros(6)
    act = jnp.zeros(0)
    ctrl = jnp.zeros(1)
    mocap_pos = jnp.zeros((1, 3))
    mocap_quat = jnp.array([[1.0, 0.0, 0.0, 0.0]])

  assert not bool(episode.nonfinite_initial_state(Data))
  for name in ('qpos', 'qvel', 'ctrl', 'mocap_pos', 'mocap_quat'):
    clean = getattr(Data, name)
    setattr(Data, name, clean.at[(0,) * clean.ndim].set(jnp.nan))
    assert bool(episode.nonfinite_initial_state(Data)), name
    setattr(Data, name, clean)


# -- the outcome methods read; a write is refused while tracing ------------


class _CountingTask(conftest.SwingTask):
  """Counts control steps in the task state, in the hook `where` names
  (`'after_step'`, composer's place for it here, or an outcome method that
  writes, as dm_control tasks count in `get_reward`)."""

  def __init__(self, where):
    super().__init__()
    self.where = where

  def initial_task_state(self):
    return {'target': jnp.zeros(()), 'steps': jnp.zeros((), jnp.int32)}

  def _counted(self, physics):
    return physics.update_task_state(steps=physics.task_state['steps'] + 1)

  def after_step(self, physics, key):
    del key
    return self._counted(physics) if self.where == 'after_step' else physics

  def get_reward(self, physics):
    if self.where == 'get_reward':
      self._counted(physics)
    if self.where == 'get_reward returns it':
      return physics.task_state['steps'], physics
    # A forward pass only computes what the read needs: allowed.
    return jnp.float32(physics.forward().task_state['steps'])

  def get_discount(self, physics):
    if self.where == 'get_discount':
      physics.set_persistent('seen', jnp.ones(()))
    return 1.0

  def should_terminate_episode(self, physics):
    if self.where == 'should_terminate_episode':
      physics.bind(self.pendulum.joint).set(qpos=jnp.zeros(1))
    return False

  def get_metrics(self, physics):
    if self.where == 'get_metrics':
      physics.set_control(jnp.zeros(1))
    return {'steps': physics.task_state['steps']}


def _reset_and_step(env):
  def run(key):
    state = env.reset(key)
    return env.step(state, jnp.zeros(env.action_spec().shape))

  return jax.eval_shape(run, jax.random.key(0))


@pytest.mark.parametrize(
    'where, write',
    [
        ('get_reward', 'update_task_state()'),
        ('get_discount', 'set_persistent()'),
        ('should_terminate_episode', 'a write of qpos'),
        ('get_metrics', 'a write of ctrl'),
    ],
)
def test_an_outcome_method_that_writes_is_refused_naming_it(where, write):
  env = composer.Environment(_CountingTask(where), time_limit=0.05)
  with pytest.raises(
      physics_lib.ReadOnlyPhysicsError,
      match=rf'_CountingTask\.{where} .*called {re.escape(write)} .*'
      r'after_step',
  ):
    _reset_and_step(env)


def test_an_outcome_method_that_returns_a_physics_is_refused():
  env = composer.Environment(
      _CountingTask('get_reward returns it'), time_limit=0.05
  )
  with pytest.raises(
      physics_lib.ReadOnlyPhysicsError,
      match=r'_CountingTask\.get_reward returned a Physics.*after_step',
  ):
    _reset_and_step(env)


def test_a_count_kept_in_after_step_is_what_the_reward_reads():
  env = composer.Environment(_CountingTask('after_step'), time_limit=0.05)
  step = jax.jit(env.step)
  state = jax.jit(env.reset)(jax.random.key(0))
  assert float(state.metrics['steps']) == 0
  for n in (1, 2, 3):
    state = step(state, jnp.zeros(env.action_spec().shape))
    assert float(state.reward) == n
    assert float(state.metrics['steps']) == n
