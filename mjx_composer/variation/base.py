"""Variation base class, composition operators and structure evaluation.

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
* The module functions `initial_state`, `sample` and `evaluate` do the same
  for a nested structure of variations; the state of a structure is the state
  of the variation when the structure is one, else a tuple with one entry per
  flattened leaf (or `None` when no leaf is stateful).

Writing a new variation: subclass `Variation` and implement
`_sample(state, key, initial_value, current_value) -> (value, new_state)`;
override `initial_state` when the node is stateful and `static_bounds` when the
support is known statically. Use `self._require_key(key)` in nodes that draw
random numbers and `self._require_state(state)` in stateful ones, so that
misuse gets a clear error naming the node. Nodes built from operands should
subclass `CompositeVariation`, which evaluates and threads the operands for
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
"""

import abc
import contextlib
import contextvars
import functools
import operator
from typing import Any, Optional, Tuple

import jax
import jax.numpy as jnp
import numpy as np
import tree

Bounds = Tuple[np.ndarray, np.ndarray]


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

  def sample(self, state, key, initial_value=None, current_value=None):
    """Draws a value and advances the state.

    Args:
      state: the pytree returned by `initial_state` or by a previous call
        (`None` for stateless variations).
      key: a JAX PRNG key (typed or legacy `uint32[2]`), or `None` for
        deterministic variations.
      initial_value: original value of the thing being varied, or `None`.
      current_value: present value of the thing being varied, or `None`.

    Returns:
      `(value, new_state)`, `new_state` with the structure of `state`.
    """
    _check_key(key, self)
    with evaluation_round(key):
      return self._sample(state, key, initial_value, current_value)

  def __call__(self, initial_value=None, current_value=None, key=None):
    """Returns a value drawn from a fresh state (see module docstring)."""
    value, _ = self.sample(
        self.initial_state(initial_value), key, initial_value, current_value
    )
    return value

  def static_bounds(self) -> Optional[Bounds]:
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
    return _BinaryOperation(operator.add, self, other)

  def __radd__(self, other):
    return _BinaryOperation(operator.add, other, self)

  def __sub__(self, other):
    return _BinaryOperation(operator.sub, self, other)

  def __rsub__(self, other):
    return _BinaryOperation(operator.sub, other, self)

  def __mul__(self, other):
    return _BinaryOperation(operator.mul, self, other)

  def __rmul__(self, other):
    return _BinaryOperation(operator.mul, other, self)

  def __truediv__(self, other):
    return _BinaryOperation(operator.truediv, self, other)

  def __rtruediv__(self, other):
    return _BinaryOperation(operator.truediv, other, self)

  def __floordiv__(self, other):
    return _BinaryOperation(operator.floordiv, self, other)

  def __rfloordiv__(self, other):
    return _BinaryOperation(operator.floordiv, other, self)

  def __pow__(self, other):
    return _BinaryOperation(operator.pow, self, other)

  def __rpow__(self, other):
    return _BinaryOperation(operator.pow, other, self)

  def __neg__(self):
    return _UnaryOperation(operator.neg, self)

  def __getitem__(self, index):
    return _GetItemOperation(self, index)


# --------------------------------------------------------------------------
# Keys and evaluation rounds.


def _check_key(key, owner):
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


def _current_round() -> Optional[_Round]:
  return _CURRENT_ROUND.get()


def _fold_in(key, index):
  return None if key is None else jax.random.fold_in(key, index)


# --------------------------------------------------------------------------
# Structures of variations.


def _is_variation(x) -> bool:
  """composer's rule: any callable leaf is a variation, the rest constants."""
  return isinstance(x, Variation) or callable(x)


def _contains_variation(structure) -> bool:
  return any(_is_variation(leaf) for leaf in tree.flatten(structure))


def _collapse(states):
  """A tuple of states, or `None` when none of them holds an array."""
  states = tuple(states)
  return tuple(states) if jax.tree_util.tree_leaves(states) else None


