"""Tests for observables (ports composer's observable/base_test)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_composer.observation import fake_physics
from mjx_composer.observation.observable import base


def _add_twelve(value, key):
  del key
  return value + 12


def test_generic_returns_the_callable_output():
  physics = fake_physics.FakePhysics.create().step().step()
  obs = base.Generic(lambda p: 3 * p.time())
  assert int(obs(physics)) == 6


def test_properties_round_trip():
  obs = base.Generic(
      lambda p: 0,
      update_interval=2,
      buffer_size=3,
      delay=4,
      aggregator='max',
      corruptor=_add_twelve,
  )
  assert (obs.update_interval, obs.buffer_size, obs.delay) == (2, 3, 4)
  assert obs.aggregator is base.AGGREGATORS['max']
  assert obs.corruptor is _add_twelve
  assert obs.enabled is False  # Observables start disabled.
  obs.update_interval, obs.buffer_size, obs.delay = 5, 6, 7
  obs.aggregator = 'sum'
  obs.enabled = True
  assert (obs.update_interval, obs.buffer_size, obs.delay) == (5, 6, 7)
  assert obs.aggregator is base.AGGREGATORS['sum']
  assert obs.enabled
  custom = lambda x: x[0]
  obs.configure(aggregator=custom, corruptor=None)
  assert obs.aggregator is custom and obs.corruptor is None
  assert obs.array_spec is None


def test_defaults_match_composer():
  obs = base.Generic(lambda p: 0)
  assert obs.update_interval == 1
  assert obs.buffer_size is None and obs.delay is None
  assert obs.aggregator is None and obs.corruptor is None


def test_corruptor():
  obs = base.Generic(lambda p: jnp.zeros(2), corruptor=_add_twelve)
  physics = fake_physics.FakePhysics.create()
  np.testing.assert_array_equal(obs(physics, key=jax.random.key(0)), [12, 12])
  with pytest.raises(ValueError, match='needs a PRNG key'):
    obs(physics)


def test_corruptor_receives_a_key():
  obs = base.Generic(
      lambda p: jnp.zeros(3),
      corruptor=lambda v, key: v + jax.random.normal(key, v.shape),
  )
  physics = fake_physics.FakePhysics.create()
  first = obs(physics, key=jax.random.key(0))
  np.testing.assert_array_equal(first, obs(physics, key=jax.random.key(0)))
  assert not np.allclose(first, obs(physics, key=jax.random.key(1)))


def test_invalid_aggregator_name():
  with pytest.raises(KeyError, match='Unrecognized aggregator name'):
    base.Generic(lambda p: 0, aggregator='invalid')
  obs = base.Generic(lambda p: 0)
  with pytest.raises(KeyError, match='Unrecognized aggregator name'):
    obs.aggregator = 'median_of_means'


def test_builtin_aggregators_reduce_axis_zero():
  values = jnp.array([[1.0, 5.0], [3.0, -1.0], [2.0, 2.0]])
  expected = {
      'min': [1.0, -1.0],
      'max': [3.0, 5.0],
      'mean': [2.0, 2.0],
      'median': [2.0, 2.0],
      'sum': [6.0, 6.0],
  }
  for name, value in expected.items():
    np.testing.assert_allclose(base.AGGREGATORS[name](values), value)
  assert [n for n, a in base.AGGREGATORS.items() if a.preserves_bounds] == [
      'min',
      'max',
      'mean',
      'median',
  ]


def test_configure_rejects_unknown_options():
  obs = base.Generic(lambda p: 0)
  with pytest.raises(
      AttributeError, match='Cannot add attribute asdf in configure.'
  ):
    obs.configure(asdf=1)
  with pytest.raises(AttributeError, match='Cannot add attribute configure'):
    obs.configure(configure=None)
