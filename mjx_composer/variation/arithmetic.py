"""Arithmetic on variations: the nodes built by `+ - * / // **`, `-v`, `v[i]`.

`Variation`'s operators (in `base`) build these nodes, as composer's
`_BinaryOperation`, `_UnaryOperation` and `_GetItemOperation` (the names they
keep here, since they show in messages such as "... is not iterable"). Each
is a `composite.CompositeVariation` that evaluates its operands and applies the
operator, with static bounds where the operator allows (interval arithmetic)
and a readable repr (`Uniform(low=0.0, high=1.0) + 2`, parenthesized by
precedence). They live apart from `base`, which holds the `Variation`
protocol itself; `base` imports this module last, because these classes
subclass `composite.CompositeVariation`.
"""

import operator

import numpy as np

from mjx_composer.variation import arrays as arrays_lib
from mjx_composer.variation import bounds as bounds_lib
from mjx_composer.variation import composite
from mjx_composer.variation import printing

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
  text = printing.format_value(value, use_str)
  return f"({text})" if parenthesize else text


class _BinaryOperation(composite.CompositeVariation):
  """`op(first, second)` of two evaluated operands (one at least a variation)."""

  _BATCHES = True

  def __init__(self, op, first, second):
    self._op = op
    self._operands = (first, second)

  def _apply(self, values, key, initial_value, current_value):
    first, second = (arrays_lib.as_array(v) for v in values)
    return self._op(first, second)

  def static_bounds(self):
    first, second = (bounds_lib.static_bounds(v) for v in self._operands)
    if first is None or second is None:
      return None
    (a_low, a_high), (b_low, b_high) = first, second
    op = self._op
    if op is operator.add:
      return bounds_lib.as_bounds(a_low + b_low, a_high + b_high)
    if op is operator.sub:
      return bounds_lib.as_bounds(a_low - b_high, a_high - b_low)
    if op is operator.mul:
      return bounds_lib.extremes(
          [a_low * b_low, a_low * b_high, a_high * b_low, a_high * b_high]
      )
    if op in (operator.truediv, operator.floordiv):
      if not (np.all(b_low > 0) or np.all(b_high < 0)):
        return None  # The divisor's range contains zero.
      low, high = bounds_lib.extremes(
          [a_low / b_low, a_low / b_high, a_high / b_low, a_high / b_high]
      )
      if op is operator.floordiv:
        low, high = np.floor(low), np.floor(high)
      return bounds_lib.as_bounds(low, high)
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


class _UnaryOperation(composite.CompositeVariation):
  """`op(operand)` of an evaluated variation (composer only has `neg`)."""

  _BATCHES = True

  def __init__(self, op, operand):
    self._op = op
    self._operands = (operand,)

  def _apply(self, values, key, initial_value, current_value):
    return self._op(arrays_lib.as_array(values[0]))

  def static_bounds(self):
    bounds = bounds_lib.static_bounds(self._operands[0])
    if bounds is None or self._op is not operator.neg:
      return None
    return bounds_lib.as_bounds(-bounds[1], -bounds[0])

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


class _GetItemOperation(composite.CompositeVariation):
  """`np.asarray(value)[index]` of an evaluated variation."""

  def __init__(self, operand, index):
    self._index = index
    self._operands = (operand,)

  def _apply(self, values, key, initial_value, current_value):
    return arrays_lib.as_array(values[0])[_normalize_index(self._index)]

  def static_bounds(self):
    bounds = bounds_lib.static_bounds(self._operands[0])
    if bounds is None:
      return None
    # The bounds may be smaller than the value (they broadcast), so an index
    # into the value need not address the bounds: use the loosest bounds.
    return bounds_lib.as_bounds(np.min(bounds[0]), np.max(bounds[1]))

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


def binary_operation(op, first, second) -> composite.CompositeVariation:
  """`op(first, second)`, e.g. `operator.add`; one operand a variation."""
  return _BinaryOperation(op, first, second)


def unary_operation(op, operand) -> composite.CompositeVariation:
  """`op(operand)` of a variation (`operator.neg`)."""
  return _UnaryOperation(op, operand)


def get_item_operation(operand, index) -> composite.CompositeVariation:
  """`np.asarray(value)[index]` of a variation's value."""
  return _GetItemOperation(operand, index)