def _leaf_values(structure, n, value, per_leaf):
  """The initial/current value handed to each flattened leaf of `structure`.

  With `per_leaf`, a `value` that has the structure of `structure` is split
  leaf by leaf; anything else (an array, a scalar, a structure that does not
  match) is handed whole to every leaf, as composer's `evaluate` does.
  """
  if value is None:
    return [None] * n
  if per_leaf:
    try:
      return tree.flatten_up_to(structure, value)
    except (TypeError, ValueError):
      pass
  return [value] * n


def _structure_initial_state(structure, initial_value, per_leaf):
  if isinstance(structure, Variation):
    return structure.initial_state(initial_value)
  leaves = tree.flatten(structure)
  ivs = _leaf_values(structure, len(leaves), initial_value, per_leaf)
  return _collapse(
      leaf.initial_state(iv) if isinstance(leaf, Variation) else None
      for leaf, iv in zip(leaves, ivs)
  )


def _sample_structure(
    structure, state, key, initial_value, current_value, per_leaf
):
  """Evaluates every variation leaf of `structure`; returns (values, state)."""
  if isinstance(structure, Variation):
    return structure._sample(state, key, initial_value, current_value)
  if callable(structure):
    return structure(initial_value, current_value, key), None
  leaves = tree.flatten(structure)
  if not any(_is_variation(leaf) for leaf in leaves):
    return structure, None
  n = len(leaves)
  ivs = _leaf_values(structure, n, initial_value, per_leaf)
  cvs = _leaf_values(structure, n, current_value, per_leaf)
  states = state if state is not None else (None,) * n
  values, new_states = [], []
  for i, (leaf, leaf_state, iv, cv) in enumerate(zip(leaves, states, ivs, cvs)):
    if isinstance(leaf, Variation):
      value, leaf_state = leaf._sample(leaf_state, _fold_in(key, i), iv, cv)
    elif callable(leaf):
      value = leaf(iv, cv, _fold_in(key, i))
    else:
      value = leaf
    values.append(value)
    new_states.append(leaf_state)
  return tree.unflatten_as(structure, values), _collapse(new_states)


def initial_state(structure, initial_value=None):
  """Returns the state of a nested structure of variations.

  Args:
    structure: a variation, a constant, or a nested structure (lists,
      tuples, dicts, namedtuples) of them.
    initial_value: `None`, a structure matching `structure` (one value per
      leaf), or a single value handed to every leaf.

  Returns:
    The variation's own state if `structure` is a variation; otherwise a
    tuple with one state per flattened leaf, or `None` if nothing in the
    structure is stateful.
  """
  return _structure_initial_state(structure, initial_value, per_leaf=True)


def sample(structure, state, key, initial_value=None, current_value=None):
  """Evaluates a nested structure of variations and advances its state.

  Args:
    structure: a variation, a constant, or a nested structure of them.
      Non-variation leaves are returned unchanged (no array conversion, so
      Python ints stay static). Any callable leaf is treated as a stateless
      variation and called as `leaf(initial_value, current_value, key)`.
    state: as returned by `initial_state(structure, ...)` or a previous call.
    key: a JAX PRNG key, split per leaf as described in the module
      docstring, or `None` if the structure is deterministic.
    initial_value: `None`, a structure matching `structure` (one value per
      leaf), or a single value handed to every leaf (composer's behaviour).
    current_value: like `initial_value`.

  Returns:
    `(values, new_state)`: `values` has the structure of `structure`.
  """
  _check_key(key, structure)
  with evaluation_round(key):
    return _sample_structure(
        structure, state, key, initial_value, current_value, per_leaf=True
    )


