"""Standard statistical distributions as variations, sampled from JAX keys.

Mirrors `dm_control.composer.variation.distributions`; numpy's samplers become
`jax.random` ones, so values are not equal to composer's numpy streams but
follow the same distributions.

Sample shape (composer's rule, generalised to broadcasting):

* Parameters may be constants, arrays or variations. Variation parameters are
  evaluated first, with the same initial and current value as the
  distribution (so by default they are drawn in the shape of the initial
  value, as in composer), each with its own subkey.
* Without `single_sample`, the sample has the broadcast shape of the
  parameters and of `initial_value` (just the parameters' shape when
  `initial_value` is `None`): one independent draw per element of the value
  being varied.
* With `single_sample=True`, one draw of the parameters' broadcast shape is
  made and then broadcast to that same shape, so every element of the value
  shares it. (composer returns the unbroadcast draw and relies on the
  assignment to broadcast; returning the full shape keeps shapes static.)

Parameters are checked at construction as `numpy.random` checks them at
each draw (a negative `scale`, a probability outside [0, 1], `low >= high`
for integers, ...), and non-finite parameters are refused too (numpy would
return NaN or infinite samples): constants by value, variations by their
`static_bounds()` where known (e.g. `Exponential(scale=Uniform(-1, 1))` is
refused, since half its draws would be invalid). A distribution that could
draw from invalid parameters never reaches a jitted step, where JAX would
return wrong samples without an error.

Dtypes: continuous distributions return the floating type of their
parameters (the default float, float32 unless x64 is enabled, for integer or
Python parameters); `UniformInteger`, `Poisson` and `Bernoulli` return the
default integer type, like numpy's integer samplers.
"""

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer.variation import arrays as arrays_lib
from mjx_composer.variation import base
from mjx_composer.variation import bounds as bounds_lib
from mjx_composer.variation import composite
from mjx_composer.variation import parameter_checks
from mjx_composer.variation import printing


class Distribution(composite.CompositeVariation):
  """Base class of parametrised distributions.

  Subclasses pass their parameters by keyword to `__init__` (in the order of
  their signature: that order fixes which subkey each variation parameter
  gets) and implement `_draw(key, shape, **params)`, which receives the
  evaluated parameters as jnp arrays (or `None`) and returns a sample of
  `shape` (or one that broadcasts to it).

  Constructor parameters are readable as attributes (`Uniform(0, 2).high`),
  as in composer.
  """

  _DRAWS_RANDOMNESS = True
  # Parameter name -> `parameter_checks.Domain` its values must lie in
  # (checked at __init__).
  _DOMAINS = {}

  def __init__(self, single_sample=False, **params):
    owner = type(self).__name__
    for name, value in params.items():
      if name in self._DOMAINS and value is not None:
        self._DOMAINS[name].check(owner, name, value)
    parameter_checks.check_shapes(owner, params)
    self._single_sample = bool(single_sample)
    self._params = dict(params)
    self._operands = tuple(params.values())

  def __getattr__(self, name):
    params = self.__dict__.get("_params", {})
    if not name.startswith("_") and name in params:
      return params[name]
    raise AttributeError(
        f"{type(self).__name__!r} object has no attribute {name!r}"
    )

  @property
  def single_sample(self) -> bool:
    return self._single_sample

  def _draw(self, key, shape, **params):
    raise NotImplementedError

  def _shapes(self, params, initial_value):
    """(draw shape, output shape) for evaluated parameters (see module doc)."""
    shapes = {
        name: jnp.shape(p)
        for name, p in zip(self._params, params)
        if p is not None
    }
    try:
      param_shape = jnp.broadcast_shapes(*shapes.values())
    except ValueError:
      # Constants were checked at construction: a variation parameter drew
      # values of a shape that does not broadcast with the others.
      raise ValueError(
          f"{type(self).__name__}: its parameters' values have shapes "
          f"{parameter_checks.shape_list(shapes)}, which do not broadcast "
          "together. Pass parameters (or variations) whose values have one "
          "shape, or "
          "shapes that broadcast, e.g. a scalar and an array."
      ) from None
    if initial_value is None:
      full_shape = param_shape
    else:
      try:
        full_shape = jnp.broadcast_shapes(param_shape, np.shape(initial_value))
      except ValueError:
        raise ValueError(
            f"{type(self).__name__}: its parameters' shape {param_shape} "
            "does not broadcast with the value it varies, of shape "
            f"{np.shape(initial_value)}. Pass parameters of the value's "
            "shape, or scalars."
        ) from None
    return (param_shape if self._single_sample else full_shape), full_shape

  def _apply(self, values, key, initial_value, current_value):
    params = [arrays_lib.as_array(v) for v in values]
    draw_shape, full_shape = self._shapes(params, initial_value)
    sample = self._draw(key, draw_shape, **dict(zip(self._params, params)))
    return jnp.broadcast_to(sample, full_shape)

  def _eq_fields(self):
    return (tuple(self._params.items()), self._single_sample)

  def __repr__(self):
    extra = {"single_sample": True} if self._single_sample else {}
    return printing.format_call(type(self).__name__, **self._params, **extra)


