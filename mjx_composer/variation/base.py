"""The `Variation` protocol: how a variation is called, keyed and combined.

A `Variation` describes how to produce a new value for something that is being
randomized (a model field, an observation, a task parameter). It mirrors
`dm_control.composer.variation.base.Variation`, with one change that makes it
usable under `jax.jit` and `jax.vmap`: randomness comes from an explicit JAX
PRNG key instead of a shared `numpy.random.RandomState`.

Calling convention
------------------
    value = variation(initial_value=None, current_value=None, key=None)

* `initial_value`: the original value of the thing being varied (e.g. a
  compiled model field). Absolute variations ignore it; distributions take
  their sample shape from it; non-cumulative noises act on it.
* `current_value`: the value it has now (e.g. after previous variations).
  Cumulative noises and `deterministic.Identity` use it.
* `key`: a JAX PRNG key, either a typed key (`jax.random.key(0)`) or a legacy
  `uint32[2]` key (`jax.random.PRNGKey(0)`). Required by every node that draws
  random numbers (a missing key raises a `ValueError` naming the node);
  deterministic nodes accept `key=None`.

Every evaluation is a pure function of these arguments: the same key gives a
bit-identical value, inside or outside `jit`, whatever the batch size of an
enclosing `vmap`.

How keys are split
------------------
Keys are split deterministically by position in the expression, never by
evaluation order, so a value never depends on what else is evaluated:

* `evaluate(structure, key=k)`: if `structure` is itself a variation it gets
  `k` unchanged (so `evaluate(v, key=k) == v(key=k)`); otherwise the variation
  at flattened leaf index `i` (dm-tree order, all leaves counted) gets
  `jax.random.fold_in(k, i)`.
* A composite node (arithmetic, noise, math, colour, rotation, distribution
  with variation-valued parameters) holds a tuple of operands. A single
  operand gets the node's operand key unchanged; with several, operand `i`
  gets `fold_in(operand_key, i)`. Within an operand the structure rule above
  applies. Operands that are constants simply pass through.
* A node that draws random numbers itself and also has variation operands
  splits its key: `own_key, operand_key = jax.random.split(key)`. A node
  without variation operands uses its key directly for its own draw, so e.g.
  `Uniform()(key=k) == jax.random.uniform(k)`.
* `variation_broadcaster` proxies draw with a key derived from the key of the
  outermost evaluation (the "round", see `evaluation_round`), so every proxy
  of one broadcaster sees the same value in that evaluation.

State protocol (for stateful variations)
----------------------------------------
composer keeps the state of `BiasedRandomWalk` and `Sequence` on the Python
object. Here state is an explicit pytree, carried per world by whoever owns
the variation (a variator, an observation corruptor, a task):

    state = variation.initial_state(initial_value)        # once, at build time
    value, state = variation.sample(state, key,            # every draw
                                    initial_value, current_value)

* `initial_state(initial_value=None)` returns a pytree of arrays, or `None`
  for a stateless variation. Composite nodes return the states of their
  operands (a tuple, or `None` when no operand is stateful), so `None` means
  "the whole expression is stateless". The state structure never depends on
  the key, so it can be the carry of `lax.scan`, and its leaves can be given a
  leading world axis (e.g. `jax.tree.map(lambda x: jnp.broadcast_to(x, (n,) +
  x.shape), state)`) for a batch of worlds.
* `sample(state, key, initial_value=None, current_value=None)` returns
  `(value, new_state)`; `new_state` has exactly the structure of `state`.
  Passing `None` as the state of a stateful variation raises a `ValueError`.
* `__call__` is the stateless convenience: it evaluates from a fresh state,
  i.e. `v(iv, cv, key) == v.sample(v.initial_state(iv), key, iv, cv)[0]`.
  For stateless variations this is all there is. For stateful ones it is the
  *first* value (the first element of a `Sequence`, the first step of a random
  walk); calling it repeatedly does not advance: use `sample`.
* `structures`' `initial_state`, `sample` and `evaluate` do the same for a
  nested structure of variations; the state of a structure is the state
  of the variation when the structure is one, else a tuple with one entry per
  flattened leaf (or `None` when no leaf is stateful).

Writing a new variation: subclass `Variation` and implement
`_sample(state, key, initial_value, current_value) -> (value, new_state)`;
override `initial_state` when the node is stateful and `static_bounds` when the
support is known statically. Use `self._require_key(key)` in nodes that draw
random numbers and `self._require_state(state)` in stateful ones, so that
misuse gets a clear error naming the node. Nodes built from operands should
subclass `composite.CompositeVariation`, which evaluates and threads the operands for
you. Composite nodes call their children's `_sample` directly; the public
`sample` additionally validates the key and opens the evaluation round.
A stateless subclass written composer-style, overriding
`__call__(initial_value, current_value, key)` instead of `_sample`, also
works: the default `_sample` calls it.

Arithmetic
----------
`+ - * / // **` (and the reflected forms), unary `-` and `v[index]` build new
variations, like composer's `_BinaryOperation`, `_UnaryOperation` and
`_GetItemOperation`. Variations compare structurally (`==`) and print
readably, e.g. `str(Uniform() + 2) == 'Uniform(low=0.0, high=1.0) + 2'`.

Where things live: this module holds the `Variation` protocol (what a
variation is, how it is called, compared and combined); `structures` the
evaluation of nested structures of variations (`initial_state`, `sample`,
`evaluate`); `bounds` static bounds; `composite` the base of nodes built from
operands (`CompositeVariation`); the arithmetic nodes are in `arithmetic`,
key checks and evaluation rounds in `rounds`; `random_state` refuses
composer's `random_state=` argument; `arrays` and `printing` are the helpers
nodes share to convert their operands and to print themselves.
"""