def evaluate(structure, initial_value=None, current_value=None, key=None):
  """Evaluates every variation in a nested structure (composer's `evaluate`).

  Stateful leaves are evaluated from a fresh state (see the module
  docstring); use `initial_state` and `sample` to carry their state.

  Args:
    structure: a variation, a constant, or a nested structure (lists,
      tuples, dicts, namedtuples) of them; constants pass through.
    initial_value: `None`, a structure matching `structure` (one value per
      leaf), or a single value handed to every leaf.
    current_value: like `initial_value`.
    key: a JAX PRNG key. Leaf `i` gets `jax.random.fold_in(key, i)`, so its
      value does not depend on the other leaves; a bare variation gets `key`.

  Returns:
    The structure with every variation replaced by its value.
  """
  state = initial_state(structure, initial_value)
  values, _ = sample(structure, state, key, initial_value, current_value)
  return values


# --------------------------------------------------------------------------
# Static bounds.


def _numeric_array(value) -> Optional[np.ndarray]:
  """`np.asarray(value)` if that gives a numeric array, else `None`."""
  try:
    array = np.asarray(value)
  except (ValueError, TypeError):
    return None
  if array.dtype.kind not in "biuf":
    return None
  return array


def static_bounds(value) -> Optional[Bounds]:
  """`(low, high)` for a variation, a constant or a structure of them.

  Constants are their own bounds. A (nested) list of scalar-valued
  variations and constants gets elementwise bounds. Returns `None` when any
  part is unbounded or not statically known.
  """
  if isinstance(value, Variation):
    return value.static_bounds()
  if callable(value):
    return None
  if tree.is_nested(value) and _contains_variation(value):
    leaves = tree.flatten(value)
    bounds = [static_bounds(leaf) for leaf in leaves]
    if any(b is None for b in bounds):
      return None
    low = _numeric_array(tree.unflatten_as(value, [b[0] for b in bounds]))
    high = _numeric_array(tree.unflatten_as(value, [b[1] for b in bounds]))
    if low is None or high is None:
      return None
    return low, high
  array = _numeric_array(value)
  if array is None:
    return None
  return array, array


# --------------------------------------------------------------------------
# Equality and printing helpers.


def _structurally_equal(a, b) -> bool:
  """Equality of construction arguments: numbers by value, variations by `==`.

  A list and an array holding the same numbers are equal.
  """
  if isinstance(a, Variation) or isinstance(b, Variation):
    return isinstance(a, Variation) and isinstance(b, Variation) and a == b
  if a is b:
    return True
  if not (_contains_variation(a) or _contains_variation(b)):
    array_a, array_b = _numeric_array(a), _numeric_array(b)
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


def format_value(value, use_str=False) -> str:
  """Text for an argument in a variation's repr (str of variations if asked)."""
  if isinstance(value, Variation):
    return str(value) if use_str else repr(value)
  return repr(value)


def format_call(name, *args, **kwargs) -> str:
  """`Name(arg, key=value, ...)` with variation arguments printed by repr."""
  parts = [format_value(a) for a in args]
  parts += [f"{k}={format_value(v)}" for k, v in kwargs.items()]
  return f"{name}({', '.join(parts)})"


def as_array(value):
  """Converts an evaluated operand (maybe a list of arrays) to a jnp array."""
  return None if value is None else jnp.asarray(value)


def float_dtype(*values):
  """Floating dtype of a result computed from `values` (default float)."""
  return jnp.result_type(*[v for v in values if v is not None], float)


# --------------------------------------------------------------------------
# Composite variations.