class Uniform(Distribution):
  """Uniform on `[low, high)` (numpy's `uniform`; `low > high` is allowed).

  `low > high` samples `(high, low]`, as composer's `RandomState.uniform`
  does; non-finite bounds are refused.
  """

  _BATCHES = True

  _DOMAINS = {
      "low": parameter_checks.FINITE,
      "high": parameter_checks.FINITE,
  }

  def __init__(self, low=0.0, high=1.0, single_sample=False):
    """Initializes a `Uniform`.

    Args:
      low: lower bound (inclusive): scalar, array, or variation.
      high: upper bound (exclusive): scalar, array, or variation.
      single_sample: draw once (in the parameters' shape) and broadcast,
        instead of once per element of the initial value.
    """
    super().__init__(low=low, high=high, single_sample=single_sample)

  def _draw(self, key, shape, low, high):
    dtype = arrays_lib.float_dtype(low, high)
    # Not jax.random.uniform(minval=, maxval=): it clamps at minval, which
    # breaks numpy's `low > high` case.
    return low + (high - low) * jax.random.uniform(key, shape, dtype)

  def static_bounds(self):
    low = bounds_lib.static_bounds(self.low)
    high = bounds_lib.static_bounds(self.high)
    if low is None or high is None:
      return None
    return bounds_lib.as_bounds(
        np.minimum(low[0], high[0]), np.maximum(low[1], high[1])
    )


class UniformInteger(Distribution):
  """Uniform integers in `[low, high)`, or `[0, low)` if `high` is None.

  numpy's `randint` semantics; the upper bound is exclusive, so
  `static_bounds()` is `(low, high - 1)`. As numpy refuses them, `low >=
  high` (or `low <= 0` without `high`) and non-integer bounds are refused.
  """

  _BATCHES = True

  _DOMAINS = {
      "low": parameter_checks.INTEGER,
      "high": parameter_checks.INTEGER,
  }

  def __init__(self, low, high=None, single_sample=False):
    """Initializes a `UniformInteger`.

    Args:
      low: smallest value (or the exclusive upper bound if `high` is None):
        integer scalar, array, or variation.
      high: exclusive upper bound, or `None`.
      single_sample: draw once and broadcast (see module docstring).

    Raises:
      TypeError: for a bound that is not a number, array or variation.
      ValueError: for non-integer bounds, or an empty range (`low >= high`,
        or `low <= 0` when `high` is None) for any element or any value the
        bounds' variations may draw.
    """
    super().__init__(low=low, high=high, single_sample=single_sample)
    if high is None:
      if not parameter_checks.below(0, low):
        raise ValueError(
            "UniformInteger: `low` (the exclusive upper bound when `high` is "
            f"None) must be >= 1, got {low!r}: the range [0, low) is empty "
            "(or may be, for a variation), which numpy.random refuses. Pass "
            "UniformInteger(n) with n >= 1 for [0, n)."
        )
    elif not parameter_checks.below(low, high):
      raise ValueError(
          f"UniformInteger: `high` must be greater than `low`, got "
          f"low={low!r}, high={high!r}: the range [low, high) is empty (or "
          "may be, for variation bounds), which numpy.random refuses. Pass "
          "low < high, e.g. UniformInteger(2, 5)."
      )

  def _draw(self, key, shape, low, high):
    if high is None:
      low, high = 0, low
    return jax.random.randint(
        key, shape, low, high, dtype=parameter_checks.int_dtype()
    )

  def static_bounds(self):
    low = bounds_lib.static_bounds(self.low)
    if self.high is None:
      return (
          None
          if low is None
          else bounds_lib.as_bounds(np.zeros_like(low[0]), low[1] - 1)
      )
    high = bounds_lib.static_bounds(self.high)
    if low is None or high is None:
      return None
    return bounds_lib.as_bounds(low[0], high[1] - 1)


