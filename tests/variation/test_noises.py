"""Tests for mjx_composer.variation.noises (composer's noises_test, plus jit)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_composer.variation import deterministic
from mjx_composer.variation import distributions
from mjx_composer.variation import noises

NUM_ITERATIONS = 100


def _amount(amount, use_constant_variation_object):
  return (
      deterministic.Constant(amount)
      if use_constant_variation_object
      else amount
  )


def _iterate(variation, initial_value, n=NUM_ITERATIONS):
  """Feeds each result back as the next current value, as a variator would."""
  current_value = initial_value
  values = []
  for _ in range(n):
    current_value = variation(
        initial_value=initial_value, current_value=current_value
    )
    values.append(float(current_value))
  return values


@pytest.mark.parametrize("use_constant", [False, True])
def test_additive(use_constant):
  variation = noises.Additive(_amount(2, use_constant))
  assert _iterate(variation, 0.0) == [2.0] * NUM_ITERATIONS


@pytest.mark.parametrize("use_constant", [False, True])
def test_additive_cumulative(use_constant):
  amount, initial = 3, 1.0
  variation = noises.Additive(_amount(amount, use_constant), cumulative=True)
  expected = [initial + amount * (i + 1) for i in range(NUM_ITERATIONS)]
  assert _iterate(variation, initial) == expected


@pytest.mark.parametrize("use_constant", [False, True])
def test_multiplicative(use_constant):
  variation = noises.Multiplicative(_amount(23, use_constant))
  assert _iterate(variation, 3.0) == [69.0] * NUM_ITERATIONS


@pytest.mark.parametrize("use_constant", [False, True])
def test_multiplicative_cumulative(use_constant):
  amount, initial = 2, 3.0
  variation = noises.Multiplicative(
      _amount(amount, use_constant), cumulative=True
  )
  # 3 * 2**100 is exact in float32.
  expected = [initial * amount ** (i + 1) for i in range(NUM_ITERATIONS)]
  assert _iterate(variation, initial) == expected


def test_cumulative_noise_in_a_jitted_scan():
  variation = noises.Multiplicative(
      deterministic.Constant(2.0), cumulative=True
  )
  initial = jnp.asarray([1.0, 3.0])

  def step(current, _):
    current = variation(initial, current)
    return current, current

  _, values = jax.jit(lambda: jax.lax.scan(step, initial, None, length=10))()
  expected = np.asarray(initial)[None] * 2.0 ** np.arange(1, 11)[:, None]
  np.testing.assert_array_equal(values, expected)


def test_random_amount_has_the_shape_of_the_initial_value():
  initial = jnp.arange(4.0)
  variation = noises.Additive(distributions.Normal(0.0, 0.1))
  key = jax.random.key(0)
  value = variation(initial, None, key)
  assert value.shape == (4,)
  # The single operand gets the node's key unchanged.
  np.testing.assert_allclose(
      value, initial + 0.1 * jax.random.normal(key, (4,)), rtol=1e-6
  )
  # Non-cumulative ignores the current value.
  np.testing.assert_array_equal(variation(initial, initial + 100, key), value)


def test_missing_base_value_is_a_clear_error():
  message = r"^Additive\(1.0\) acts on initial_value, but initial_value is None"
  with pytest.raises(ValueError, match=message):
    noises.Additive(1.0)(current_value=1.0)
  with pytest.raises(
      ValueError, match=r"acts on current_value, but current_value is None"
  ):
    noises.Multiplicative(2.0, cumulative=True)(initial_value=1.0)


def test_repr_and_eq():
  assert repr(noises.Additive(distributions.Normal(), cumulative=True)) == (
      "Additive(Normal(loc=0.0, scale=1.0), cumulative=True)"
  )
  assert noises.Additive(1.0) == noises.Additive(1.0)
  assert noises.Additive(1.0) != noises.Additive(1.0, cumulative=True)
  assert noises.Additive(1.0) != noises.Multiplicative(1.0)
