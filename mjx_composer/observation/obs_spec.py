"""`dm_env` specs of the observation updater's observations.

`updater.Updater.observation_spec` returns, for every observable, the spec of
what `get_observation` returns for it: the buffer of `buffer_size` samples
(or a single sample with `strip_singleton_buffer_dim`), or the aggregator's
output, traced abstractly with `jax.eval_shape`, keeping a `BoundedArray`'s
bounds only when the aggregator says it preserves them. This module builds
one observable's spec from its `plan.Entry` (whose sample shapes the updater
has already learnt) and the spec of a flattened group. It is separate from
`updater` because none of it runs in `reset`, `update` or `get_observation`:
it only describes their output.
"""

import logging

from dm_env import specs
import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer.observation import flatten as flatten_lib
from mjx_composer.observation import plan


def observable_spec(entry: plan.Entry, corrupted: bool, strip: bool):
  """The spec of one observable's observation.

  Args:
    entry: the observable's entry; `entry.shapes` must hold the shape of the
      stream read.
    corrupted: whether the corrupted (True) or clean view is read.
    strip: the updater's `strip_singleton_buffer_dim`.
  """
  sample = entry.shapes[entry.stream(corrupted)]
  name = entry.key
  buffered = (entry.buffer_size,) + tuple(sample.shape)
  array_spec = entry.array_spec
  aggregator = entry.aggregator
  if aggregator is None:
    shape = (
        tuple(sample.shape) if strip and entry.buffer_size == 1 else buffered
    )
    if array_spec is not None:
      return array_spec.replace(name=name, shape=shape)
    return specs.Array(shape=shape, dtype=sample.dtype, name=name)
  out = jax.eval_shape(aggregator, jax.ShapeDtypeStruct(buffered, sample.dtype))
  if isinstance(array_spec, specs.BoundedArray):
    preserves = getattr(aggregator, 'preserves_bounds', None)
    if preserves is None:
      logging.warning(
          'Observable %r: its aggregator %r does not say whether it '
          'preserves bounds (attribute `preserves_bounds`); the bounds of '
          'its BoundedArray spec are dropped.',
          name,
          aggregator,
      )
    if preserves:
      try:
        return specs.BoundedArray(
            shape=out.shape,
            dtype=out.dtype,
            minimum=array_spec.minimum,
            maximum=array_spec.maximum,
            name=name,
        )
      except ValueError:
        logging.warning(
            'Observable %r: bounds of shape %s do not fit the '
            'aggregated shape %s; dropped.',
            name,
            np.shape(array_spec.minimum),
            out.shape,
        )
  return specs.Array(shape=out.shape, dtype=out.dtype, name=name)


def flat_group_spec(name, spec_dict):
  """The spec of a `flatten=True` group: one float32 vector."""
  return flatten_lib.Flattener(spec_dict, jnp.float32, name=name).spec
