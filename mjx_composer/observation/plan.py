"""What the observation updater plans, on the host, for each observable.

`updater.Updater` reads every enabled observable's options once, at build
time, into an `Entry`: its buffer size, its `update_interval` and `delay` as
`Rate`s (a constant, or a bounded `Variation` drawn per sample), the static
`obs_buffer.ConstantSchedule` or the capacity of its arrival buffer, the
buffer streams it needs (corrupted and/or clean values), and the `uids` that
make its random draws independent of every other observable's (see
`updater`'s module docstring, "Randomness"). This module holds that static
per-observable plan and the key derivation built on it; it is separate from
`updater` because none of it is traced: `updater` holds the pure functions
(`reset`, `update`, `get_observation`) that run on these plans.
"""

import dataclasses
import numbers
from typing import Any, Optional

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer.observation import obs_buffer
from mjx_composer.utils import stable_id as stable_id_lib

DEFAULT_BUFFER_SIZE = 1
DEFAULT_UPDATE_INTERVAL = 1
DEFAULT_DELAY = 0

# Buffer streams: the observable's output after its corruptor, and the raw
# value (kept only when a group asks for clean values of a corrupted one).
VALUE = 'value'
CLEAN = 'clean'

# `purpose` values folded into per-sample keys.
CORRUPTOR, DELAY, INTERVAL = 0, 1, 2


def is_number(value) -> bool:
  return isinstance(value, numbers.Number) and not isinstance(value, bool)


class Rate:
  """A static description of an `update_interval` or a `delay`."""

  def __init__(self, owner: str, name: str, value, default: int, minimum: int):
    self.name = name
    self.variation = None
    if value is None or (is_number(value) and value == 0):
      value = default  # composer reads these options by truthiness.
    if is_number(value):
      if value != int(value) or value < minimum:
        raise ValueError(
            f'Observable {owner!r}: {name} must be an integer >= {minimum}, '
            f'got {value!r}.'
        )
      self.low = self.high = int(value)
      return
    if not callable(value):
      raise ValueError(
          f'Observable {owner!r}: {name} must be an int or a '
          f'Variation, got {value!r}.'
      )
    bounds_fn = getattr(value, 'static_bounds', None)
    bounds = bounds_fn() if bounds_fn is not None else None
    if bounds is None:
      raise ValueError(
          f'Observable {owner!r}: its {name} is {value!r}, whose values have '
          'no static bounds. A varying update_interval or delay needs bounds '
          'known at build time to size the observation buffer (buffer_size '
          '+ ceil(max_delay / min_interval) slots): use a bounded variation '
          '(e.g. UniformInteger or Sequence) or a constant.'
      )
    self.variation = value
    self.low = max(minimum, int(np.round(np.min(bounds[0]))))
    self.high = max(self.low, int(np.round(np.max(bounds[1]))))

  @property
  def constant(self) -> bool:
    return self.variation is None

  @property
  def _stateful(self) -> bool:
    return hasattr(self.variation, 'sample') and hasattr(
        self.variation, 'initial_state'
    )

  def initial_state(self):
    if self.constant or not self._stateful:
      return None
    return self.variation.initial_state(None)

  def draw(self, state, make_key):
    """Returns `(value as () int32 within the static bounds, new state)`.

    Args:
      state: the variation's state (None for constants and stateless ones).
      make_key: a zero-argument function returning the key for this draw;
        called only for a variation, so constants cost no key derivation.
    """
    if self.constant:
      return jnp.asarray(self.low, jnp.int32), state
    key = make_key()
    if self._stateful:
      value, state = self.variation.sample(state, key)
    else:
      value = self.variation(key=key)
    value = jnp.round(jnp.asarray(value, jnp.float32)).reshape(())
    # Clipping keeps the buffer's capacity bound even for a variation whose
    # draws stray outside its declared bounds.
    return jnp.clip(value.astype(jnp.int32), self.low, self.high), state


@dataclasses.dataclass
class Entry:
  """Static configuration of one enabled observable."""

  index: int
  key: str
  observable: Any
  uids: tuple  # fold_in data per purpose (CORRUPTOR, DELAY, INTERVAL)
  buffer_size: int
  interval: Rate
  delay: Rate
  schedule: Optional[obs_buffer.ConstantSchedule]
  capacity: int
  streams: tuple
  # Snapshots of the observable's options, taken at construction.
  aggregator: Any
  corruptor: Any
  array_spec: Any
  shapes: dict = dataclasses.field(default_factory=dict)

  @property
  def needs_key(self) -> bool:
    """Whether sampling draws random numbers (corruptor, varying rates)."""
    return self.corruptor is not None or self.schedule is None

  def stream(self, corrupted: bool) -> str:
    """The buffer stream holding this view of the observable."""
    if corrupted or self.corruptor is None:
      return VALUE
    return CLEAN