class CompositeVariation(Variation):
  """A variation computed from a tuple of operands.

  Subclasses set `self._operands` (a tuple; each operand a variation, a
  constant, or a nested structure of them) and implement
  `_apply(values, key, initial_value, current_value)`, which receives the
  evaluated operands (same tuple structure) and returns the value. Set the
  class attribute `_DRAWS_RANDOMNESS = True` if `_apply` draws random numbers
  with `key`: the node then requires a key and splits it into its own key and
  the operands' key when it has variation operands (see module docstring).

  By default every operand is evaluated with the node's `initial_value` and
  `current_value`, as in composer; override `_operand_inputs` to hand each
  operand something else (e.g. one colour channel, or nothing).

  The state is the tuple of the operands' states (`None` when stateless).
  """

  _DRAWS_RANDOMNESS = False
  _operands: Tuple[Any, ...] = ()

  def _operand_inputs(self, initial_value, current_value):
    """One `(initial_value, current_value)` pair per operand."""
    return [(initial_value, current_value)] * len(self._operands)

  @abc.abstractmethod
  def _apply(self, values, key, initial_value, current_value):
    """Computes the value from the evaluated operands."""

  def initial_state(self, initial_value=None):
    inputs = self._operand_inputs(initial_value, None)
    return _collapse(
        _structure_initial_state(operand, iv, per_leaf=False)
        for operand, (iv, _) in zip(self._operands, inputs)
    )

  def _split_key(self, key):
    if not self._DRAWS_RANDOMNESS:
      return None, key
    self._require_key(key)
    if not _contains_variation(self._operands):
      return key, None
    own_key, operand_key = jax.random.split(key)
    return own_key, operand_key

  def _sample(self, state, key, initial_value, current_value):
    own_key, operand_key = self._split_key(key)
    n = len(self._operands)
    states = state if state is not None else (None,) * n
    inputs = self._operand_inputs(initial_value, current_value)
    values, new_states = [], []
    for i, (operand, operand_state, (iv, cv)) in enumerate(
        zip(self._operands, states, inputs)
    ):
      operand_key_i = None
      if _contains_variation(operand):
        operand_key_i = operand_key if n == 1 else _fold_in(operand_key, i)
      value, operand_state = _sample_structure(
          operand, operand_state, operand_key_i, iv, cv, per_leaf=False
      )
      values.append(value)
      new_states.append(operand_state)
    value = self._apply(tuple(values), own_key, initial_value, current_value)
    return value, _collapse(new_states)


# --------------------------------------------------------------------------
# Arithmetic nodes.

# Symbol and precedence (higher binds tighter) of each operator.
_BINARY_SYMBOLS = {
    operator.add: ("+", 1),
    operator.sub: ("-", 1),
    operator.mul: ("*", 2),
    operator.truediv: ("/", 2),
    operator.floordiv: ("//", 2),
    operator.pow: ("**", 4),
}
_UNARY_PRECEDENCE = 3
_ATOM_PRECEDENCE = 5


def _precedence(value) -> int:
  if isinstance(value, _BinaryOperation):
    return _BINARY_SYMBOLS[value._op][1]
  if isinstance(value, _UnaryOperation):
    return _UNARY_PRECEDENCE
  return _ATOM_PRECEDENCE


def _format_operand(value, use_str, parenthesize):
  text = format_value(value, use_str)
  return f"({text})" if parenthesize else text


class _BinaryOperation(CompositeVariation):
  """`op(first, second)` of two evaluated operands (one at least a variation)."""

  def __init__(self, op, first, second):
    self._op = op
    self._operands = (first, second)

  def _apply(self, values, key, initial_value, current_value):
    first, second = (as_array(v) for v in values)
    return self._op(first, second)

  def static_bounds(self):
    first, second = (static_bounds(v) for v in self._operands)
    if first is None or second is None:
      return None
    (a_low, a_high), (b_low, b_high) = first, second
    op = self._op
    if op is operator.add:
      return _as_bounds(a_low + b_low, a_high + b_high)
    if op is operator.sub:
      return _as_bounds(a_low - b_high, a_high - b_low)
    if op is operator.mul:
      return _extremes(
          [a_low * b_low, a_low * b_high, a_high * b_low, a_high * b_high]
      )
    if op in (operator.truediv, operator.floordiv):
      if not (np.all(b_low > 0) or np.all(b_high < 0)):
        return None  # The divisor's range contains zero.
      low, high = _extremes(
          [a_low / b_low, a_low / b_high, a_high / b_low, a_high / b_high]
      )
      if op is operator.floordiv:
        low, high = np.floor(low), np.floor(high)
      return _as_bounds(low, high)
    return None

  def _eq_fields(self):
    return (self._op, self._operands)

  def _format(self, use_str):
    symbol, precedence = _BINARY_SYMBOLS[self._op]
    first, second = self._operands
    right_assoc = self._op is operator.pow
    first_text = _format_operand(
        first,
        use_str,
        _precedence(first) < precedence
        or (right_assoc and _precedence(first) == precedence),
    )
    second_text = _format_operand(
        second,
        use_str,
        _precedence(second) < precedence
        or (not right_assoc and _precedence(second) == precedence),
    )
    return f"{first_text} {symbol} {second_text}"

  def __str__(self):
    return self._format(use_str=True)

  def __repr__(self):
    return self._format(use_str=False)


