"""Observables: descriptions of what to observe, and how often.

An `Observable` is a host-side configuration object. It says how to read one
quantity from a `Physics` (a pure function traced into the environment's
step), and how the observation updater should sample it: every
`update_interval` sub-steps, into a buffer of `buffer_size` samples that
arrive `delay` sub-steps after they are taken, reduced by an optional
`aggregator` over the buffer axis, each sample passed through an optional
`corruptor` before it is buffered.

Differences from dm_control's composer:

* A corruptor is a pure function `corruptor(value, key) -> value` of a JAX
  PRNG key, not of a numpy `RandomState`; a `Variation` (composer's
  `noises.Additive(distributions.Normal(scale=0.01))`) works as one too,
  evaluated as `variation(value, value, key=key)`.
* Reading an observable happens while tracing, so everything that selects
  *what* is read (element handles, names, indices) must be static.
* The built-in aggregators are `jax.numpy` reductions over axis 0, and the
  bounds-preserving ones (min, max, mean, median) really keep the bounds of a
  `BoundedArray` spec (composer's `bounds_reserving` typo drops them).
"""

import abc
from typing import Any, Callable

import jax.numpy as jnp

from mjx_composer.variation import base as variation_base


class Aggregator:
  """A named reduction over the buffer axis (axis 0) of an observation.

  Attributes:
    name: the name under which it is registered in `AGGREGATORS`.
    preserves_bounds: whether the output of a bounded input stays within the
      input's bounds, so that the observation spec may keep them.
  """

  def __init__(self, name: str, fn: Callable[..., Any], preserves_bounds: bool):
    self.name = name
    self._fn = fn
    self.preserves_bounds = preserves_bounds

  def __call__(self, buffered):
    return self._fn(buffered, axis=0)

  def __repr__(self):
    return f'Aggregator({self.name!r})'


AGGREGATORS = {
    'min': Aggregator('min', jnp.min, preserves_bounds=True),
    'max': Aggregator('max', jnp.max, preserves_bounds=True),
    'mean': Aggregator('mean', jnp.mean, preserves_bounds=True),
    'median': Aggregator('median', jnp.median, preserves_bounds=True),
    'sum': Aggregator('sum', jnp.sum, preserves_bounds=False),
}

# The options that `Observable.configure` and `Observables.set_options`
# accept when applied to every observable at once.
OPTION_NAMES = frozenset(
    [
        'update_interval',
        'buffer_size',
        'delay',
        'aggregator',
        'corruptor',
        'enabled',
    ]
)


def _get_aggregator(name_or_callable):
  """Resolves an aggregator name; callables and None pass through."""
  if name_or_callable is None or callable(name_or_callable):
    return name_or_callable
  try:
    return AGGREGATORS[name_or_callable]
  except (KeyError, TypeError):
    raise KeyError(
        f'Unrecognized aggregator name: {name_or_callable!r}. Valid names: '
        f'{sorted(AGGREGATORS)}.'
    ) from None