def fold(step_key, entry: Entry, purpose: int):
  """The key of one observable's sample for one purpose."""
  if step_key is None:
    raise ValueError(
        f'Observable {entry.key!r} has a corruptor or a varying rate and '
        'needs a PRNG key: pass one to reset/update.'
    )
  return jax.random.fold_in(step_key, entry.uids[purpose])


def fold_each(step_key, entries, purpose: int) -> dict:
  """`{entry.index: fold(step_key, entry, purpose)}`, from one hash.

  The same keys, bit for bit, as `fold` of each entry
  (`stable_id.fold_in_each`): an update of many noisy observables derives
  their keys in one PRNG call, not one each.
  """
  entries = list(entries)
  if step_key is None and entries:
    fold(step_key, entries[0], purpose)  # says what is missing
  keys = stable_id_lib.fold_in_each(
      step_key, [entry.uids[purpose] for entry in entries]
  )
  return {entry.index: key for entry, key in zip(entries, keys)}


def step_key(key, t):
  """The key shared by every sample taken at timestamp `t`."""
  return None if key is None else jax.random.fold_in(key, t)


def canonical_dtype(dtype):
  """The dtype JAX actually uses for `dtype` (float64 -> float32 unless x64)."""
  return jnp.asarray(np.zeros((), dtype)).dtype


def needed_streams(key, obs, groups) -> tuple:
  """The buffer streams an enabled observable needs (empty: unused).

  Args:
    key: the observable's key.
    obs: the observable.
    groups: the updater's checked `{name: ObservationGroup}`, or None.
  """
  if groups is None:
    views = [True]
  else:
    views = [g.corrupted for g in groups.values() if key in g.keys]
  streams = set()
  for corrupted in views:
    streams.add(VALUE if (corrupted or obs.corruptor is None) else CLEAN)
  return tuple(sorted(streams, key=[VALUE, CLEAN].index))


def make_entry(
    index, dict_index, key, obs, streams, *, n, is_sequence
) -> Entry:
  """Reads an observable's options into its `Entry`.

  Args:
    index: the entry's position in `Updater.keys` (and `UpdaterState.buffers`).
    dict_index: which dict of the updater's observables holds it.
    key: its key in that dict.
    obs: the observable.
    streams: the buffer streams it needs (see `needed_streams`).
    n: the physics sub-steps per control step.
    is_sequence: whether the updater was given a list or tuple of dicts (then
      `dict_index` is part of the path its uids hash).
  """
  buffer_size = obs.buffer_size or DEFAULT_BUFFER_SIZE
  if (
      not is_number(buffer_size)
      or buffer_size != int(buffer_size)
      or (buffer_size < 1)
  ):
    raise ValueError(
        f'Observable {key!r}: buffer_size must be a positive '
        f'int (it fixes array shapes), got {buffer_size!r}.'
    )
  buffer_size = int(buffer_size)
  interval = Rate(
      key,
      'update_interval',
      obs.update_interval,
      DEFAULT_UPDATE_INTERVAL,
      minimum=1,
  )
  delay = Rate(key, 'delay', obs.delay, DEFAULT_DELAY, minimum=0)
  if interval.constant and delay.constant:
    schedule = obs_buffer.ConstantSchedule.plan(
        interval.low, delay.low, buffer_size, n
    )
    capacity = schedule.capacity
  else:
    schedule = None
    capacity = obs_buffer.arrival_capacity(
        buffer_size, delay.high, interval.low
    )
  path = key if not is_sequence else f'{dict_index}/{key}'
  uids = tuple(
      stable_id_lib.stable_id(f'{path}#{purpose}')
      for purpose in (CORRUPTOR, DELAY, INTERVAL)
  )
  spec = obs.array_spec
  entry = Entry(
      index=index,
      key=key,
      observable=obs,
      uids=uids,
      buffer_size=buffer_size,
      interval=interval,
      delay=delay,
      schedule=schedule,
      capacity=capacity,
      streams=streams,
      aggregator=obs.aggregator,
      corruptor=obs.corruptor,
      array_spec=spec,
  )
  if spec is not None:  # Samples are cast to the declared spec.
    for stream in streams:
      entry.shapes[stream] = jax.ShapeDtypeStruct(
          tuple(spec.shape), canonical_dtype(spec.dtype)
      )
  return entry