class UniformChoice(Distribution):
  """Uniform choice among numeric `choices` (rows of an array).

  `choices` is a sequence of numbers, an array whose first axis enumerates
  the choices (each choice is then a row of shape `choices.shape[1:]`), an
  integer `n` (numpy's shorthand for `range(n)`), or a list containing
  variations (evaluated, then stacked). String or object choices, which
  composer allows, cannot live in a JAX array: choose an index with
  `UniformInteger(len(choices))` and map it on the host.

  Shape: choices fill the trailing axes; without `single_sample`, the
  leading axes of the (broadcast) initial value get independent picks.
  E.g. scalar choices and an initial value of shape (3,) give 3 picks; rows
  of shape (4,) and an initial value of shape (4,) give one row.
  """

  def __init__(self, choices, single_sample=False):
    """Initializes a `UniformChoice`.

    Args:
      choices: see the class docstring.
      single_sample: draw one choice and broadcast it.

    Raises:
      TypeError: for non-numeric choices.
      ValueError: for an empty set of choices.
    """
    if not base.contains_variation(choices):
      array = np.asarray(choices)
      if array.dtype.kind not in "biuf":
        raise TypeError(
            "UniformChoice needs numeric choices (they become a JAX "
            f"array); got {choices!r}. Choose an index with "
            "UniformInteger(len(choices)) and map it on the host."
        )
      if array.ndim == 0:
        if array.dtype.kind not in "iu":
          raise ValueError(
              f"UniformChoice choices must be a sequence, got {choices!r}."
          )
        choices = np.arange(int(array))
        array = choices
      if array.shape[0] == 0:
        raise ValueError("UniformChoice needs at least one choice.")
    super().__init__(choices=choices, single_sample=single_sample)

  def _apply(self, values, key, initial_value, current_value):
    choices = arrays_lib.as_array(values[0])
    row_shape = choices.shape[1:]
    if initial_value is None:
      full_shape = row_shape
    else:
      full_shape = jnp.broadcast_shapes(np.shape(initial_value), row_shape)
    batch_shape = (
        ()
        if self._single_sample
        else full_shape[: len(full_shape) - len(row_shape)]
    )
    index = jax.random.randint(key, batch_shape, 0, choices.shape[0])
    return jnp.broadcast_to(choices[index], full_shape)

  def static_bounds(self):
    bounds = bounds_lib.static_bounds(self.choices)
    if bounds is None or np.ndim(bounds[0]) == 0:
      return None
    return bounds_lib.as_bounds(
        np.min(bounds[0], axis=0), np.max(bounds[1], axis=0)
    )


class UniformPointOnSphere(base.Variation):
  """Unit 3-vectors, uniform on the sphere (normalised standard normals).

  Shape: without `single_sample`, one point per row of the initial value
  when its last axis has size 3 (e.g. varying an axis attribute), otherwise
  `shape(initial_value) + (3,)` as in composer; `(3,)` without an initial
  value. With `single_sample`, one point broadcast to that shape.
  (composer always appends an axis, which turns a (3,) initial value into
  (3, 3); we fill it instead.)
  """

  def __init__(self, single_sample=False):
    self._single_sample = bool(single_sample)

  def _sample(self, state, key, initial_value, current_value):
    self._require_key(key)
    if initial_value is None:
      full_shape = (3,)
    else:
      shape = tuple(np.shape(initial_value))
      full_shape = shape if shape[-1:] == (3,) else shape + (3,)
    draw_shape = (3,) if self._single_sample else full_shape
    point = jax.random.normal(key, draw_shape, arrays_lib.float_dtype())
    point = point / jnp.linalg.norm(point, axis=-1, keepdims=True)
    return jnp.broadcast_to(point, full_shape), state

  def static_bounds(self):
    return np.asarray(-1.0), np.asarray(1.0)

  def _eq_fields(self):
    return (self._single_sample,)

  def __repr__(self):
    extra = {"single_sample": True} if self._single_sample else {}
    return printing.format_call(type(self).__name__, **extra)


class Normal(Distribution):
  """Gaussian with mean `loc` and standard deviation `scale` (finite, >= 0)."""

  _BATCHES = True

  _DOMAINS = {
      "loc": parameter_checks.FINITE,
      "scale": parameter_checks.NONNEGATIVE,
  }

  def __init__(self, loc=0.0, scale=1.0, single_sample=False):
    super().__init__(loc=loc, scale=scale, single_sample=single_sample)

  def _draw(self, key, shape, loc, scale):
    dtype = arrays_lib.float_dtype(loc, scale)
    return loc + scale * jax.random.normal(key, shape, dtype)


class LogNormal(Distribution):
  """`exp(N(mean, sigma))` (numpy's `lognormal` parametrisation; `sigma >= 0`)."""

  _BATCHES = True

  _DOMAINS = {
      "mean": parameter_checks.FINITE,
      "sigma": parameter_checks.NONNEGATIVE,
  }

  def __init__(self, mean=0.0, sigma=1.0, single_sample=False):
    super().__init__(mean=mean, sigma=sigma, single_sample=single_sample)

  def _draw(self, key, shape, mean, sigma):
    dtype = arrays_lib.float_dtype(mean, sigma)
    return jnp.exp(mean + sigma * jax.random.normal(key, shape, dtype))


