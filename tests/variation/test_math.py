"""Tests for mjx_composer.variation.math."""

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer import variation
from mjx_composer.variation import deterministic
from mjx_composer.variation import distributions
from mjx_composer.variation import math as vmath


def test_math_ops_evaluate_their_arguments():
  c = deterministic.Constant(np.array([1.0, 4.0, 2.0]))
  np.testing.assert_allclose(
      variation.evaluate(vmath.Log(c)), np.log([1.0, 4.0, 2.0])
  )
  assert variation.evaluate(vmath.Max(c)) == 4.0
  assert variation.evaluate(vmath.Min(c)) == 1.0
  np.testing.assert_allclose(variation.evaluate(vmath.Norm(c)), np.sqrt(21.0))
  # numpy semantics: a list is stacked; axis gives an elementwise max.
  assert variation.evaluate(vmath.Max([deterministic.Constant(3), 5])) == 5
  np.testing.assert_array_equal(
      variation.evaluate(vmath.Max([c, np.array([2.0, 2.0, 2.0])], axis=0)),
      [2.0, 4.0, 2.0],
  )


def test_math_ops_with_random_arguments():
  u = distributions.Uniform()
  key = jax.random.key(3)
  np.testing.assert_allclose(
      vmath.Log(u)(key=key), jnp.log(u(key=key)), rtol=1e-6
  )
  # Max([u, u]): the two list leaves get independent subkeys.
  value = vmath.Max([u, u])(key=key)
  assert value == max(
      u(key=jax.random.fold_in(key, 0)), u(key=jax.random.fold_in(key, 1))
  )
  assert vmath.Max(u)(jnp.zeros(5), None, key) == jnp.max(
      u(jnp.zeros(5), None, key)
  )


def test_math_repr_eq_and_bounds():
  assert repr(vmath.Max([1, 2], axis=0)) == "Max([1, 2], axis=0)"
  assert vmath.Log(2.0) == vmath.Log(2.0) and vmath.Log(2.0) != vmath.Log(3.0)
  assert vmath.Max(2.0) != vmath.Min(2.0)
  low, high = vmath.Max([distributions.Uniform(0.0, 2.0), 1.0]).static_bounds()
  assert (float(low), float(high)) == (1.0, 2.0)
  low, high = vmath.Min(
      [distributions.UniformInteger(-3, 0), 1]
  ).static_bounds()
  assert (int(low), int(high)) == (-3, -1)
  assert vmath.Max([1.0, 2.0], axis=0).static_bounds() is None
  assert vmath.Max(distributions.Normal()).static_bounds() is None
