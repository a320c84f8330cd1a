"""Episode rules: the step limit and divergence.

`test_environment.py` checks termination, truncation, divergence and both
auto-reset modes through a composed environment.
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
