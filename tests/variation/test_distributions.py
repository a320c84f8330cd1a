"""Tests for mjx_composer.variation.distributions.

composer's tests compare each distribution with numpy's stream for the same
seed; JAX keys cannot reproduce numpy streams, so these tests check the
distributions themselves: moments on many samples (tolerance: Z standard
errors of the estimator), supports, shapes, `single_sample`, parameters that
are variations, reprs and errors.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_composer import variation
from mjx_composer.variation import deterministic
from mjx_composer.variation import distributions

N = 40_000
# Tolerance in standard errors. Keys are fixed, so tests are deterministic; a
# correct sampler passes a 5-SE check with probability > 1 - 6e-7.
Z = 5.0


def draw(dist, n=N, seed=0):
  """n iid samples: the shape rule gives one draw per element of initial_value."""
  fn = jax.jit(lambda key: dist(jnp.zeros(n), None, key))
  return np.asarray(fn(jax.random.key(seed)))


def assert_moments(samples, mean, var, fourth_central_moment):
  """Sample mean and variance within Z standard errors of the true ones."""
  samples = np.asarray(samples, np.float64)
  n = samples.size
  mean_se = np.sqrt(var / n)
  assert abs(samples.mean() - mean) < Z * mean_se, (
      samples.mean(),
      mean,
      mean_se,
  )
  var_se = np.sqrt((fourth_central_moment - var**2) / n)
  assert abs(samples.var() - var) < Z * var_se, (samples.var(), var, var_se)


def assert_proportion(hits, n, p):
  se = np.sqrt(p * (1 - p) / n)
  assert abs(hits / n - p) < Z * se, (hits / n, p, se)


# ----------------------------------------------------------------- moments.


def test_uniform_moments_and_support():
  low, high = 2.0, 5.0
  samples = draw(distributions.Uniform(low, high))
  width = high - low
  assert_moments(samples, (low + high) / 2, width**2 / 12, width**4 / 80)
  assert samples.min() >= low and samples.max() < high


def test_uniform_low_above_high_samples_between_like_numpy():
  samples = draw(distributions.Uniform(5.0, 2.0))
  assert samples.min() > 2.0 and samples.max() <= 5.0
  assert_moments(samples, 3.5, 9 / 12, 81 / 80)


def test_uniform_integer_support_and_frequencies():
  samples = draw(distributions.UniformInteger(3, 7))
  assert samples.dtype == np.int32
  assert set(np.unique(samples)) == {3, 4, 5, 6}  # high is exclusive.
  for value in range(3, 7):
    assert_proportion(np.sum(samples == value), N, 0.25)


def test_uniform_integer_single_argument_is_range_from_zero():
  samples = draw(distributions.UniformInteger(3))
  assert set(np.unique(samples)) == {0, 1, 2}


def test_normal_moments():
  loc, scale = 1.0, 2.0
  samples = draw(distributions.Normal(loc=loc, scale=scale))
  assert_moments(samples, loc, scale**2, 3 * scale**4)


def test_lognormal_log_is_normal():
  mean, sigma = 0.5, 0.3
  samples = draw(distributions.LogNormal(mean=mean, sigma=sigma))
  assert samples.min() > 0
  assert_moments(np.log(samples), mean, sigma**2, 3 * sigma**4)


def test_exponential_moments():
  scale = 3.0
  samples = draw(distributions.Exponential(scale=scale))
  assert samples.min() >= 0
  assert_moments(samples, scale, scale**2, 9 * scale**4)


def test_poisson_moments_and_support():
  lam = 4.0
  samples = draw(distributions.Poisson(lam=lam))
  assert samples.dtype == np.int32 and samples.min() >= 0
  assert_moments(samples, lam, lam, lam * (1 + 3 * lam))


def test_bernoulli_values_and_frequency():
  samples = draw(distributions.Bernoulli(prob=0.3))
  assert samples.dtype == np.int32
  assert set(np.unique(samples)) == {0, 1}
  assert_proportion(samples.sum(), N, 0.3)


def test_uniform_choice_frequencies():
  choices = [1.5, -2.0, 7.0]
  samples = draw(distributions.UniformChoice(choices))
  assert set(np.unique(samples)) == set(choices)
  for choice in choices:
    assert_proportion(np.sum(samples == choice), N, 1 / 3)


def test_uniform_choice_integer_is_numpy_range_shorthand():
  samples = draw(distributions.UniformChoice(4))
  assert set(np.unique(samples)) == {0, 1, 2, 3}


def test_per_key_draws_have_the_same_distribution_as_per_element_draws():
  keys = jax.random.split(jax.random.key(3), N)
  dist = distributions.Normal(loc=-1.0, scale=0.5)
  samples = np.asarray(jax.jit(jax.vmap(lambda k: dist(key=k)))(keys))
  assert samples.shape == (N,)
  assert_moments(samples, -1.0, 0.25, 3 * 0.5**4)


# ------------------------------------------------------------------ shapes.


def test_sample_takes_shape_of_initial_value():
  key = jax.random.key(0)
  assert distributions.Uniform()(key=key).shape == ()
  assert distributions.Uniform()(jnp.zeros((2, 3)), key=key).shape == (2, 3)
  # Without an initial value, the parameters' broadcast shape.
  assert distributions.Uniform([0, 1, 2], 5.0)(key=key).shape == (3,)
  # Parameters broadcast against the initial value.
  value = distributions.Uniform([0.0, 10.0], [1.0, 11.0])(
      jnp.zeros((4, 2)), key=key
  )
  assert value.shape == (4, 2)
  assert np.all((value[:, 0] >= 0) & (value[:, 0] < 1))
  assert np.all((value[:, 1] >= 10) & (value[:, 1] < 11))
  assert len(np.unique(value)) == 8  # One draw per element.


@pytest.mark.parametrize(
    "dist",
    [
        distributions.Uniform(single_sample=True),
        distributions.Normal(single_sample=True),
        distributions.UniformInteger(0, 1000, single_sample=True),
        distributions.Exponential(single_sample=True),
        distributions.UniformChoice(
            [1, 2, 3, 4, 5, 6, 7, 8], single_sample=True
        ),
    ],
    ids=repr,
)
def test_single_sample_draws_once_and_broadcasts(dist):
  values = jax.vmap(lambda k: dist(jnp.zeros(5), None, k))(
      jax.random.split(jax.random.key(1), 64)
  )
  assert values.shape == (64, 5)
  np.testing.assert_array_equal(values, np.broadcast_to(values[:, :1], (64, 5)))
  assert len(np.unique(values[:, 0])) > 1  # Still random across keys.


def test_single_sample_keeps_parameter_shape():
  value = distributions.Uniform([0, 10], [1, 11], single_sample=True)(
      jnp.zeros((3, 2)), key=jax.random.key(0)
  )
  assert value.shape == (3, 2)
  np.testing.assert_array_equal(value, np.broadcast_to(value[0], (3, 2)))
  assert 0 <= value[0, 0] < 1 and 10 <= value[0, 1] < 11


def test_uniform_choice_rows():
  rows = np.array(
      [[1.0, 0.0, 0.0, 1.0], [0.0, 1.0, 0.0, 1.0], [0.0, 0.0, 1.0, 1.0]]
  )
  dist = distributions.UniformChoice(rows)
  key = jax.random.key(0)
  # An initial value with the row shape gets one row.
  one = dist(jnp.zeros(4), None, key)
  assert one.shape == (4,) and any(np.array_equal(one, r) for r in rows)
  # Leading axes of the initial value get independent rows.
  many = np.asarray(dist(jnp.zeros((N, 4)), None, key))
  counts = [np.sum(np.all(many == r, axis=1)) for r in rows]
  assert sum(counts) == N
  for count in counts:
    assert_proportion(count, N, 1 / 3)


def test_parameters_can_be_variations():
  # loc ~ U(0, 10) drawn per element (the initial value's shape), then
  # x ~ N(loc, 1): mean 5, variance 100/12 + 1.
  dist = distributions.Normal(loc=distributions.Uniform(0.0, 10.0), scale=1.0)
  samples = draw(dist)
  var_loc = 100 / 12
  # Fourth central moment of U + N (independent, zero-mean parts):
  # E[U^4] + 6 E[U^2] E[N^2] + E[N^4].
  fourth = 10**4 / 80 + 6 * var_loc * 1.0 + 3.0
  assert_moments(samples, 5.0, var_loc + 1.0, fourth)


def test_variation_parameters_get_their_own_subkey():
  # With a variation parameter the node splits its key: the parameter's draw
  # and the node's own draw are independent.
  dist = distributions.Uniform(low=distributions.Uniform(0.0, 1.0), high=2.0)
  key = jax.random.key(5)
  own_key, param_key = jax.random.split(key)
  low = distributions.Uniform(0.0, 1.0)(key=jax.random.fold_in(param_key, 0))
  expected = low + (2.0 - low) * jax.random.uniform(own_key)
  np.testing.assert_allclose(dist(key=key), expected, rtol=1e-6)


def test_constant_parameters_use_the_key_directly():
  key = jax.random.key(9)
  np.testing.assert_array_equal(
      distributions.Uniform()(key=key), jax.random.uniform(key)
  )
  np.testing.assert_array_equal(
      distributions.Normal()(key=key), jax.random.normal(key)
  )


def test_dtypes():
  key = jax.random.key(0)
  assert distributions.Uniform(0, 3)(key=key).dtype == jnp.float32
  assert distributions.Normal()(key=key).dtype == jnp.float32
  assert distributions.UniformInteger(0, 3)(key=key).dtype == jnp.int32
  assert distributions.Poisson()(key=key).dtype == jnp.int32
  assert distributions.Bernoulli()(key=key).dtype == jnp.int32


# ------------------------------------------------------ points on spheres.


def test_uniform_point_on_sphere():
  points = np.asarray(
      distributions.UniformPointOnSphere()(
          jnp.zeros((N, 3)), None, jax.random.key(0)
      )
  )
  assert points.shape == (N, 3)
  np.testing.assert_allclose(np.linalg.norm(points, axis=-1), 1.0, rtol=1e-5)
  assert len(np.unique(points[:100].reshape(-1))) == 300  # All distinct.
  # Uniform on the sphere: each coordinate has mean 0 and E[x^2] = 1/3
  # (Var[x^2] = E[x^4] - 1/9 = 1/5 - 1/9).
  for axis in range(3):
    x = points[:, axis]
    assert abs(x.mean()) < Z * np.sqrt(1 / 3 / N)
    assert abs((x**2).mean() - 1 / 3) < Z * np.sqrt((1 / 5 - 1 / 9) / N)


def test_uniform_point_on_sphere_shapes():
  dist = distributions.UniformPointOnSphere()
  key = jax.random.key(0)
  assert dist(key=key).shape == (3,)
  assert dist(0.0, key=key).shape == (3,)
  assert dist(jnp.zeros(3), key=key).shape == (3,)  # Fills an axis attribute.
  assert dist(jnp.zeros(5), key=key).shape == (
      5,
      3,
  )  # composer's appended axis.
  single = distributions.UniformPointOnSphere(single_sample=True)(
      jnp.zeros((4, 3)), key=key
  )
  np.testing.assert_array_equal(single, np.broadcast_to(single[0], (4, 3)))


# -------------------------------------------------------- biased random walk.


def _walk(stdev, timescale, worlds=20_000, steps=60, seed=0):
  """(worlds, steps) values of independent walks, sampled with lax.scan."""
  walk = distributions.BiasedRandomWalk(stdev=stdev, timescale=timescale)

  def one_world(key):
    def step(state, key):
      value, state = walk.sample(state, key)
      return state, value

    _, values = jax.lax.scan(
        step, walk.initial_state(), jax.random.split(key, steps)
    )
    return values

  keys = jax.random.split(jax.random.key(seed), worlds)
  return np.asarray(jax.jit(jax.vmap(one_world))(keys), np.float64)


@pytest.mark.parametrize("timescale", [0.0, 10.0])
def test_biased_random_walk_stationary_statistics(timescale):
  stdev, worlds = 0.1, 20_000
  values = _walk(stdev, timescale, worlds=worlds)
  retain = 0.0 if timescale == 0 else np.exp(-1 / timescale)
  # Starts at 0: the first value is N(0, scale^2), scale = stdev sqrt(1 - retain^2).
  scale = stdev * np.sqrt(1 - retain**2)
  assert_moments(values[:, 0], 0.0, scale**2, 3 * scale**4)
  # After 6 timescales the variance is stdev^2 (1 - retain^120) ~= stdev^2.
  assert_moments(values[:, -1], 0.0, stdev**2, 3 * stdev**4)
  # Lag-k correlation retain^k (lag 10 = one timescale: exp(-1)).
  a, b = values[:, -11], values[:, -1]
  corr = np.corrcoef(a, b)[0, 1]
  expected = retain**10
  assert abs(corr - expected) < Z * (1 - expected**2) / np.sqrt(worlds)


def test_biased_random_walk_array_parameters_walk_independently():
  walk = distributions.BiasedRandomWalk(stdev=[0.1, 1.0], timescale=5.0)
  state = walk.initial_state()
  assert state.shape == (2,)
  value, state = walk.sample(state, jax.random.key(0))
  assert value.shape == (2,) and value[0] != value[1]


def test_biased_random_walk_call_is_first_step_and_ignores_initial_shape():
  walk = distributions.BiasedRandomWalk(stdev=0.5, timescale=0.0)
  key = jax.random.key(2)
  value = walk(jnp.zeros(7), None, key)
  assert value.shape == ()  # Like composer: the walk's own shape.
  np.testing.assert_allclose(value, 0.5 * jax.random.normal(key), rtol=1e-6)


def test_biased_random_walk_errors():
  with pytest.raises(ValueError, match=r"^`stdev` must be >= 0, got -1.$"):
    distributions.BiasedRandomWalk(stdev=-1)
  with pytest.raises(ValueError, match=r"^`timescale` must be >= 0, got -1.$"):
    distributions.BiasedRandomWalk(timescale=-1)
  walk = distributions.BiasedRandomWalk()
  with pytest.raises(ValueError, match=r"BiasedRandomWalk.*is stateful"):
    walk.sample(None, jax.random.key(0))


# ------------------------------------------------------------ API details.


def test_repr_eq_and_parameter_attributes():
  normal = distributions.Normal(loc=1, scale=2)
  assert repr(normal) == "Normal(loc=1, scale=2)"
  assert str(distributions.Uniform()) == "Uniform(low=0.0, high=1.0)"
  assert repr(distributions.Uniform(single_sample=True)) == (
      "Uniform(low=0.0, high=1.0, single_sample=True)"
  )
  assert normal == distributions.Normal(loc=1, scale=2)
  assert normal != distributions.Normal(loc=1, scale=3)
  assert normal != distributions.Normal(loc=1, scale=2, single_sample=True)
  assert normal != distributions.LogNormal(1, 2)
  assert distributions.Uniform([0, 1], 2) == distributions.Uniform(
      np.array([0, 1]), 2
  )
  assert normal.loc == 1 and normal.scale == 2
  assert distributions.Uniform(0, 3).high == 3
  assert hash(normal) == hash(distributions.Normal(loc=1, scale=2))


def test_uniform_choice_errors():
  with pytest.raises(TypeError, match="numeric choices"):
    distributions.UniformChoice(["apple", "banana"])
  with pytest.raises(ValueError, match="at least one choice"):
    distributions.UniformChoice([])


def test_missing_key_names_the_distribution():
  message = r"^Poisson\(lam=2.0\) draws random numbers and needs a PRNG key"
  with pytest.raises(ValueError, match=message):
    distributions.Poisson(2.0)()


def test_static_bounds():
  def bounds(v):
    b = v.static_bounds()
    return (
        None
        if b is None
        else (np.asarray(b[0]).tolist(), np.asarray(b[1]).tolist())
    )

  assert bounds(distributions.Uniform(1, 3)) == (1, 3)
  assert bounds(distributions.Uniform([0, 1], [2, 0])) == ([0, 0], [2, 1])
  assert bounds(distributions.UniformInteger(1, 4)) == (1, 3)
  assert bounds(distributions.UniformInteger(4)) == (0, 3)
  assert bounds(
      distributions.UniformInteger(distributions.UniformInteger(1, 3), 10)
  ) == (1, 9)
  assert bounds(distributions.UniformChoice([3, 1, 2])) == (1, 3)
  assert bounds(distributions.UniformChoice([[0, 5], [2, 1]])) == (
      [0, 1],
      [2, 5],
  )
  assert bounds(distributions.Bernoulli(0.2)) == (0, 1)
  assert bounds(distributions.Uniform(deterministic.Constant(2), 4)) == (2, 4)
  for unbounded in [
      distributions.Normal(),
      distributions.LogNormal(),
      distributions.Exponential(),
      distributions.Poisson(),
      distributions.BiasedRandomWalk(),
      distributions.Uniform(distributions.Normal(), 1.0),
  ]:
    assert unbounded.static_bounds() is None, unbounded


def test_static_bounds_contain_samples():
  dist = distributions.UniformInteger(2, 6) * 3 - distributions.Uniform(0, 1)
  low, high = dist.static_bounds()
  samples = draw(dist)
  assert low == 2 * 3 - 1 and high == 5 * 3 - 0
  assert samples.min() >= low and samples.max() <= high
  assert variation.static_bounds(5) == (5, 5)
