"""A distribution's parameters, checked at construction as numpy checks them.

`numpy.random` refuses invalid parameters at each draw (a negative `scale`,
a probability outside [0, 1], `low >= high` for integers, shapes that do not
broadcast); a jitted draw would return wrong samples without an error. So
`distributions` checks them when a distribution is built: constants by
value, variations by their `static_bounds()` where known (a `Domain` per
parameter; `check_shapes` for the constants' shapes).
"""

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer.variation import arrays as arrays_lib
from mjx_composer.variation import base
from mjx_composer.variation import bounds as bounds_lib


def int_dtype():
  """The default integer type: what numpy's integer samplers return."""
  return jnp.result_type(int)


class Domain:
  """The values a parameter may take, checked on its static bounds."""

  def __init__(self, requirement, valid, fix):
    self.requirement = requirement  # "must be ..." in the message.
    self.valid = valid  # (low, high) bound arrays -> all valid.
    self.fix = fix

  def check(self, owner, name, value):
    """Raises for a constant, or bounded variation, outside the domain."""
    if not base.contains_variation(value) and not callable(value):
      array = arrays_lib.numeric_array(value)
      if array is None:
        if isinstance(value, jax.core.Tracer):
          return  # Traced (inside a user's jit): checked by no one here.
        raise TypeError(
            f"{owner}: `{name}` must be a number, array or variation, got "
            f"{value!r}. {self.fix}"
        )
    bounds = bounds_lib.static_bounds(value)
    if bounds is None:
      return  # An unbounded variation: its draws cannot be checked here.
    low, high = (np.asarray(b, dtype=float) for b in bounds)
    with np.errstate(invalid="ignore"):
      ok = bool(np.all(self.valid(low, high)))
    if not ok:
      if base.contains_variation(value):
        got = (
            f"a variation with values in [{_brief(low)}, {_brief(high)}] "
            f"({value!r})"
        )
      else:
        got = repr(value)
      raise ValueError(
          f"{owner}: `{name}` must be {self.requirement}, got {got}. "
          f"{self.fix}"
      )


def below(low, high):
  """False if some `low` may be >= `high` (True when bounds are unknown)."""
  low_bounds = bounds_lib.static_bounds(low)
  high_bounds = bounds_lib.static_bounds(high)
  if low_bounds is None or high_bounds is None:
    return True
  return bool(np.all(np.asarray(low_bounds[1]) < np.asarray(high_bounds[0])))


def _brief(array):
  return np.array2string(np.asarray(array), threshold=6)


def _finite(low, high):
  return np.isfinite(low) & np.isfinite(high)


FINITE = Domain("finite", _finite, "Pass finite values.")
NONNEGATIVE = Domain(
    "finite and >= 0 (numpy.random refuses negative ones)",
    lambda low, high: _finite(low, high) & (low >= 0),
    "Pass values >= 0.",
)
PROBABILITY = Domain(
    "a probability in [0, 1] (numpy.random refuses others)",
    lambda low, high: _finite(low, high) & (low >= 0) & (high <= 1),
    "Pass values between 0 and 1.",
)


def _poisson_max():
  """numpy's largest rate for int64 samples, for the default integer type."""
  maximum = float(np.iinfo(int_dtype()).max)
  return maximum - 10 * np.sqrt(maximum)


RATE = Domain(
    "finite, >= 0 and small enough for the integer type (numpy.random "
    "refuses others)",
    lambda low, high: _finite(low, high)
    & (low >= 0)
    & (high <= _poisson_max()),
    "Pass a rate >= 0 (and below about 2e9 for int32 samples, without x64).",
)


def _integral(low, high):
  return _finite(low, high) & (low == np.round(low)) & (high == np.round(high))


INTEGER = Domain(
    "integers", _integral, "Pass integer bounds, e.g. UniformInteger(0, 5)."
)


def shape_list(shapes):
  """`name` shape, ... for a message about shapes that do not broadcast."""
  return ", ".join(f"`{name}` {shape}" for name, shape in shapes.items())


def check_shapes(owner, params):
  """Raises if constant parameters' shapes do not broadcast together.

  numpy's samplers refuse them too ("shape mismatch"); checked here, at
  construction, rather than inside JAX's broadcasting when a world draws.
  Variation parameters are left out: their values' shapes are known only
  when they are drawn.
  """
  shapes = {}
  for name, value in params.items():
    if value is None or callable(value) or base.contains_variation(value):
      continue
    array = arrays_lib.numeric_array(value)
    if array is None:
      continue
    try:
      np.broadcast_shapes(*shapes.values(), array.shape)
    except ValueError:
      raise ValueError(
          f"{owner}: `{name}` has shape {array.shape}, which does not "
          f"broadcast with {shape_list(shapes)}. Pass parameters of one "
          "shape, or shapes that broadcast together (e.g. a scalar and an "
          "array), as numpy's samplers require."
      ) from None
    shapes[name] = array.shape
