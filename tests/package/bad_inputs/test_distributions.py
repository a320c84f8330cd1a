"""Distributions refuse at construction what NumPy's sampling refuses."""

import jax
import numpy as np
import pytest

# -- distributions: numpy's parameter checks, at construction ----------------

_NAN, _INF = float('nan'), float('inf')
_GEN = np.random.default_rng(0)

# (distribution, the argument named, the numpy call that refuses the same
# parameters, or None where numpy returns NaN/inf samples instead).
_BAD_DISTRIBUTIONS = [
    (lambda d: d.Exponential(scale=-1), 'scale', lambda: _GEN.exponential(-1)),
    (lambda d: d.Poisson(lam=-1), 'lam', lambda: _GEN.poisson(-1)),
    (lambda d: d.Poisson(lam=_NAN), 'lam', lambda: _GEN.poisson(_NAN)),
    (lambda d: d.Poisson(lam=1e20), 'lam', lambda: _GEN.poisson(1e20)),
    (lambda d: d.Bernoulli(prob=1.5), 'prob', lambda: _GEN.binomial(1, 1.5)),
    (lambda d: d.Bernoulli(prob=-0.1), 'prob', lambda: _GEN.binomial(1, -0.1)),
    (lambda d: d.Bernoulli(prob=_NAN), 'prob', lambda: _GEN.binomial(1, _NAN)),
    (lambda d: d.UniformInteger(5, 2), 'high', lambda: _GEN.integers(5, 2)),
    (lambda d: d.UniformInteger(2, 2), 'high', lambda: _GEN.integers(2, 2)),
    (lambda d: d.UniformInteger(0), 'low', lambda: _GEN.integers(0)),
    (lambda d: d.UniformInteger([0, 5], [3, 4]), 'high', None),
    (lambda d: d.UniformInteger(_NAN), 'low', lambda: _GEN.integers(_NAN)),
    (lambda d: d.UniformInteger(2.5), 'low', None),
    (lambda d: d.Normal(0, scale=-1), 'scale', lambda: _GEN.normal(0, -1)),
    (lambda d: d.Normal(0, scale=_NAN), 'scale', None),
    (lambda d: d.Normal(loc=_INF), 'loc', None),
    (
        lambda d: d.LogNormal(0, sigma=-1),
        'sigma',
        lambda: _GEN.lognormal(0, -1),
    ),
    (lambda d: d.LogNormal(mean=_NAN), 'mean', None),
    (lambda d: d.Uniform(0, _INF), 'high', lambda: _GEN.uniform(0, _INF)),
    (lambda d: d.Uniform(_NAN, 1), 'low', lambda: _GEN.uniform(_NAN, 1)),
    # Parameters whose shapes do not broadcast together.
    (
        lambda d: d.Uniform([0, 1], [1, 2, 3]),
        'high',
        lambda: _GEN.uniform([0, 1], [1, 2, 3]),
    ),
    (
        lambda d: d.Normal([0, 1, 2], [[1, 2]]),
        'scale',
        lambda: _GEN.normal([0, 1, 2], [[1, 2]]),
    ),
    # Variation parameters whose static bounds leave the domain.
    (lambda d: d.Exponential(scale=d.Uniform(-1, 1)), 'scale', None),
    (lambda d: d.Bernoulli(prob=d.Uniform(0.5, 2)), 'prob', None),
    (lambda d: d.UniformInteger(d.UniformInteger(0, 5), 3), 'high', None),
]


@pytest.mark.parametrize(
    'make, name, numpy_call',
    _BAD_DISTRIBUTIONS,
    ids=[str(i) for i in range(len(_BAD_DISTRIBUTIONS))],
)
def test_distribution_refuses_parameters_numpy_refuses(make, name, numpy_call):
  from mjx_composer.variation import distributions  # pylint: disable=g-import-not-at-top

  if numpy_call is not None:  # The reference: numpy refuses them too.
    with pytest.raises((ValueError, OverflowError)):
      numpy_call()
  with pytest.raises(ValueError, match=rf'`{name}`.*Pass'):
    make(distributions)


def test_distribution_refuses_non_numeric_parameters():
  from mjx_composer.variation import distributions  # pylint: disable=g-import-not-at-top

  with pytest.raises(TypeError, match=r"Normal: `loc` must be a number.*'a'"):
    distributions.Normal('a')


def test_distribution_boundary_parameters_numpy_accepts_are_kept():
  from mjx_composer.variation import distributions  # pylint: disable=g-import-not-at-top

  key = jax.random.key(0)
  assert float(distributions.Exponential(0.0)(key=key)) == _GEN.exponential(0)
  assert int(distributions.Bernoulli(1.0)(key=key)) == 1
  assert int(distributions.Bernoulli(0)(key=key)) == 0
  assert int(distributions.UniformInteger(1)(key=key)) == 0
  assert int(distributions.Poisson(0.0)(key=key)) == 0
  assert float(distributions.Normal(2.0, 0.0)(key=key)) == 2.0
  # composer's RandomState.uniform allows low > high: so do we.
  assert 1.0 < float(distributions.Uniform(2.0, 1.0)(key=key)) <= 2.0
  # Unbounded variation parameters cannot be checked at construction.
  distributions.Normal(0.0, distributions.Normal())


def test_distribution_parameters_that_broadcast_are_kept():
  from mjx_composer.variation import distributions  # pylint: disable=g-import-not-at-top

  key = jax.random.key(0)
  sample = distributions.Uniform([0.0, 1.0], [[1.0], [2.0]])(key=key)
  assert sample.shape == np.broadcast_shapes((2,), (2, 1)) == (2, 2)
  assert distributions.Normal([0.0, 1.0, 2.0], 0.5)(key=key).shape == (3,)


def test_distribution_shapes_known_only_when_drawn_are_named():
  """A varied parameter, or the value varied, of another shape."""
  from mjx_composer.variation import distributions  # pylint: disable=g-import-not-at-top

  key = jax.random.key(0)
  varied_low = distributions.Uniform(
      distributions.Uniform([0, 0], [1, 1]), [2, 3, 4]
  )
  with pytest.raises(
      ValueError, match=r'Uniform: .*`low` \(2,\), `high` \(3,\).*Pass'
  ):
    varied_low(key=key)
  with pytest.raises(ValueError):  # numpy refuses it too.
    _GEN.uniform([0, 1], [1, 2], size=(3,))
  with pytest.raises(
      ValueError,
      match=r'shape \(2,\) does not broadcast with the value it varies, of '
      r'shape \(3,\)\. Pass',
  ):
    distributions.Uniform([0, 1], [1, 2])(initial_value=np.zeros(3), key=key)
