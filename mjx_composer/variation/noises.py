"""Noises: variations that perturb the value being varied.

Mirrors `dm_control.composer.variation.noises`. A non-cumulative noise acts on
the initial value, so every evaluation is `initial (op) amount`; a cumulative
one acts on the current value, so repeated application compounds (the caller
feeds each result back as the next `current_value`).
"""

import jax.numpy as jnp

from mjx_composer.variation import arrays as arrays_lib
from mjx_composer.variation import composite
from mjx_composer.variation import printing


class _Noise(composite.CompositeVariation):
  """`base (op) amount`, base being the initial or the current value."""

  _SYMBOL = "?"

  def __init__(self, variation, cumulative=False):
    """Initializes the noise.

    Args:
      variation: the amount: a variation, a constant, or a structure of
        them. It is evaluated with the same initial and current value, so
        a distribution is drawn in the shape of the value being varied.
      cumulative: act on `current_value` instead of `initial_value`.
    """
    self._variation = variation
    self._cumulative = bool(cumulative)
    self._operands = (variation,)

  def _combine(self, value, amount):
    raise NotImplementedError

  def _apply(self, values, key, initial_value, current_value):
    value = current_value if self._cumulative else initial_value
    if value is None:
      which = "current_value" if self._cumulative else "initial_value"
      raise ValueError(f"{self!r} acts on {which}, but {which} is None.")
    return self._combine(jnp.asarray(value), arrays_lib.as_array(values[0]))

  def _eq_fields(self):
    return (self._variation, self._cumulative)

  def __repr__(self):
    extra = {"cumulative": True} if self._cumulative else {}
    return printing.format_call(type(self).__name__, self._variation, **extra)


class Additive(_Noise):
  """Adds the amount: `(current if cumulative else initial) + amount`."""

  _BATCHES = True

  def _combine(self, value, amount):
    return value + amount


class Multiplicative(_Noise):
  """Multiplies by the amount: `(current if cumulative else initial) * amount`."""

  _BATCHES = True

  def _combine(self, value, amount):
    return value * amount
