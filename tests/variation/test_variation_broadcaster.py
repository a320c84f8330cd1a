"""Tests for mjx_composer.variation.variation_broadcaster.

composer's test checks per-proxy queues against a numpy stream. Here a round is
one outermost evaluation: every proxy of a broadcaster returns the same value
within it, and a new key gives the next value.
"""

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer import variation
from mjx_composer.variation import deterministic
from mjx_composer.variation import distributions
from mjx_composer.variation import noises
from mjx_composer.variation import variation_broadcaster

KEY = jax.random.key(0)


def _broadcaster(wrapped=None):
  return variation_broadcaster.VariationBroadcaster(
      wrapped or distributions.Uniform(0, 1)
  )


def test_proxies_share_one_draw_per_round():
  broadcaster = _broadcaster()
  proxy_1, proxy_2, proxy_3 = (broadcaster.get_proxy() for _ in range(3))
  structure = {"a": proxy_1, "b": [proxy_2, 0.5], "c": proxy_3, "d": proxy_1}
  rounds = [
      variation.evaluate(structure, key=jax.random.key(i)) for i in range(5)
  ]
  for values in rounds:
    assert values["a"] == values["b"][0] == values["c"] == values["d"]
  # Each round (key) gives a new value.
  assert len({float(values["a"]) for values in rounds}) == 5


def test_the_draw_does_not_depend_on_which_proxy_asks():
  broadcaster = _broadcaster()
  proxy_1, proxy_2 = broadcaster.get_proxy(), broadcaster.get_proxy()
  # Separate calls with the same key are separate rounds with the same key.
  assert proxy_1(key=KEY) == proxy_2(key=KEY)
  # Nor on where the proxy sits in an expression.
  assert variation.evaluate([1.0, proxy_2], key=KEY)[1] == proxy_1(key=KEY)


def test_proxies_inside_expressions_see_the_shared_value():
  broadcaster = _broadcaster()
  proxy_1, proxy_2 = broadcaster.get_proxy(), broadcaster.get_proxy()
  structure = [proxy_1 * 2, noises.Additive(proxy_2)]
  values = variation.evaluate(structure, initial_value=[0.0, 10.0], key=KEY)
  np.testing.assert_allclose(values[0] / 2, values[1] - 10.0, rtol=1e-6)


def test_different_broadcasters_draw_independently():
  first, second = _broadcaster(), _broadcaster()
  values = variation.evaluate(
      [first.get_proxy(), second.get_proxy(), first.get_proxy()], key=KEY
  )
  assert values[0] == values[2]
  assert values[0] != values[1]


def test_explicit_round_shares_across_separate_calls():
  broadcaster = _broadcaster()
  proxies = [broadcaster.get_proxy() for _ in range(3)]
  # A variator evaluating each binding with its own subkey opens one round.
  with variation.evaluation_round(KEY):
    values = [p(key=jax.random.fold_in(KEY, i)) for i, p in enumerate(proxies)]
  assert values[0] == values[1] == values[2]
  # Without the round, the different subkeys give different draws.
  values = [p(key=jax.random.fold_in(KEY, i)) for i, p in enumerate(proxies)]
  assert len(set(float(v) for v in values)) == 3


def test_jit_and_vmap():
  broadcaster = _broadcaster()
  structure = [broadcaster.get_proxy(), broadcaster.get_proxy()]
  values = jax.jit(
      jax.vmap(lambda k: jnp.stack(variation.evaluate(structure, key=k)))
  )(jax.random.split(KEY, 32))
  np.testing.assert_array_equal(values[:, 0], values[:, 1])
  assert len(np.unique(values[:, 0])) == 32


def test_stateful_wrapped_variation_advances_in_lockstep():
  broadcaster = _broadcaster(deterministic.Sequence([1, 2, 3]))
  structure = [broadcaster.get_proxy(), broadcaster.get_proxy()]
  state = variation.initial_state(structure)
  seen = []
  for i in range(4):
    values, state = variation.sample(structure, state, jax.random.key(i))
    seen.append([int(v) for v in values])
  assert seen == [[1, 1], [2, 2], [3, 3], [1, 1]]


def test_bounds_are_those_of_the_wrapped_variation():
  proxy = _broadcaster(distributions.UniformInteger(1, 5)).get_proxy()
  low, high = proxy.static_bounds()
  assert (int(low), int(high)) == (1, 4)
