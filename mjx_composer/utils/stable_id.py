"""Integers derived from names, the same in every process and run.

Random streams are split by `jax.random.fold_in(key, stable_id(name))`, so
that a draw depends on who draws (a hook's owner, an observable's purpose),
not on the order in which things were built. Python's `hash` of a string
changes from process to process; CRC-32 does not. `fold_in_each` folds
many of them into one key at once.

This module imports nothing from the package: authoring code (observables,
variations) and the runtime both use it.
"""

import zlib

import jax
import jax.numpy as jnp


def stable_digest(text: str) -> int:
  """The CRC-32 of `text` (UTF-8): an unsigned 32-bit integer."""
  return zlib.crc32(text.encode('utf-8'))


def stable_id(text: str) -> int:
  """A 31-bit integer for `fold_in`, the same in every process and run.

  31 bits: a non-negative value of a signed 32-bit integer.
  """
  return stable_digest(text) & 0x7FFFFFFF


def fold_in_each(key, indices) -> list:
  """`[jax.random.fold_in(key, i) for i in indices]`, from one batched hash.

  The same keys, bit for bit, as folding each index in on its own; but each
  PRNG call is a kernel (a GPU) or a few hundred instructions (a CPU) of
  its own in the compiled program, and a reset or an observation update
  derives dozens of keys. `indices`: non-negative integers below 2**32
  (`stable_id`s, slots). None for `key` gives None for each.
  """
  indices = list(indices)
  if key is None:
    return [None] * len(indices)
  if len(indices) < 2:
    return [jax.random.fold_in(key, i) for i in indices]
  keys = jax.vmap(jax.random.fold_in, in_axes=(None, 0))(
      key, jnp.asarray(indices, jnp.uint32)
  )
  return list(keys)
