"""Flattening a dict of observations into one vector, with a matching spec.

    flattener = Flattener(updater.observation_spec()['policy'])
    flattener.spec            # BoundedArray or Array of shape (D,)
    vector = flattener(obs)   # jnp array (..., D); leading batch axes kept

The key order is the spec dict's order (fixed on the host), and every offset
is static, so on the device a flatten is one reshape per entry and a concat.
"""

import collections
from typing import Mapping

from dm_env import specs
import jax.numpy as jnp
import numpy as np


class Flattener:
  """Flattens `{key: array}` dicts laid out like a given dict of specs.

  Attributes:
    keys: the keys, in flattening order.
    slices: `{key: slice}` into the flat vector.
    spec: the flat vector's spec, shape `(D,)`: a `BoundedArray` when some
      entry is bounded (unbounded entries get -inf/inf), else an `Array`.
  """

  def __init__(
      self, spec_dict: Mapping[str, specs.Array], dtype=jnp.float32, name=None
  ):
    if not isinstance(spec_dict, Mapping):
      raise TypeError(
          'Flattener needs a dict of specs, got ' f'{type(spec_dict).__name__}.'
      )
    self.keys = tuple(spec_dict.keys())
    self._shapes = {k: tuple(spec_dict[k].shape) for k in self.keys}
    self._dtype = np.dtype(dtype)
    self.slices = collections.OrderedDict()
    offset = 0
    for k in self.keys:
      size = int(np.prod(self._shapes[k], dtype=np.int64))
      self.slices[k] = slice(offset, offset + size)
      offset += size
    self.size = offset
    bounded = [
        k for k in self.keys if isinstance(spec_dict[k], specs.BoundedArray)
    ]
    if bounded:
      lows, highs = [], []
      for k in self.keys:
        spec, shape = spec_dict[k], self._shapes[k]
        if isinstance(spec, specs.BoundedArray):
          low = np.broadcast_to(np.asarray(spec.minimum, np.float64), shape)
          high = np.broadcast_to(np.asarray(spec.maximum, np.float64), shape)
        else:
          low, high = np.full(shape, -np.inf), np.full(shape, np.inf)
        lows.append(low.ravel())
        highs.append(high.ravel())
      self.spec = specs.BoundedArray(
          shape=(self.size,),
          dtype=self._dtype,
          minimum=np.concatenate(lows).astype(self._dtype),
          maximum=np.concatenate(highs).astype(self._dtype),
          name=name,
      )
    else:
      self.spec = specs.Array(shape=(self.size,), dtype=self._dtype, name=name)

  def __call__(self, observation: Mapping[str, jnp.ndarray]):
    """Concatenates the entries (raveled, cast) along a new last axis."""
    missing = [k for k in self.keys if k not in observation]
    if missing:
      raise KeyError(f'Observation is missing keys {missing}.')
    parts = []
    for k in self.keys:
      value = jnp.asarray(observation[k])
      shape = self._shapes[k]
      lead = value.shape[: value.ndim - len(shape)]
      if value.shape[len(lead) :] != shape:
        raise ValueError(
            f'Observation {k!r} has shape {value.shape}, '
            f'expected (..., {shape}).'
        )
      parts.append(value.reshape(lead + (-1,)).astype(self._dtype))
    if not parts:
      return jnp.zeros((0,), self._dtype)
    return jnp.concatenate(parts, axis=-1)

  def unflatten(self, vector):
    """The inverse: `{key: array}` from a `(..., D)` vector."""
    lead = vector.shape[:-1]
    return collections.OrderedDict(
        (k, vector[..., self.slices[k]].reshape(lead + self._shapes[k]))
        for k in self.keys
    )


def flatten_spec(spec_dict, dtype=jnp.float32, name=None):
  """The `(D,)` spec of `Flattener(spec_dict)`."""
  return Flattener(spec_dict, dtype, name).spec
