"""`CompositeVariation`: a variation computed from a tuple of operands.

The base of every node that combines other variations or constants: the
arithmetic operators, the math and colour nodes, rotations, noises. It
evaluates its operands with their own keys (`fold_in(operand_key, i)`) and
states, then applies the node's function (`_apply`).
"""

import abc
from typing import Any, Tuple

import jax

from mjx_composer.utils import stable_id
from mjx_composer.variation import base
from mjx_composer.variation import structures


class CompositeVariation(base.Variation):
  """A variation computed from a tuple of operands.

  Subclasses set `self._operands` (a tuple; each operand a variation, a
  constant, or a nested structure of them) and implement
  `_apply(values, key, initial_value, current_value)`, which receives the
  evaluated operands (same tuple structure) and returns the value. Set the
  class attribute `_DRAWS_RANDOMNESS = True` if `_apply` draws random numbers
  with `key`: the node then requires a key and splits it into its own key and
  the operands' key when it has variation operands (see `base`'s module docstring).

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

  def _batches(self) -> bool:
    return super()._batches() and all(
        structures.batches(operand) for operand in self._operands
    )

  def initial_state(self, initial_value=None):
    inputs = self._operand_inputs(initial_value, None)
    return structures.collapse(
        structures.structure_initial_state(operand, iv, per_leaf=False)
        for operand, (iv, _) in zip(self._operands, inputs)
    )

  def _split_key(self, key):
    if not self._DRAWS_RANDOMNESS:
      return None, key
    self._require_key(key)
    if not base.contains_variation(self._operands):
      return key, None
    own_key, operand_key = jax.random.split(key)
    return own_key, operand_key

  def _sample(self, state, key, initial_value, current_value):
    own_key, operand_key = self._split_key(key)
    n = len(self._operands)
    states = state if state is not None else (None,) * n
    inputs = self._operand_inputs(initial_value, current_value)
    # Operand i's key is fold_in(operand_key, i) (operand_key itself when
    # there is one operand), all of them from one hash.
    varied = [
        i for i, op in enumerate(self._operands) if base.contains_variation(op)
    ]
    operand_keys = (
        {i: operand_key for i in varied}
        if n == 1
        else dict(zip(varied, stable_id.fold_in_each(operand_key, varied)))
    )
    values, new_states = [], []
    for i, (operand, operand_state, (iv, cv)) in enumerate(
        zip(self._operands, states, inputs)
    ):
      operand_key_i = operand_keys.get(i)
      value, operand_state = structures.sample_structure(
          operand, operand_state, operand_key_i, iv, cv, per_leaf=False
      )
      values.append(value)
      new_states.append(operand_state)
    value = self._apply(tuple(values), own_key, initial_value, current_value)
    return value, structures.collapse(new_states)
