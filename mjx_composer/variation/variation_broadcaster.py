"""Share one draw of a variation among several consumers.

Mirrors `dm_control.composer.variation.variation_broadcaster`: wrap a
variation in a `VariationBroadcaster` and bind `get_proxy()` proxies in its
place, e.g. to give several geoms the same random colour.

Pure-JAX semantics (deviation from composer): composer keeps a queue of drawn
values per proxy and draws a new value whenever an empty queue is read, so a
proxy called twice before the others returns the *next* value. Here there is
no mutable queue. A "round" is one outermost evaluation (one `evaluate`,
`sample` or call, or an explicit `rounds.evaluation_round(key)` block), and
within a round every proxy of a broadcaster returns the same value, drawn
with a key derived only from the round's key and the broadcaster (not from
the proxy or from where it sits in the expression). Reading a proxy twice in
one round returns the same value twice; the next round, with another key,
gives the next value.

The key of a broadcaster's draw is
`fold_in(fold_in(round_key, SALT), slot)`, where `slot` numbers the
broadcasters in the order they are first evaluated in the round, so two
broadcasters in one round draw independently.

Like composer, the wrapped variation is evaluated with no initial or current
value. If it is stateful (e.g. a `Sequence`), each proxy carries its own copy
of the state; the copies stay in lockstep as long as every proxy is sampled
once per round, which is composer's documented contract.
"""

import jax

from mjx_composer.variation import base
from mjx_composer.variation import bounds as bounds_lib
from mjx_composer.variation import printing
from mjx_composer.variation import rounds
from mjx_composer.variation import structures

# Separates broadcaster keys from the per-leaf keys fold_in(round_key, i).
_SALT = 0x62726F61


class VariationBroadcaster:
  """Wraps a variation so that several proxies share each of its draws."""

  def __init__(self, wrapped_variation):
    """Initializes a `VariationBroadcaster`.

    Args:
      wrapped_variation: the variation (or structure of variations) whose
        value is shared.
    """
    self._wrapped_variation = wrapped_variation

  @property
  def wrapped_variation(self):
    return self._wrapped_variation

  def get_proxy(self) -> base.Variation:
    """Returns a `Variation` to use in place of the wrapped variation."""
    return _BroadcastedValueProxy(self)

  def _round_key(self, key):
    """The key of this broadcaster's draw in the current round."""
    current = rounds.current_round()
    if current is None or current.key is None:
      return key
    slot = current.slot(self)
    return jax.random.fold_in(jax.random.fold_in(current.key, _SALT), slot)

  def __repr__(self):
    return printing.format_call(type(self).__name__, self._wrapped_variation)


class _BroadcastedValueProxy(base.Variation):
  """Returns the broadcaster's value for the current round."""

  def __init__(self, broadcaster):
    self._broadcaster = broadcaster

  def initial_state(self, initial_value=None):
    del initial_value  # The wrapped variation is evaluated without one.
    return structures.structure_initial_state(
        self._broadcaster.wrapped_variation, None, per_leaf=False
    )

  def _sample(self, state, key, initial_value, current_value):
    return structures.sample_structure(
        self._broadcaster.wrapped_variation,
        state,
        self._broadcaster._round_key(key),
        None,
        None,
        per_leaf=False,
    )

  def static_bounds(self):
    return bounds_lib.static_bounds(self._broadcaster.wrapped_variation)

  def __repr__(self):
    return f"BroadcastedValueProxy({self._broadcaster!r})"
