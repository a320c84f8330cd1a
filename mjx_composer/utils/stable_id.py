"""Integers derived from names, the same in every process and run.

Random streams are split by `jax.random.fold_in(key, stable_id(name))`, so
that a draw depends on who draws (a hook's owner, an observable's purpose),
not on the order in which things were built. Python's `hash` of a string
changes from process to process; CRC-32 does not.

This module imports nothing from the package: authoring code (observables,
variations) and the runtime both use it.
"""

import zlib


def stable_digest(text: str) -> int:
  """The CRC-32 of `text` (UTF-8): an unsigned 32-bit integer."""
  return zlib.crc32(text.encode('utf-8'))


def stable_id(text: str) -> int:
  """A 31-bit integer for `fold_in`, the same in every process and run.

  31 bits: a non-negative value of a signed 32-bit integer.
  """
  return stable_digest(text) & 0x7FFFFFFF
