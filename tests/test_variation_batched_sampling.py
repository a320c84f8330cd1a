"""Equal variations drawn together: the values of drawing each on its own."""

import jax
import jax.extend
import jax.numpy as jnp
import numpy as np

from mjx_composer import variation
from mjx_composer.variation import batched_sampling
from mjx_composer.variation import colors
from mjx_composer.variation import deterministic
from mjx_composer.variation import distributions
from mjx_composer.variation import noises

KEY = jax.random.key(7)


def _scale():
  # A new object each call: equal by structure, not by identity.
  return noises.Multiplicative(distributions.Uniform(0.9, 1.1))


class _ComposerStyle(variation.Variation):
  """Written as composer's subclasses are: `__call__`, no `_eq_fields`."""

  def __call__(self, initial_value=None, current_value=None, key=None):
    return initial_value + jax.random.uniform(key, np.shape(initial_value))


def _bindings():
  """(variations, initial values) covering every grouping rule."""
  broadcaster = variation.variation_broadcaster.VariationBroadcaster(
      distributions.Uniform(0.0, 2.0)
  )
  composer_style = _ComposerStyle()
  hsv = lambda: colors.HsvVariation(
      h=distributions.Uniform(0.0, 1.0),
      s=distributions.Uniform(0.3, 0.8),
      v=distributions.Uniform(0.5, 1.0),
  )
  rows = [
      (_scale(), np.float32(1000.0)),  # 0: group A
      (distributions.Normal(0.0, 1.0), np.zeros(3, np.float32)),  # 1: B
      (_scale(), np.float32(500.0)),  # 2: A
      (_scale(), np.ones(3, np.float32)),  # 3: shape differs from A
      (deterministic.Sequence([1.0, 2.0]), np.float32(0.0)),  # 4: stateful
      (deterministic.Sequence([1.0, 2.0]), np.float32(0.0)),  # 5: stateful
      (broadcaster.get_proxy() * 2.0, np.float32(1.0)),  # 6: proxy
      (broadcaster.get_proxy() * 2.0, np.float32(1.0)),  # 7: proxy
      (composer_style, np.float32(3.0)),  # 8: identity only
      (composer_style, np.float32(4.0)),  # 9: identity only
      (distributions.Normal(0.0, 1.0), np.ones(3, np.float32)),  # 10: B
      (hsv(), np.array([0.1, 0.2, 0.3, 1.0], np.float32)),  # 11: C
      (hsv(), np.array([0.5, 0.5, 0.5, 1.0], np.float32)),  # 12: C
      (_scale(), np.float32(2.0)),  # 13: A
      (deterministic.Constant(5.0), np.float32(0.0)),  # 14: keyless
      (noises.Multiplicative(composer_style), np.float32(1.0)),  # 15: alone
      (noises.Multiplicative(composer_style), np.float32(2.0)),  # 16: alone
  ]
  return [v for v, _ in rows], [i for _, i in rows]


def _inputs(variations, initial):
  states = [variation.initial_state(v, i) for v, i in zip(variations, initial)]
  keys = [jax.random.fold_in(KEY, i) for i in range(len(variations))]
  current = [jnp.asarray(i) * 1.5 for i in initial]
  return states, keys, current


def test_equal_stateless_variations_form_groups():
  variations, initial = _bindings()
  states, _, _ = _inputs(variations, initial)
  assert batched_sampling.groups(variations, states, initial) == [
      [0, 2, 13],
      [1, 10],
      [3],
      [4],
      [5],
      [6],
      [7],
      [8],
      [9],
      [11, 12],
      [14],
      [15],
      [16],
  ]


def test_grouped_draws_are_bit_identical_to_separate_draws():
  variations, initial = _bindings()
  states, keys, current = _inputs(variations, initial)

  @jax.jit
  def grouped(keys, current):
    with variation.evaluation_round(KEY):
      return batched_sampling.sample_bindings(
          variations, states, keys, initial, current
      )

  @jax.jit
  def separate(keys, current):
    with variation.evaluation_round(KEY):
      pairs = [
          variation.sample(v, s, k, i, c)
          for v, s, k, i, c in zip(variations, states, keys, initial, current)
      ]
    return [p[0] for p in pairs], [p[1] for p in pairs]

  got_values, got_states = grouped(keys, current)
  want_values, want_states = separate(keys, current)
  for i, (got, want) in enumerate(zip(got_values, want_values)):
    np.testing.assert_array_equal(got, want, err_msg=f'binding {i}')
  assert jax.tree.structure(got_states) == jax.tree.structure(want_states)
  for got, want in zip(
      jax.tree.leaves(got_states), jax.tree.leaves(want_states)
  ):
    np.testing.assert_array_equal(got, want)
  # The draws are random, not all equal (the groups did not share a key).
  assert len({float(got_values[i]) for i in (0, 2, 13)}) == 3


def _count(jaxpr, primitive):
  count = 0
  for eqn in jaxpr.eqns:
    count += eqn.primitive.name == primitive
    for sub in jax.extend.core.jaxprs_in_params(eqn.params):
      count += _count(sub, primitive)
  return count


def test_a_group_is_one_draw_in_the_program():
  variations = [_scale() for _ in range(10)]
  initial = [np.float32(k) for k in range(10)]
  states, keys, current = _inputs(variations, initial)

  def grouped(keys, current):
    return batched_sampling.sample_bindings(
        variations, states, keys, initial, current
    )[0]

  def separate(keys, current):
    return [
        variation.sample(v, None, k, i, c)[0]
        for v, k, i, c in zip(variations, keys, initial, current)
    ]

  count = lambda f: _count(
      jax.make_jaxpr(f)(keys, current).jaxpr, 'random_bits'
  )
  assert count(grouped) == 1
  assert count(separate) == 10
