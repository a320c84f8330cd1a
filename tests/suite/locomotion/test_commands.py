"""VelocityCommand: draws, the resampling schedule, standing and heading.

The command only reads and writes task state, so these tests drive it on a
`Physics` holding nothing but its task state, jitted and batched over keys.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_composer import physics as physics_lib
from mjx_composer.suite.locomotion import commands

_KEYS = 4096


def _physics(command):
  return physics_lib.Physics(
      model=None, data=None, task_state=command.initial_state()
  )


def _rollout(command, steps, key, yaws=None):
  """Task states after reset and after each of `steps` steps (stacked)."""
  yaws = jnp.zeros(steps + 1) if yaws is None else jnp.asarray(yaws)
  heading = lambda i: None if command.heading_range is None else yaws[i]

  def run(key):
    physics = command.reset(_physics(command), key, heading=heading(0))
    states = [physics.task_state]
    for i in range(steps):
      physics = command.step(
          physics, jax.random.fold_in(key, i), heading=heading(i + 1)
      )
      states.append(physics.task_state)
    return jax.tree.map(lambda *x: jnp.stack(x), *states)

  return jax.device_get(jax.jit(jax.vmap(run))(jax.random.split(key, _KEYS)))


def test_draws_are_uniform_in_the_ranges_and_resampled_every_k_steps():
  command = commands.VelocityCommand(
      (0.5, 1.5), (-0.3, 0.2), (-1.0, -0.5), resample_interval=3
  )
  states = _rollout(command, 10, jax.random.key(0))
  velocity = states['command']  # (keys, 11, 3)
  low, high = np.array([0.5, -0.3, -1.0]), np.array([1.5, 0.2, -0.5])
  assert np.all((velocity >= low) & (velocity <= high))
  # Uniform: the mean of each entry is the middle of its range.
  np.testing.assert_allclose(
      velocity[:, 0].mean(axis=0), (low + high) / 2, atol=0.02
  )
  changed = np.any(velocity[:, 1:] != velocity[:, :-1], axis=-1).all(axis=0)
  # Steps 4, 7, 10 of the episode begin with a new draw (3 steps done).
  np.testing.assert_array_equal(np.flatnonzero(changed) + 1, [4, 7, 10])
  assert not np.any(
      np.any(velocity[:, 1:] != velocity[:, :-1], axis=-1)[:, ~changed]
  )


def test_standing_share_zeroes_that_share_of_the_draws():
  command = commands.VelocityCommand(
      (0.5, 1.0),
      (0.5, 1.0),
      (0.5, 1.0),
      resample_interval=1,
      standing_share=0.25,
  )
  states = _rollout(command, 2, jax.random.key(1))
  standing = states['command_standing']
  assert abs(standing.mean() - 0.25) < 0.02
  np.testing.assert_array_equal(states['command'][standing], 0.0)
  assert np.all(states['command'][~standing] >= 0.5)


def test_heading_control_turns_towards_the_drawn_heading():
  command = commands.VelocityCommand(
      ang_vel_z=(-1.0, 1.0),
      heading_range=(-np.pi, np.pi),
      heading_stiffness=0.5,
      resample_interval=0,
  )
  yaws = np.linspace(-3.0, 3.0, 5)
  states = _rollout(command, 4, jax.random.key(2), yaws)
  target = states['command_heading']
  error = (target - yaws + np.pi) % (2 * np.pi) - np.pi
  want = np.clip(0.5 * error, -1.0, 1.0)
  np.testing.assert_allclose(states['command'][..., 2], want, atol=1e-5)
  assert np.all(target == target[:, :1])  # Drawn once: never resampled.
  with pytest.raises(ValueError, match='heading'):
    command.reset(_physics(command), jax.random.key(0))


def test_playgrounds_rule_keeps_or_zeroes_entries():
  command = commands.VelocityCommand(
      (-1.0, 1.0),
      (-1.0, 1.0),
      (-1.0, 1.0),
      resample_interval=1,
      keep_probability=0.5,
      zero_probability=(0.1, 0.75, 0.5),
  )
  # With k = 1 the second step begins with the first resample.
  states = _rollout(command, 2, jax.random.key(3))
  first, second = states['command'][:, 1], states['command'][:, 2]
  assert np.all(first != 0)  # The episode's first draw is never zeroed.
  kept = second == first
  np.testing.assert_allclose(kept.mean(axis=0), 0.5, atol=0.03)
  zeroed = np.mean(second[~kept.all(axis=1)] == 0, axis=0)
  # A changed entry is zero with probability zero_probability.
  changed = ~kept
  np.testing.assert_allclose(
      (second == 0).sum(axis=0) / changed.sum(axis=0),
      [0.1, 0.75, 0.5],
      atol=0.04,
  )
  assert zeroed[1] > zeroed[0]


@pytest.mark.parametrize(
    'kwargs, match',
    [
        ({'lin_vel_x': (1.0, -1.0)}, 'lin_vel_x'),
        ({'ang_vel_z': (0.0, float('nan'))}, 'ang_vel_z'),
        ({'resample_interval': 2.5}, 'resample_interval'),
        ({'resample_interval': -1}, 'resample_interval'),
        ({'standing_share': 1.5}, 'standing_share'),
        ({'zero_probability': (0.1, 0.2)}, 'zero_probability'),
        ({'heading_range': (1.0,)}, 'heading_range'),
    ],
)
def test_bad_arguments_are_refused_by_name(kwargs, match):
  with pytest.raises((TypeError, ValueError), match=match):
    commands.VelocityCommand(**kwargs)
