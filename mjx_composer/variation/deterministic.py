"""Deterministic variations: constants, sequences and the identity.

Mirrors `dm_control.composer.variation.deterministic`. `Sequence` is stateful:
its position is carried in an explicit state (see `base` for the protocol).
"""

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer.variation import arrays as arrays_lib
from mjx_composer.variation import base
from mjx_composer.variation import bounds as bounds_lib
from mjx_composer.variation import printing
from mjx_composer.variation import structures


class Constant(base.Variation):
  """Always returns `value`.

  Numeric values (numbers, nested lists of numbers, arrays) are returned as
  jnp arrays; anything else (e.g. a dict) is returned unchanged, as composer
  does. Mainly useful in tests and as an operand of arithmetic.
  """

  def __init__(self, value):
    self._value = value
    self._array = arrays_lib.numeric_array(value)

  @property
  def value(self):
    return self._value

  def _sample(self, state, key, initial_value, current_value):
    if self._array is None:
      return self._value, state
    return jnp.asarray(self._array), state

  def static_bounds(self):
    if self._array is None:
      return None
    return self._array, self._array

  def _eq_fields(self):
    return (self._value,)

  def __str__(self):
    return str(self._value)

  def __repr__(self):
    return printing.format_call("Constant", self._value)


class SequenceState(NamedTuple):
  """State of a `Sequence`.

  Attributes:
    index: int32 scalar, the position of the next value to return.
    item_states: states of the items that are stateful variations (a tuple
      with one entry per item), or `None` when no item is stateful.
  """

  index: Any
  item_states: Any


class Sequence(base.Variation):
  """Cycles through `values` in order, forever.

  composer iterates a Python iterator and restarts it when exhausted; here
  the position is an int32 counter in the state, advanced modulo
  `len(values)`, so after the last value the sequence wraps around to the
  first, exactly like composer's restart. Items may be variations (or
  structures containing some); the current item is evaluated (with the
  sequence's key, initial and current value) and only its state advances.
  All items must evaluate to the same shape; dtypes are promoted to a common
  one.

  `__call__` evaluates from a fresh state and therefore always returns the
  first item; to step through the values carry the state:

      state = seq.initial_state()
      value, state = seq.sample(state, key)   # values[0]
      value, state = seq.sample(state, key)   # values[1] ...
  """

  def __init__(self, values):
    """Initializes a `Sequence`.

    Args:
      values: a non-empty sequence of values (numbers, arrays, variations
        or structures of them), or an array whose first axis enumerates
        the values.

    Raises:
      ValueError: if `values` is empty, or constant values differ in shape.
    """
    self._values = values
    self._items = list(values)
    if not self._items:
      raise ValueError("Sequence needs at least one value.")
    self._table = None
    if not base.contains_variation(self._items):
      arrays = [np.asarray(item) for item in self._items]
      shapes = {a.shape for a in arrays}
      if len(shapes) != 1:
        raise ValueError(
            f"Sequence values must all have the same shape, got shapes {sorted(shapes)}."
        )
      self._table = np.stack(arrays)

  def initial_state(self, initial_value=None):
    item_states = structures.collapse(
        structures.structure_initial_state(item, initial_value, per_leaf=False)
        for item in self._items
    )
    return SequenceState(jnp.zeros((), jnp.int32), item_states)

  def _sample(self, state, key, initial_value, current_value):
    self._require_state(state)
    n = len(self._items)
    index = jnp.asarray(state.index, jnp.int32) % n
    if self._table is not None:
      value, item_states = jnp.asarray(self._table)[index], state.item_states
    else:
      value, item_states = self._switch(
          index, state.item_states, key, initial_value, current_value
      )
    return value, SequenceState((index + 1) % n, item_states)

  def _switch(self, index, item_states, key, initial_value, current_value):
    """Evaluates item `index` with `lax.switch`, advancing only its state."""
    n = len(self._items)
    stateless = item_states is None

    def branch_for(i):
      def branch(item_states, key, initial_value, current_value):
        states = (None,) * n if stateless else item_states
        value, new_state = structures.sample_structure(
            self._items[i],
            states[i],
            key,
            initial_value,
            current_value,
            per_leaf=False,
        )
        if not stateless:
          states = states[:i] + (new_state,) + states[i + 1 :]
        return jnp.asarray(value), (None if stateless else states)

      return branch

    branches = [branch_for(i) for i in range(n)]
    args = (item_states, key, initial_value, current_value)
    outputs = [jax.eval_shape(b, *args)[0] for b in branches]
    shapes = {o.shape for o in outputs}
    if len(shapes) != 1:
      raise ValueError(
          f"{self!r}: all values must evaluate to the same shape, got "
          f"shapes {[o.shape for o in outputs]}."
      )
    dtype = jnp.result_type(*[o.dtype for o in outputs])

    def cast(branch):
      def cast_branch(*branch_args):
        value, states = branch(*branch_args)
        return value.astype(dtype), states

      return cast_branch

    return jax.lax.switch(index, [cast(b) for b in branches], *args)

  def static_bounds(self):
    if self._table is not None:
      return bounds_lib.as_bounds(
          self._table.min(axis=0), self._table.max(axis=0)
      )
    bounds = [bounds_lib.static_bounds(item) for item in self._items]
    if any(b is None for b in bounds):
      return None
    lows, highs = [b[0] for b in bounds], [b[1] for b in bounds]
    return bounds_lib.as_bounds(
        bounds_lib.extremes(lows)[0], bounds_lib.extremes(highs)[1]
    )

  def _eq_fields(self):
    return (self._items,)

  def __repr__(self):
    return printing.format_call("Sequence", self._values)


class Identity(base.Variation):
  """Returns `current_value` unchanged."""

  def _sample(self, state, key, initial_value, current_value):
    return current_value, state

  def _eq_fields(self):
    return ()