class Observable(abc.ABC):
  """Abstract base class of an observable quantity.

  Options (all settable through `configure` or as properties):
    update_interval: sample every this many physics sub-steps (an int, or a
      `Variation` re-sampled for every sample). `None`/0 means 1.
    buffer_size: how many samples an observation holds (an int). `None`/0
      means 1.
    delay: how many sub-steps after it is taken a sample becomes visible (an
      int, or a `Variation` re-sampled for every sample). `None` means 0.
    aggregator: `None`, one of `AGGREGATORS` by name, or a callable reducing
      axis 0 (the buffer axis) of a `(buffer_size, *shape)` array.
    corruptor: `None`, a pure `corruptor(value, key) -> value`, or a
      `Variation` (a composer noise: `variation(value, value, key=key)`),
      applied to every sample before it is buffered (so aggregators see
      noisy values).
    enabled: whether the environment observes it. False on a new observable.
  """

  def __init__(
      self, update_interval, buffer_size, delay, aggregator, corruptor
  ):
    self._update_interval = update_interval
    self._buffer_size = buffer_size
    self._delay = delay
    self._aggregator = _get_aggregator(aggregator)
    self._corruptor = corruptor
    self._enabled = False

  @property
  def update_interval(self):
    return self._update_interval

  @update_interval.setter
  def update_interval(self, value):
    self._update_interval = value

  @property
  def buffer_size(self):
    return self._buffer_size

  @buffer_size.setter
  def buffer_size(self, value):
    self._buffer_size = value

  @property
  def delay(self):
    return self._delay

  @delay.setter
  def delay(self, value):
    self._delay = value

  @property
  def aggregator(self):
    return self._aggregator

  @aggregator.setter
  def aggregator(self, value):
    self._aggregator = _get_aggregator(value)

  @property
  def corruptor(self):
    return self._corruptor

  @corruptor.setter
  def corruptor(self, value):
    self._corruptor = value

  @property
  def enabled(self):
    return self._enabled

  @enabled.setter
  def enabled(self, value):
    self._enabled = value

  @property
  def array_spec(self):
    """A `dm_env.specs.Array` for one sample, or None to infer it by tracing."""
    return None

  @abc.abstractmethod
  def _callable(self, physics) -> Callable[[], Any]:
    """Returns a zero-argument callable reading the raw value from `physics`.

    It is called while tracing; name and element resolution happen here, so
    the returned callable only indexes arrays.
    """

  def raw_observation_callable(self, physics) -> Callable[[], Any]:
    """A zero-argument callable returning the uncorrupted value.

    Subclasses implement `_callable` (composer's protected hook); callers
    outside the class use this.
    """
    return self._callable(physics)

  def observation_callable(self, physics, key=None) -> Callable[[], Any]:
    """A zero-argument callable returning the (corrupted) observation.

    Args:
      physics: the `Physics` to read.
      key: the PRNG key handed to the corruptor. Required when there is one.
    """
    raw = self.raw_observation_callable(physics)
    corruptor = self._corruptor
    if corruptor is None:
      return raw
    if key is None:
      raise ValueError(
          'This observable has a corruptor, which needs a PRNG key: call it '
          'with `key=jax.random.key(...)`.'
      )
    return lambda: corrupt(corruptor, raw(), key)

  def __call__(self, physics, key=None):
    """Evaluates the (corrupted) observation once."""
    return self.observation_callable(physics, key)()

  def configure(self, **kwargs):
    """Sets options by name; unknown names raise composer's AttributeError."""
    for name, value in kwargs.items():
      prop = getattr(type(self), name, None)
      if not isinstance(prop, property) or prop.fset is None:
        raise AttributeError(f'Cannot add attribute {name} in configure.')
      setattr(self, name, value)


class Generic(Observable):
  """An observable computed by a function of the physics: `fn(physics)`.

  Besides composer's arguments it takes an optional `array_spec` (for
  example a `BoundedArray` whose bounds flow into the observation spec);
  without one the spec is inferred by tracing `fn`.
  """

  def __init__(
      self,
      raw_observation_callable,
      update_interval=1,
      buffer_size=None,
      delay=None,
      aggregator=None,
      corruptor=None,
      array_spec=None,
  ):
    self._raw = raw_observation_callable
    self._array_spec = array_spec
    super().__init__(update_interval, buffer_size, delay, aggregator, corruptor)

  @property
  def array_spec(self):
    return self._array_spec

  def _callable(self, physics):
    return lambda: self._raw(physics)


class MujocoFeature(Observable):
  """Reads `physics.named.data.<kind>[feature_name]`.

  `feature_name` is a name, a list of names, or a zero-argument callable
  returning either. Unlike composer, where a callable is re-evaluated at
  every sample, here it is evaluated while tracing (names must be static).
  """

  def __init__(
      self,
      kind,
      feature_name,
      update_interval=1,
      buffer_size=None,
      delay=None,
      aggregator=None,
      corruptor=None,
  ):
    self._kind = kind
    self._feature_name = feature_name
    super().__init__(update_interval, buffer_size, delay, aggregator, corruptor)

  def _callable(self, physics):
    names = (
        self._feature_name()
        if callable(self._feature_name)
        else self._feature_name
    )
    field = getattr(physics.named.data, self._kind)
    return lambda: field[names]


def corrupt(corruptor, value, key):
  """`value` through an observable's `corruptor`, with `key`.

  A plain corruptor is called `corruptor(value, key)`. A `Variation`
  (composer's idiom, `corruptor=noises.Additive(distributions.Normal(
  scale=0.01))`) takes its key as variations do, by keyword:
  `corruptor(value, value, key=key)`, the sample being both its initial and
  its current value (composer passes it as the initial value).
  """
  if isinstance(corruptor, variation_base.Variation):
    return corruptor(value, value, key=key)
  return corruptor(value, key)
