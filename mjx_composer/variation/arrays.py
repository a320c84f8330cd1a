"""Values as arrays: what nodes convert their evaluated operands with.

`numeric_array` (a numeric numpy array, or `None`: for static bounds and
comparisons of construction arguments), `as_array` (an evaluated operand as
a `jnp` array) and `float_dtype` (the floating dtype of a result).
"""

from typing import Optional

import jax.numpy as jnp
import numpy as np


def numeric_array(value) -> Optional[np.ndarray]:
  """`np.asarray(value)` if that gives a numeric array, else `None`."""
  try:
    array = np.asarray(value)
  except (ValueError, TypeError):
    return None
  if array.dtype.kind not in "biuf":
    return None
  return array


def as_array(value):
  """Converts an evaluated operand (maybe a list of arrays) to a jnp array."""
  return None if value is None else jnp.asarray(value)


def float_dtype(*values):
  """Floating dtype of a result computed from `values` (default float)."""
  return jnp.result_type(*[v for v in values if v is not None], float)
