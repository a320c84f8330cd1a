"""Tests for mjx_composer.variation.base: arithmetic, evaluate, keys, state."""

import collections
import operator

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_composer import variation
from mjx_composer.variation import deterministic
from mjx_composer.variation import distributions

KEY = jax.random.key(0)
fold_in = jax.random.fold_in


# ---------------------------------------------------------------- arithmetic.

BINARY_OPS = ["add", "sub", "mul", "truediv", "floordiv", "pow"]


@pytest.mark.parametrize("name", BINARY_OPS)
def test_binary_operators_in_every_operand_order(name):
  func = getattr(operator, name)
  c3, c5 = deterministic.Constant(3), deterministic.Constant(5)
  expected = func(3, 5)
  for expression in [func(3, c5), func(c3, 5), func(c3, c5)]:
    assert isinstance(expression, variation.Variation)
    np.testing.assert_allclose(
        variation.evaluate(expression), expected, rtol=1e-6
    )
  assert func(c3, c5) == func(c3, c5)
  assert func(c3, c5) != func(c3, c3)
  assert func(c3, c5) != func(c5, c3)


def test_unary_negation():
  assert variation.evaluate(-deterministic.Constant(3)) == -3
  u = distributions.Uniform(1.0, 2.0)
  np.testing.assert_array_equal((-u)(key=KEY), -u(key=KEY))


def test_numpy_and_jax_scalars_defer_to_reflected_operators():
  u = distributions.Uniform()
  for scalar in [np.float64(2.0), np.int32(2), jnp.float32(2.0)]:
    expression = scalar * u
    assert isinstance(expression, variation.Variation), type(expression)
    np.testing.assert_allclose(
        expression(key=KEY), 2 * u(key=fold_in(KEY, 1)), rtol=1e-6
    )


