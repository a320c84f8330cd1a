"""Tests for `structures.sample_each`: equal variations drawn together.

A variator samples every binding with its own key. `sample_each` draws equal
variations (with arrays of one shape) in one `jax.vmap`, so a reset holds
one PRNG call per distinct variation instead of one per binding. The values
must be those of sampling each binding on its own, bit for bit; what may not
be drawn together (a broadcaster's proxies, bare callables, subclasses that
do not say they batch, Python numbers) is sampled one by one.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_composer import variation
from mjx_composer.variation import distributions
from mjx_composer.variation import noises
from mjx_composer.variation import structures
from mjx_composer.variation import variation_broadcaster
from tests import jaxprs


def _draws(jaxpr) -> int:
  """PRNG calls (random_bits, or threefry for raw keys) in a jaxpr."""
  return jaxprs.count(jaxpr, 'random_bits', 'threefry2x32')


def _one_by_one(variations, keys, initials, currents):
  """Each sampled on its own, in one round (as a variator samples)."""
  states = [
      structures.initial_state(v, iv) for v, iv in zip(variations, initials)
  ]
  with variation.evaluation_round(keys[0]):
    return [
        structures.sample(*args)
        for args in zip(variations, states, keys, initials, currents)
    ]


def _run(fn, variations, keys, initials, currents):
  """`fn` compiled, the variations and initial values fixed (numpy constants
  of the program, as a variator's initial values are)."""
  return jax.jit(lambda k, c: fn(variations, k, initials, c))(keys, currents)


def _jaxpr(fn, variations, keys, initials, currents):
  return jax.make_jaxpr(lambda k, c: fn(variations, k, initials, c))(
      keys, currents
  ).jaxpr


def _together(variations, keys, initials, currents):
  states = [
      structures.initial_state(v, iv) for v, iv in zip(variations, initials)
  ]
  with variation.evaluation_round(keys[0]):
    return structures.sample_each(variations, states, keys, initials, currents)


# Each made anew per binding, as a task binds them: equal, not identical.
_MAKERS = {
    'uniform': lambda: distributions.Uniform(0.9, 1.1),
    'uniform_integer': lambda: distributions.UniformInteger(0, 7),
    'normal': lambda: distributions.Normal(
        loc=np.array([0.0, 1.0, 2.0]), scale=0.5
    ),
    'lognormal': lambda: distributions.LogNormal(0.0, 0.3),
    'exponential': lambda: distributions.Exponential(2.0),
    'bernoulli': lambda: distributions.Bernoulli(0.3),
    'multiplicative': lambda: noises.Multiplicative(
        distributions.Uniform(0.9, 1.1)
    ),
    'additive_cumulative': lambda: noises.Additive(
        distributions.Normal(0.0, 0.1), cumulative=True
    ),
    'arithmetic': lambda: -(
        distributions.Uniform() * 2.0 + distributions.Normal()
    ),
    'single_sample': lambda: distributions.Uniform(
        -1.0, 1.0, single_sample=True
    ),
}


@pytest.mark.parametrize('name', sorted(_MAKERS))
def test_equal_variations_draw_what_each_draws_alone_in_one_call(name):
  n = 5
  variations = [_MAKERS[name]() for _ in range(n)]
  keys = list(jax.random.split(jax.random.key(7), n))
  initials = [np.full((3,), 1.0 + i, np.float32) for i in range(n)]
  currents = [jnp.full((3,), 2.0 - i, jnp.float32) for i in range(n)]

  expected = _run(_one_by_one, variations, keys, initials, currents)
  got = _run(_together, variations, keys, initials, currents)
  for (value, state), (want, want_state) in zip(got, expected):
    np.testing.assert_array_equal(np.asarray(value), np.asarray(want))
    assert jax.tree.structure(state) == jax.tree.structure(want_state)

  alone = _jaxpr(_one_by_one, variations, keys, initials, currents)
  together = _jaxpr(_together, variations, keys, initials, currents)
  assert _draws(together) * n == _draws(alone) > 0


def test_variations_group_by_equality_and_shape():
  uniform = lambda: distributions.Uniform(0.9, 1.1)
  variations = [
      uniform(),
      distributions.Uniform(0.8, 1.2),
      uniform(),
      uniform(),
  ]
  initials = [
      np.ones((), np.float32),
      np.ones((), np.float32),
      np.ones((), np.float32),
      np.ones((2,), np.float32),  # another shape: a group of its own
  ]
  keys = list(jax.random.split(jax.random.key(1), 4))
  currents = [None] * 4
  jaxpr = _jaxpr(_together, variations, keys, initials, currents)
  # {0, 2}, {1}, {3}.
  assert _draws(jaxpr) == 3
  got = _run(_together, variations, keys, initials, currents)
  expected = _run(_one_by_one, variations, keys, initials, currents)
  for (value, _), (want, _) in zip(got, expected):
    np.testing.assert_array_equal(np.asarray(value), np.asarray(want))


class _Doubled(distributions.Uniform):
  """A user's subclass: it does not say that it batches."""

  def _draw(self, key, shape, low, high):
    return 2.0 * super()._draw(key, shape, low, high)


def _broadcast_proxy():
  broadcaster = variation_broadcaster.VariationBroadcaster(
      distributions.Uniform()
  )
  return lambda: broadcaster.get_proxy()


@pytest.mark.parametrize(
    'make, initial',
    [
        (lambda: _Doubled(0.0, 1.0), np.ones((), np.float32)),
        (_broadcast_proxy(), np.ones((), np.float32)),
        (
            lambda: (lambda initial, current, key: jax.random.uniform(key)),
            np.ones((), np.float32),
        ),
        (lambda: distributions.Uniform(0.9, 1.1), 1.0),  # a Python number
        (lambda: distributions.Poisson(3.0), np.ones((), np.float32)),
    ],
    ids=[
        'subclass',
        'broadcaster_proxy',
        'callable',
        'python_number',
        'poisson',
    ],
)
def test_what_may_not_batch_is_drawn_one_by_one(make, initial):
  n = 3
  variations = [make() for _ in range(n)]
  keys = list(jax.random.split(jax.random.key(2), n))
  initials, currents = [initial] * n, [None] * n
  jaxpr = _jaxpr(_together, variations, keys, initials, currents)
  alone = _jaxpr(_one_by_one, variations, keys, initials, currents)
  assert _draws(jaxpr) == _draws(alone) >= n - 1
  got = _run(_together, variations, keys, initials, currents)
  expected = _run(_one_by_one, variations, keys, initials, currents)
  for (value, _), (want, _) in zip(got, expected):
    np.testing.assert_array_equal(np.asarray(value), np.asarray(want))
