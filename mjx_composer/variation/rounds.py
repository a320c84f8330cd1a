"""PRNG keys and evaluation rounds: the context every evaluation runs in.

Every public entry point of `base` (`Variation.__call__`, `Variation.sample`,
`evaluate`, `sample`) checks its key with `check_key` and opens an
`evaluation_round`; `variation_broadcaster` reads the open round with
`current_round` so that every proxy of one broadcaster draws the same value in
one evaluation; composite nodes and structures derive the keys of their parts
with `fold_in` (see "How keys are split" in `base`). None of this depends on
the `Variation` class, so it lives apart from it; `base` re-exports
`evaluation_round`.
"""

import contextlib
import contextvars
from typing import Optional

import jax
import jax.numpy as jnp
import numpy as np


def check_key(key, owner):
  """Rejects things that are not JAX keys, with a message for porters."""
  if key is None:
    return
  if isinstance(key, (np.random.RandomState, np.random.Generator)):
    raise TypeError(
        f"{owner!r}: got a numpy random state. mjx_composer variations "
        "take a JAX PRNG key (jax.random.key(seed)) where composer took "
        "random_state."
    )
  dtype = getattr(key, "dtype", None)
  if dtype is None or not (
      jnp.issubdtype(dtype, jax.dtypes.prng_key) or dtype == np.uint32
  ):
    raise TypeError(
        f"{owner!r}: key must be a JAX PRNG key such as "
        f"jax.random.key(0) or jax.random.PRNGKey(0), got {key!r}."
    )


class _Round:
  """Evaluation-wide context shared by all nodes of one outermost call."""

  def __init__(self, key):
    self.key = key
    self._slots = {}

  def slot(self, owner) -> int:
    """A per-round index for `owner`, in order of first use."""
    return self._slots.setdefault(owner, len(self._slots))


_CURRENT_ROUND = contextvars.ContextVar(
    "mjx_composer_variation_round", default=None
)


@contextlib.contextmanager
def evaluation_round(key):
  """Makes everything evaluated inside one "round" with root key `key`.

  Every public entry point (`Variation.__call__`, `Variation.sample`,
  `evaluate`, `sample`) opens a round with its own key unless one is already
  open, in which case the outer round is kept. Within a round, every
  `VariationBroadcaster` proxy of one broadcaster returns the same value.
  Open a round explicitly when several variations are evaluated by separate
  calls but must share broadcast values, e.g. a variator evaluating each
  bound attribute with its own subkey:

      with variation.evaluation_round(key):
          for i, v in enumerate(bound_variations):
              values.append(v(init[i], cur[i], jax.random.fold_in(key, i)))

  The round only exists while Python traces or runs the enclosed code; it
  holds no state between calls, so evaluation stays pure.
  """
  if _CURRENT_ROUND.get() is not None:
    yield
    return
  token = _CURRENT_ROUND.set(_Round(key))
  try:
    yield
  finally:
    _CURRENT_ROUND.reset(token)


def current_round() -> Optional[_Round]:
  """The open evaluation round, or None outside every round."""
  return _CURRENT_ROUND.get()


def fold_in(key, index):
  """`jax.random.fold_in(key, index)`, or None without a key."""
  return None if key is None else jax.random.fold_in(key, index)
