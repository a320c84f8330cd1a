"""dm_control's shaped rewards (`dm_control.utils.rewards`), in `jax.numpy`.

`tolerance(x, bounds, margin, sigmoid, value_at_margin)`: 1 inside the
bounds, falling off outside them along one of dm_control's sigmoids; the
reward of dm_control's suite and of MuJoCo Playground's dm_control tasks.
"""

import jax.numpy as jnp
import numpy as np

# dm_control's default value at the margin.
_DEFAULT_VALUE_AT_MARGIN = 0.1


def _sigmoids(x, value_at_1, sigmoid):
  """dm_control's sigmoids: 1 at x = 0, `value_at_1` at |x| = 1."""
  if sigmoid == 'gaussian':
    scale = np.sqrt(-2 * np.log(value_at_1))
    return jnp.exp(-0.5 * (x * scale) ** 2)
  if sigmoid == 'hyperbolic':
    scale = np.arccosh(1 / value_at_1)
    return 1 / jnp.cosh(x * scale)
  if sigmoid == 'long_tail':
    scale = np.sqrt(1 / value_at_1 - 1)
    return 1 / ((x * scale) ** 2 + 1)
  if sigmoid == 'reciprocal':
    scale = 1 / value_at_1 - 1
    return 1 / (jnp.abs(x) * scale + 1)
  if sigmoid == 'cosine':
    scale = np.arccos(2 * value_at_1 - 1) / np.pi
    scaled = x * scale
    inside = jnp.abs(scaled) < 1
    return jnp.where(inside, (1 + jnp.cos(np.pi * scaled)) / 2, 0.0)
  if sigmoid == 'linear':
    scaled = x * (1 - value_at_1)
    return jnp.where(jnp.abs(scaled) < 1, 1 - scaled, 0.0)
  if sigmoid == 'quadratic':
    scaled = x * np.sqrt(1 - value_at_1)
    return jnp.where(jnp.abs(scaled) < 1, 1 - scaled**2, 0.0)
  if sigmoid == 'tanh_squared':
    scale = np.arctanh(np.sqrt(1 - value_at_1))
    return 1 - jnp.tanh(x * scale) ** 2
  raise ValueError(f'Unknown sigmoid type {sigmoid!r}.')


def tolerance(
    x,
    bounds=(0.0, 0.0),
    margin=0.0,
    sigmoid='gaussian',
    value_at_margin=_DEFAULT_VALUE_AT_MARGIN,
):
  """1 where `bounds[0] <= x <= bounds[1]`, decaying outside (dm_control's).

  Args:
    x: the value(s) to judge.
    bounds: (lower, upper); either may be infinite.
    margin: how far outside the bounds the reward falls to
      `value_at_margin`; 0 makes the reward a step function of the bounds.
    sigmoid: the decay's shape: 'gaussian', 'hyperbolic', 'long_tail',
      'reciprocal', 'cosine', 'linear', 'quadratic' or 'tanh_squared'.
    value_at_margin: the reward at distance `margin` from the bounds.

  Returns:
    A float32 array of `x`'s shape, in [0, 1].

  Raises:
    ValueError: for `bounds[0] > bounds[1]` or a negative `margin`.
  """
  lower, upper = bounds
  if lower > upper:
    raise ValueError('Lower bound must be <= upper bound.')
  if margin < 0:
    raise ValueError('`margin` must be non-negative.')
  x = jnp.asarray(x, jnp.float32)
  in_bounds = jnp.logical_and(lower <= x, x <= upper)
  if margin == 0:
    return jnp.where(in_bounds, 1.0, 0.0)
  # Outside the bounds exactly one of the two distances is positive; inside,
  # the result is masked (and an infinite bound must not make a NaN there).
  distance = jnp.where(
      x < lower, lower - x, jnp.where(x > upper, x - upper, 0.0)
  )
  return jnp.where(
      in_bounds, 1.0, _sigmoids(distance / margin, value_at_margin, sigmoid)
  )
