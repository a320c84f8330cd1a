"""Episode rules: the step limit, divergence and non-finite values.

`test_environment.py` checks termination, truncation, divergence and both
auto-reset modes through a composed environment; `test_nonfinite.py` the
non-finite flags through one, on both backends.
"""

import math

import jax.numpy as jnp
import pytest

from mjx_composer.runtime import episode


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