class _UnaryOperation(CompositeVariation):
  """`op(operand)` of an evaluated variation (composer only has `neg`)."""

  def __init__(self, op, operand):
    self._op = op
    self._operands = (operand,)

  def _apply(self, values, key, initial_value, current_value):
    return self._op(as_array(values[0]))

  def static_bounds(self):
    bounds = static_bounds(self._operands[0])
    if bounds is None or self._op is not operator.neg:
      return None
    return _as_bounds(-bounds[1], -bounds[0])

  def _eq_fields(self):
    return (self._op, self._operands)

  def _format(self, use_str):
    operand = self._operands[0]
    text = _format_operand(
        operand, use_str, _precedence(operand) < _ATOM_PRECEDENCE
    )
    return f"-{text}"

  def __str__(self):
    return self._format(use_str=True)

  def __repr__(self):
    return self._format(use_str=False)


def _normalize_index(index):
  """numpy-style index usable on a jnp array (lists become index arrays)."""
  if isinstance(index, list):
    return np.asarray(index)
  if isinstance(index, tuple):
    return tuple(np.asarray(i) if isinstance(i, list) else i for i in index)
  return index


def _format_index(index) -> str:
  if isinstance(index, tuple):
    return ", ".join(_format_index(i) for i in index)
  if isinstance(index, slice):
    parts = ["" if p is None else repr(p) for p in (index.start, index.stop)]
    text = ":".join(parts)
    return text if index.step is None else f"{text}:{index.step!r}"
  if index is Ellipsis:
    return "..."
  return repr(index)


class _GetItemOperation(CompositeVariation):
  """`np.asarray(value)[index]` of an evaluated variation."""

  def __init__(self, operand, index):
    self._index = index
    self._operands = (operand,)

  def _apply(self, values, key, initial_value, current_value):
    return as_array(values[0])[_normalize_index(self._index)]

  def static_bounds(self):
    bounds = static_bounds(self._operands[0])
    if bounds is None:
      return None
    # The bounds may be smaller than the value (they broadcast), so an index
    # into the value need not address the bounds: use the loosest bounds.
    return _as_bounds(np.min(bounds[0]), np.max(bounds[1]))

  def _eq_fields(self):
    return (self._operands, _format_index(self._index))

  def _format(self, use_str):
    operand = self._operands[0]
    text = _format_operand(
        operand, use_str, _precedence(operand) < _ATOM_PRECEDENCE
    )
    return f"{text}[{_format_index(self._index)}]"

  def __str__(self):
    return self._format(use_str=True)

  def __repr__(self):
    return self._format(use_str=False)


def _extremes(candidates) -> Bounds:
  """Elementwise min and max over arrays that broadcast together."""
  return _as_bounds(
      functools.reduce(np.minimum, candidates),
      functools.reduce(np.maximum, candidates),
  )


def _as_bounds(low, high) -> Bounds:
  return np.asarray(low), np.asarray(high)