class Exponential(Distribution):
  """Exponential with mean `scale` (numpy's parametrisation; `scale >= 0`)."""

  _BATCHES = True

  _DOMAINS = {"scale": parameter_checks.NONNEGATIVE}

  def __init__(self, scale=1.0, single_sample=False):
    super().__init__(scale=scale, single_sample=single_sample)

  def _draw(self, key, shape, scale):
    return scale * jax.random.exponential(
        key, shape, arrays_lib.float_dtype(scale)
    )


class Poisson(Distribution):
  """Poisson with rate `lam` (finite, >= 0); integer samples."""

  _DOMAINS = {"lam": parameter_checks.RATE}

  def __init__(self, lam=1.0, single_sample=False):
    super().__init__(lam=lam, single_sample=single_sample)

  def _draw(self, key, shape, lam):
    return jax.random.poisson(
        key, lam, shape, dtype=parameter_checks.int_dtype()
    )


class Bernoulli(Distribution):
  """1 with probability `prob`, else 0 (integers, like `binomial(1, prob)`).

  `prob` must lie in [0, 1], as numpy's `binomial` requires.
  """

  _BATCHES = True

  _DOMAINS = {"prob": parameter_checks.PROBABILITY}

  def __init__(self, prob=0.5, single_sample=False):
    super().__init__(prob=prob, single_sample=single_sample)

  def _draw(self, key, shape, prob):
    # jax.random.bernoulli refuses integer (or bool) probabilities: cast.
    prob = prob.astype(arrays_lib.float_dtype(prob))
    return jax.random.bernoulli(key, prob, shape).astype(
        parameter_checks.int_dtype()
    )

  def static_bounds(self):
    return np.asarray(0), np.asarray(1)


_NEGATIVE_STDEV = "`stdev` must be >= 0, got {}."
_NEGATIVE_TIMESCALE = "`timescale` must be >= 0, got {}."


class BiasedRandomWalk(base.Variation):
  """Zero-mean Ornstein-Uhlenbeck noise: a stateful, correlated walk.

  With `retain = exp(-1 / timescale)` (0 when `timescale == 0`) and
  `scale = stdev * sqrt(1 - retain**2)`, each draw does

      x <- retain * x + N(0, scale)

  starting from `x = 0`, so the stationary standard deviation is `stdev`
  and the correlation decays by `exp(-1)` every `timescale` draws.

  composer keeps `x` on the object; here it is the state:
  `initial_state()` is `x = 0` and `sample(state, key)` returns the new `x`
  both as the value and as the new state. Like composer, the walk ignores the
  shape of the initial value; it has the broadcast shape of `stdev` and
  `timescale`, so array parameters give independent walks per element.
  """

  def __init__(self, stdev=0.1, timescale=10.0):
    """Initializes a `BiasedRandomWalk`.

    Args:
      stdev: stationary standard deviation (>= 0), scalar or array.
      timescale: number of draws over which the correlation drops by
        `exp(-1)` (>= 0); 0 gives independent normal draws.

    Raises:
      ValueError: if `stdev` or `timescale` is negative.
    """
    stdev_array = np.asarray(stdev, dtype=float)
    timescale_array = np.asarray(timescale, dtype=float)
    if np.any(stdev_array < 0):
      raise ValueError(_NEGATIVE_STDEV.format(stdev))
    if np.any(timescale_array < 0):
      raise ValueError(_NEGATIVE_TIMESCALE.format(timescale))
    self._stdev, self._timescale = stdev, timescale
    with np.errstate(divide="ignore"):
      retain = np.where(
          timescale_array == 0, 0.0, np.exp(-1.0 / timescale_array)
      )
    self._retain = retain
    self._scale = stdev_array * np.sqrt(1.0 - retain * retain)
    self._shape = np.broadcast_shapes(stdev_array.shape, timescale_array.shape)

  def initial_state(self, initial_value=None):
    del initial_value  # The walk's shape is that of its parameters.
    return jnp.zeros(self._shape, arrays_lib.float_dtype())

  def _sample(self, state, key, initial_value, current_value):
    self._require_key(key)
    self._require_state(state)
    noise = jax.random.normal(key, self._shape, state.dtype)
    value = (self._retain * state + self._scale * noise).astype(state.dtype)
    return value, value

  def __repr__(self):
    return printing.format_call(
        type(self).__name__, stdev=self._stdev, timescale=self._timescale
    )
