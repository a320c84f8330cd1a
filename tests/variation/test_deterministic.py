"""Tests for mjx_composer.variation.deterministic."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_composer.variation import deterministic
from mjx_composer.variation import distributions

KEY = jax.random.key(0)


# ----------------------------------------------------------------- Constant.


def test_constant():
  np.testing.assert_array_equal(deterministic.Constant([1, 2])(), [1, 2])
  assert (
      deterministic.Constant(3)(jnp.zeros(5)) == 3
  )  # Ignores the initial value.
  structure = {"a": 1}
  assert deterministic.Constant(structure)() is structure  # Non-numeric: as is.
  assert repr(deterministic.Constant(3)) == "Constant(3)"
  assert str(deterministic.Constant(3)) == "3"
  assert deterministic.Constant([1, 2]) == deterministic.Constant(
      np.array([1, 2])
  )
  low, high = deterministic.Constant([1, 2]).static_bounds()
  np.testing.assert_array_equal(low, [1, 2])
  np.testing.assert_array_equal(high, [1, 2])


def test_identity_returns_current_value():
  identity = deterministic.Identity()
  assert identity(1.0, 2.0) == 2.0
  assert identity(1.0) is None


# ----------------------------------------------------------------- Sequence.


def _scan_sequence(sequence, n, key=KEY):
  def step(state, key):
    value, state = sequence.sample(state, key)
    return state, value

  _, values = jax.jit(lambda s, k: jax.lax.scan(step, s, k))(
      sequence.initial_state(), jax.random.split(key, n)
  )
  return np.asarray(values)


def test_sequence_cycles_in_order_and_wraps_around():
  values = _scan_sequence(deterministic.Sequence([3, 1, 2]), 7)
  np.testing.assert_array_equal(values, [3, 1, 2, 3, 1, 2, 3])


def test_sequence_of_arrays():
  values = _scan_sequence(deterministic.Sequence(np.array([[0, 1], [2, 3]])), 3)
  np.testing.assert_array_equal(values, [[0, 1], [2, 3], [0, 1]])


def test_sequence_evaluates_variation_items():
  sequence = deterministic.Sequence(
      [distributions.Uniform(10, 11), 0, deterministic.Sequence([5, 6])]
  )
  values = _scan_sequence(sequence, 6)
  assert (
      10 <= values[0] < 11 and 10 <= values[3] < 11 and values[0] != values[3]
  )
  assert values[1] == values[4] == 0
  # The inner sequence only advances when it is the item evaluated.
  assert (values[2], values[5]) == (5, 6)
  assert values.dtype == np.float32  # Items' dtypes are promoted.


def test_sequence_state_and_call():
  sequence = deterministic.Sequence([1, 2])
  state = sequence.initial_state()
  assert (
      isinstance(state, deterministic.SequenceState) and int(state.index) == 0
  )
  value, state = sequence.sample(state, None)
  assert (int(value), int(state.index)) == (1, 1)
  # __call__ starts from a fresh state, so it is always the first value.
  assert sequence() == 1 and sequence() == 1


def test_sequence_state_batched_over_worlds():
  sequence = deterministic.Sequence([1, 2, 3])
  state = jax.tree.map(
      lambda x: jnp.broadcast_to(x, (4,) + x.shape), sequence.initial_state()
  )
  state = state._replace(
      index=jnp.arange(4, dtype=jnp.int32)
  )  # Worlds at different positions.
  values, state = jax.vmap(lambda s: sequence.sample(s, None))(state)
  np.testing.assert_array_equal(values, [1, 2, 3, 1])
  np.testing.assert_array_equal(state.index, [1, 2, 0, 1])


def test_sequence_errors_and_bounds():
  with pytest.raises(ValueError, match="at least one value"):
    deterministic.Sequence([])
  with pytest.raises(ValueError, match="same shape"):
    deterministic.Sequence([1, [1, 2]])
  with pytest.raises(ValueError, match="same shape"):
    deterministic.Sequence(
        [distributions.Uniform(), distributions.Uniform([0, 0], 1)]
    ).sample(deterministic.Sequence([0]).initial_state(), KEY)
  with pytest.raises(ValueError, match=r"Sequence\(\[1, 2\]\) is stateful"):
    deterministic.Sequence([1, 2]).sample(None, None)
  low, high = deterministic.Sequence([3, 1, 2]).static_bounds()
  assert (int(low), int(high)) == (1, 3)
  low, high = deterministic.Sequence(
      [distributions.UniformInteger(0, 3), 5]
  ).static_bounds()
  assert (int(low), int(high)) == (0, 5)