import abc
import operator
from typing import Optional

import numpy as np
import tree

from mjx_composer.variation import arrays
from mjx_composer.variation import random_state as random_state_lib
from mjx_composer.variation import rounds


class Variation(metaclass=abc.ABCMeta):
  """Abstract base class of variations (see the module docstring)."""

  # Makes numpy defer to our reflected operators, so that
  # `np.float64(2.) * Uniform()` builds a variation instead of an object array.
  __array_ufunc__ = None

  # ------------------------------------------------------------------ API.

  def initial_state(self, initial_value=None):
    """Returns the state this variation starts from (`None`: stateless).

    Args:
      initial_value: the original value of the thing being varied, for
        variations whose state depends on its shape. May be `None`.
    """
    del initial_value
    return None

  def sample(
      self,
      state,
      key=None,
      initial_value=None,
      current_value=None,
      *,
      random_state=random_state_lib.NO_RANDOM_STATE,
  ):
    """Draws a value and advances the state.

    Args:
      state: the pytree returned by `initial_state` or by a previous call
        (`None` for stateless variations).
      key: a JAX PRNG key (typed or legacy `uint32[2]`), or `None` for
        deterministic variations.
      initial_value: original value of the thing being varied, or `None`.
      current_value: present value of the thing being varied, or `None`.

      random_state: composer's numpy `RandomState` argument: passing it
        raises a `TypeError` that says to pass `key=` instead.

    Returns:
      `(value, new_state)`, `new_state` with the structure of `state`.
    """
    random_state_lib.reject(random_state, f"{self!r}.sample")
    rounds.check_key(key, self)
    with rounds.evaluation_round(key):
      return self._sample(state, key, initial_value, current_value)

  def __call__(
      self,
      initial_value=None,
      current_value=None,
      key=None,
      *,
      random_state=random_state_lib.NO_RANDOM_STATE,
  ):
    """Returns a value drawn from a fresh state (see module docstring).

    `random_state=` (composer's numpy `RandomState`) raises a `TypeError`
    that says to pass `key=` instead.
    """
    random_state_lib.reject(random_state, repr(self))
    value, _ = self.sample(
        self.initial_state(initial_value), key, initial_value, current_value
    )
    return value

  def static_bounds(self) -> Optional[tuple[np.ndarray, np.ndarray]]:
    """Returns `(low, high)` bounding every value, or `None` if unknown.

    Both bounds are inclusive numpy arrays (0-d for scalars) that broadcast
    against the sampled values. They only depend on the construction
    arguments, not on initial or current values, so callers can use them
    to size buffers at build time (e.g. a variation-valued observable
    `update_interval` or `delay`).
    """
    return None

  def _sample(self, state, key, initial_value, current_value):
    """Implementation of `sample`, called on already-validated arguments.

    The default serves stateless subclasses that override `__call__`
    composer-style; every other subclass must override `_sample`.
    """
    if type(self).__call__ is Variation.__call__:
      raise NotImplementedError(
          f"{type(self).__name__} must implement _sample (or __call__)."
      )
    return self(initial_value, current_value, key), state

  # ------------------------------------------------- Sampling together.

  # Whether equal copies of this variation, bound to several attributes, may
  # be drawn in one `jax.vmap` over their keys, initial and current values
  # and states (`structures.sample_each`): its `_sample` is a function of
  # those arrays alone (no Python use of their values, no evaluation round).
  # Read from the class itself, never inherited: a subclass that overrides
  # how it samples says so again.
  _BATCHES = False

  def _batches(self) -> bool:
    """Whether `structures.sample_each` may draw copies of it together."""
    return bool(type(self).__dict__.get("_BATCHES", False))

  # ---------------------------------------------------------- Helpers.

  def _require_key(self, key):
    if key is None:
      raise ValueError(
          f"{self!r} draws random numbers and needs a PRNG key: call it "
          "as variation(initial_value, current_value, "
          "key=jax.random.key(seed)), or pass key= to "
          "variation.evaluate / variation.sample."
      )

  def _require_state(self, state):
    if state is None:
      raise ValueError(
          f"{self!r} is stateful: pass the state returned by "
          "initial_state() (or by a previous sample()) to sample(), "
          "not None."
      )

  def _eq_fields(self):
    """Construction arguments compared by `==`; `None` means identity."""
    return None

  def __eq__(self, other):
    mine = self._eq_fields()
    if mine is None:
      return self is other
    if type(other) is not type(self):
      return False
    return _structurally_equal(mine, other._eq_fields())

  def __ne__(self, other):
    return not self.__eq__(other)

  def __hash__(self):
    if self._eq_fields() is None:
      return object.__hash__(self)
    # Structurally equal variations may print differently (a list and an
    # array of the same numbers), so hash only what `==` always agrees on.
    return hash(type(self).__name__)

  def __iter__(self):
    # `__getitem__` would otherwise make every variation an endless iterable.
    raise TypeError(
        f"{type(self).__name__} is not iterable; index it (v[0]) to build "
        "a variation of one element."
    )

  def __repr__(self):
    return f"{type(self).__name__}()"

  # ------------------------------------------------------- Arithmetic.

  def __add__(self, other):
    return arithmetic.binary_operation(operator.add, self, other)

  def __radd__(self, other):
    return arithmetic.binary_operation(operator.add, other, self)

  def __sub__(self, other):
    return arithmetic.binary_operation(operator.sub, self, other)

  def __rsub__(self, other):
    return arithmetic.binary_operation(operator.sub, other, self)

  def __mul__(self, other):
    return arithmetic.binary_operation(operator.mul, self, other)

  def __rmul__(self, other):
    return arithmetic.binary_operation(operator.mul, other, self)

  def __truediv__(self, other):
    return arithmetic.binary_operation(operator.truediv, self, other)

  def __rtruediv__(self, other):
    return arithmetic.binary_operation(operator.truediv, other, self)

  def __floordiv__(self, other):
    return arithmetic.binary_operation(operator.floordiv, self, other)

  def __rfloordiv__(self, other):
    return arithmetic.binary_operation(operator.floordiv, other, self)

  def __pow__(self, other):
    return arithmetic.binary_operation(operator.pow, self, other)

  def __rpow__(self, other):
    return arithmetic.binary_operation(operator.pow, other, self)

  def __neg__(self):
    return arithmetic.unary_operation(operator.neg, self)

  def __getitem__(self, index):
    return arithmetic.get_item_operation(self, index)