def test_composition_computes_what_it_says():
  u = distributions.Uniform()
  # A binary node gives operand i the key fold_in(key, i); a single operand
  # (unary, indexing) gets the key unchanged.
  u_left = lambda key: u(key=fold_in(key, 0))
  u_right = lambda key: u(key=fold_in(key, 1))
  cases = [
      ((u + 1) * 2, lambda k: (u_left(fold_in(k, 0)) + 1) * 2),
      (2 - u, lambda k: 2 - u_right(k)),
      (1 / (u + 1), lambda k: 1 / (u_left(fold_in(k, 1)) + 1)),
      (2**u, lambda k: 2 ** u_right(k)),
      (u**2 // 0.25, lambda k: u_left(fold_in(k, 0)) ** 2 // 0.25),
      (-(u * 3), lambda k: -(u_left(k) * 3)),
      (u - u, lambda k: u_left(k) - u_right(k)),
  ]
  for key in jax.random.split(KEY, 5):
    for expression, expected in cases:
      np.testing.assert_allclose(expression(key=key), expected(key), rtol=1e-6)


def test_operands_get_independent_subkeys():
  # If both operands shared a key, u - u would be 0 and u + u would be 2u.
  u = distributions.Uniform()
  n = 40_000
  diff = np.asarray(
      jax.jit(lambda k: (u - u)(jnp.zeros(n), None, k))(KEY), np.float64
  )
  assert np.all(diff != 0)
  # Difference of two independent U(0, 1): mean 0, variance 1/6.
  assert abs(diff.mean()) < 5 * np.sqrt(1 / 6 / n)
  assert abs(diff.var() - 1 / 6) < 5 * np.sqrt(
      (1 / 15 - 1 / 36) / n
  )  # E[d^4] = 1/15.


def test_operand_values_follow_the_initial_value_shape():
  u = distributions.Uniform()
  value = (u * 2 + u)(jnp.zeros(3), None, KEY)
  assert value.shape == (3,)


def test_getitem():
  value = deterministic.Constant(np.array([4, 5, 6, 7, 8]))
  np.testing.assert_array_equal(variation.evaluate(value[[3, 1]]), [7, 5])
  np.testing.assert_array_equal(variation.evaluate(value[1:3]), [5, 6])
  assert variation.evaluate(value[3]) == 7
  grid = deterministic.Constant(np.arange(6).reshape(2, 3))
  np.testing.assert_array_equal(
      variation.evaluate(grid[:, [0, 2]]), [[0, 2], [3, 5]]
  )
  u = distributions.Uniform([0, 10, 20], [1, 11, 21])
  np.testing.assert_array_equal(u[1](key=KEY), u(key=KEY)[1])


def test_str_and_repr():
  c3, c5 = deterministic.Constant(3), deterministic.Constant(5)
  assert str(c3 + c5) == "3 + 5"
  assert repr(c3 + c5) == "Constant(3) + Constant(5)"
  u = distributions.Uniform()
  assert str(u + 2) == "Uniform(low=0.0, high=1.0) + 2"
  assert str((u + 1) * 2) == "(Uniform(low=0.0, high=1.0) + 1) * 2"
  assert str(2 - (u - 1)) == "2 - (Uniform(low=0.0, high=1.0) - 1)"
  assert str(u * 2 + 1) == "Uniform(low=0.0, high=1.0) * 2 + 1"
  assert str(-(u + 1)) == "-(Uniform(low=0.0, high=1.0) + 1)"
  assert str(2**u**2) == "2 ** Uniform(low=0.0, high=1.0) ** 2"
  assert str((2**u) ** 2) == "(2 ** Uniform(low=0.0, high=1.0)) ** 2"
  assert str(u[1:3]) == "Uniform(low=0.0, high=1.0)[1:3]"
  assert (
      str(deterministic.Constant(np.array([4, 5]))[[1, 0]]) == "[4 5][[1, 0]]"
  )
  assert repr((u + 1)[0]) == "(Uniform(low=0.0, high=1.0) + 1)[0]"


def test_variations_are_not_iterable():
  with pytest.raises(TypeError, match="not iterable"):
    list(distributions.Uniform())


# ---------------------------------------------------------------- evaluate.

Pose = collections.namedtuple("Pose", ["pos", "quat"])


def test_evaluate_nested_structures():
  u = distributions.Uniform(10.0, 11.0)
  structure = {
      "pose": Pose(pos=[u, 0.5, u], quat=(1, 0, 0, 0)),
      "mass": u * 2,
      "name": "box",
      "count": 3,
  }
  values = variation.evaluate(structure, key=KEY)
  assert isinstance(values["pose"], Pose)
  assert values["name"] == "box"
  assert (
      values["count"] == 3 and type(values["count"]) is int
  )  # Constants pass through.
  assert values["pose"].quat == (1, 0, 0, 0)
  assert values["pose"].pos[1] == 0.5
  pos0, pos2 = values["pose"].pos[0], values["pose"].pos[2]
  assert 10 <= pos0 < 11 and 10 <= pos2 < 11 and pos0 != pos2
  assert 20 <= values["mass"] < 22


def test_evaluate_leaf_keys_are_fold_in_of_flat_index():
  u = distributions.Uniform()
  structure = [1.0, u, {"a": u, "b": 2.0}]
  values = variation.evaluate(structure, key=KEY)
  np.testing.assert_array_equal(values[1], u(key=fold_in(KEY, 1)))
  np.testing.assert_array_equal(values[2]["a"], u(key=fold_in(KEY, 2)))
  # A bare variation gets the key unchanged.
  np.testing.assert_array_equal(variation.evaluate(u, key=KEY), u(key=KEY))


def test_evaluate_leaf_value_does_not_depend_on_other_leaves():
  u, n = distributions.Uniform(), distributions.Normal()
  a = variation.evaluate([u, u], key=KEY)
  b = variation.evaluate([u, n], key=KEY)
  c = variation.evaluate([u, 7.0], key=KEY)
  np.testing.assert_array_equal(a[0], b[0])
  np.testing.assert_array_equal(a[0], c[0])


def test_evaluate_initial_values_per_leaf_or_whole():
  noise = variation.noises.Additive(1.0)
  shape_of = distributions.Uniform()
  # A structure matching `structure` is split leaf by leaf.
  values = variation.evaluate(
      {"a": noise, "b": [noise, shape_of]},
      initial_value={"a": 1.0, "b": [jnp.full(2, 10.0), jnp.zeros((4, 5))]},
      key=KEY,
  )
  assert values["a"] == 2.0
  np.testing.assert_array_equal(values["b"][0], [11.0, 11.0])
  assert values["b"][1].shape == (4, 5)
  # Anything else is handed whole to every leaf, as composer does.
  values = variation.evaluate(
      [noise, shape_of], initial_value=jnp.zeros(3), key=KEY
  )
  np.testing.assert_array_equal(values[0], [1.0, 1.0, 1.0])
  assert values[1].shape == (3,)
  # current_value likewise.
  identity = deterministic.Identity()
  assert variation.evaluate([identity, identity], current_value=[1, 2]) == [
      1,
      2,
  ]


def test_evaluate_calls_plain_callables_like_composer():
  def scaled_initial(initial_value, current_value, key):
    return initial_value * 10 + jax.random.uniform(key)

  values = variation.evaluate([scaled_initial, 5], initial_value=2.0, key=KEY)
  np.testing.assert_allclose(
      values[0], 20 + jax.random.uniform(fold_in(KEY, 0))
  )
  assert values[1] == 5


# -------------------------------------------------------------------- keys.


EXPRESSION = (
    distributions.Uniform() + distributions.Normal(loc=[0.0, 1.0, 2.0])
) * 2 + (distributions.UniformInteger(0, 10))
# One jitted function shared by the tests below: it compiles once per batch
# size and key type.
_sample_batch = jax.jit(jax.vmap(lambda k: EXPRESSION(jnp.zeros(3), None, k)))


def test_same_key_same_value_whatever_the_batch_size():
  keys = jax.random.split(KEY, 64)
  small = _sample_batch(keys[:8])
  large = _sample_batch(keys)
  np.testing.assert_array_equal(small, large[:8])
  # And equal to an unbatched evaluation.
  single = jax.jit(lambda k: EXPRESSION(jnp.zeros(3), None, k))(keys[3])
  np.testing.assert_array_equal(small[3], single)


def test_different_keys_give_different_values():
  values = np.asarray(_sample_batch(jax.random.split(KEY, 64)))
  assert len(np.unique(values[:, 0])) == 64


def test_typed_and_legacy_keys():
  typed_keys = jax.random.split(KEY, 8)
  legacy_keys = jax.random.split(jax.random.PRNGKey(0), 8)
  assert legacy_keys.dtype == jnp.uint32
  # Same key data, same values.
  np.testing.assert_array_equal(
      _sample_batch(typed_keys), _sample_batch(legacy_keys)
  )


# ------------------------------------------------------------------ errors.


def test_missing_key_names_the_variation():
  with pytest.raises(
      ValueError, match=r"^Uniform\(low=0.0, high=1.0\) draws random numbers"
  ):
    distributions.Uniform()()
  # In a composite, the random node itself is named.
  with pytest.raises(
      ValueError, match=r"^Normal\(loc=0.0, scale=1.0\) draws random numbers"
  ):
    variation.evaluate(
        {"x": deterministic.Constant(1) + distributions.Normal()}
    )
  # Deterministic expressions need no key.
  assert variation.evaluate(deterministic.Constant(2) * 3) == 6


def test_numpy_random_state_or_int_key_is_rejected():
  with pytest.raises(TypeError, match="numpy random state"):
    distributions.Uniform()(None, None, np.random.RandomState(0))
  with pytest.raises(TypeError, match=r"key must be a JAX PRNG key"):
    variation.evaluate(distributions.Uniform(), key=0)


# ------------------------------------------------------------------- state.


def test_stateless_expressions_have_no_state():
  expression = distributions.Uniform() * 2 + distributions.Normal(
      distributions.Uniform()
  )
  assert expression.initial_state() is None
  assert variation.initial_state([expression, 1.0, {"a": expression}]) is None
  value, state = expression.sample(None, KEY)
  assert state is None
  np.testing.assert_array_equal(value, expression(key=KEY))


def test_composites_thread_the_states_of_stateful_operands():
  sequence = deterministic.Sequence([0.0, 10.0, 20.0])
  expression = (sequence + distributions.Uniform()) * 2

  def step(state, key):
    value, state = expression.sample(state, key)
    return state, value

  keys = jax.random.split(KEY, 7)
  _, values = jax.jit(lambda s, k: jax.lax.scan(step, s, k))(
      expression.initial_state(), keys
  )
  values = np.asarray(values)
  np.testing.assert_array_equal(
      np.floor(values / 20) * 10, [0, 10, 20, 0, 10, 20, 0]
  )
  # __call__ is the value from a fresh state: the first element.
  assert 0 <= expression(key=KEY) < 2


def test_structure_state_threads_each_leaf():
  structure = {
      "seq": deterministic.Sequence([1, 2]),
      "walk": [distributions.BiasedRandomWalk(stdev=1.0, timescale=0.0), 5.0],
      "plain": distributions.Uniform(),
  }
  state = variation.initial_state(structure)
  seqs = []
  for i in range(4):
    values, state = variation.sample(structure, state, jax.random.key(i))
    seqs.append(int(values["seq"]))
    assert values["walk"][1] == 5.0
    # Leaves in dm-tree order: plain (0), seq (1), walk[0] (2), walk[1] (3).
    # With timescale 0 the walk is an independent N(0, 1) draw each time.
    np.testing.assert_allclose(
        values["walk"][0],
        jax.random.normal(fold_in(jax.random.key(i), 2)),
        rtol=1e-6,
    )
  assert seqs == [1, 2, 1, 2]
  # A None state for a stateful structure is an error naming the variation.
  with pytest.raises(ValueError, match=r"Sequence\(\[1, 2\]\) is stateful"):
    variation.sample(structure, None, KEY)


def test_state_can_be_batched_over_worlds():
  walk = distributions.BiasedRandomWalk(stdev=1.0, timescale=5.0)
  worlds = 16
  state = jax.tree.map(
      lambda x: jnp.broadcast_to(x, (worlds,) + x.shape), walk.initial_state()
  )
  keys = jax.random.split(KEY, worlds)
  values, new_state = jax.vmap(walk.sample)(state, keys)
  assert values.shape == (worlds,) and len(np.unique(values)) == worlds
  np.testing.assert_array_equal(values, new_state)


# ----------------------------------------------------------- static bounds.


def test_interval_arithmetic_bounds():
  def bounds(v):
    low, high = v.static_bounds()
    return float(low), float(high)

  u = distributions.Uniform(1.0, 3.0)
  i = distributions.UniformInteger(-2, 3)  # [-2, 2]
  assert bounds(u + 1) == (2.0, 4.0)
  assert bounds(10 - u) == (7.0, 9.0)
  assert bounds(u - i) == (-1.0, 5.0)
  assert bounds(u * i) == (-6.0, 6.0)
  assert bounds(-u * 2) == (-6.0, -2.0)
  assert bounds(i / u) == (-2.0, 2.0)
  assert bounds(6 // u) == (2.0, 6.0)
  assert bounds(u[0]) == (1.0, 3.0)
  assert (u / i).static_bounds() is None  # The divisor's range contains 0.
  assert (u**2).static_bounds() is None
  assert (u + distributions.Normal()).static_bounds() is None
  low, high = variation.static_bounds([u, 0.5])
  np.testing.assert_array_equal(low, [1.0, 0.5])
  np.testing.assert_array_equal(high, [3.0, 0.5])


# ------------------------------------------------------------- subclassing.


class _ComposerStyle(variation.Variation):
  """A stateless variation written as in composer: it overrides __call__."""

  def __call__(self, initial_value=None, current_value=None, key=None):
    return initial_value + jax.random.uniform(key)


def test_composer_style_subclass_composes():
  v = _ComposerStyle()
  np.testing.assert_allclose(v(1.0, None, KEY), 1.0 + jax.random.uniform(KEY))
  np.testing.assert_allclose(
      (v * 2)(1.0, None, KEY), 2 * v(1.0, None, fold_in(KEY, 0))
  )
  assert (
      variation.evaluate({"a": v}, initial_value={"a": 5.0}, key=KEY)["a"]
      >= 5.0
  )


def test_subclass_without_sample_is_a_clear_error():
  class Empty(variation.Variation):
    pass

  with pytest.raises(NotImplementedError, match="Empty must implement _sample"):
    Empty()()
