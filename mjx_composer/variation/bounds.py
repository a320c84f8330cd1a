"""Static bounds: what a variation's values are known to lie in, at build time.

`static_bounds(value)` gives `(low, high)` for a variation (its own
`Variation.static_bounds`), a constant (its own bounds) or a structure of
them, or `None` where they are not known statically; callers size buffers
with them (e.g. an observable's variation-valued `delay`). `extremes` and
`as_bounds` are what nodes compute their own bounds with.
"""

import functools
from typing import Optional, Tuple

import numpy as np
import tree

from mjx_composer.variation import arrays
from mjx_composer.variation import base

Bounds = Tuple[np.ndarray, np.ndarray]


def static_bounds(value) -> Optional[Bounds]:
  """`(low, high)` for a variation, a constant or a structure of them.

  Constants are their own bounds. A (nested) list of scalar-valued
  variations and constants gets elementwise bounds. Returns `None` when any
  part is unbounded or not statically known.
  """
  if isinstance(value, base.Variation):
    return value.static_bounds()
  if callable(value):
    return None
  if tree.is_nested(value) and base.contains_variation(value):
    leaves = tree.flatten(value)
    bounds = [static_bounds(leaf) for leaf in leaves]
    if any(b is None for b in bounds):
      return None
    low = arrays.numeric_array(tree.unflatten_as(value, [b[0] for b in bounds]))
    high = arrays.numeric_array(
        tree.unflatten_as(value, [b[1] for b in bounds])
    )
    if low is None or high is None:
      return None
    return low, high
  array = arrays.numeric_array(value)
  if array is None:
    return None
  return array, array


def extremes(candidates) -> Bounds:
  """Elementwise min and max over arrays that broadcast together."""
  return as_bounds(
      functools.reduce(np.minimum, candidates),
      functools.reduce(np.maximum, candidates),
  )


def as_bounds(low, high) -> Bounds:
  """`(low, high)` as numpy arrays."""
  return np.asarray(low), np.asarray(high)