def is_variation(x) -> bool:
  """composer's rule: any callable leaf is a variation, the rest constants."""
  return isinstance(x, Variation) or callable(x)


def contains_variation(structure) -> bool:
  """Whether any leaf of `structure` is a variation (`is_variation`)."""
  return any(is_variation(leaf) for leaf in tree.flatten(structure))


def _structurally_equal(a, b) -> bool:
  """Equality of construction arguments: numbers by value, variations by `==`.

  A list and an array holding the same numbers are equal.
  """
  if isinstance(a, Variation) or isinstance(b, Variation):
    return isinstance(a, Variation) and isinstance(b, Variation) and a == b
  if a is b:
    return True
  if not (contains_variation(a) or contains_variation(b)):
    array_a, array_b = arrays.numeric_array(a), arrays.numeric_array(b)
    if array_a is not None and array_b is not None:
      return array_a.shape == array_b.shape and bool(np.all(array_a == array_b))
  if isinstance(a, dict) and isinstance(b, dict):
    return a.keys() == b.keys() and all(
        _structurally_equal(a[k], b[k]) for k in a
    )
  if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
    return len(a) == len(b) and all(
        _structurally_equal(x, y) for x, y in zip(a, b)
    )
  try:
    return bool(a == b)
  except (TypeError, ValueError):
    return False


# `Variation`'s operators build the arithmetic nodes (`CompositeVariation`
# subclasses) at call time: imported last, once `Variation` exists.
from mjx_composer.variation import arithmetic  # pylint: disable=g-import-not-at-top,wrong-import-position
