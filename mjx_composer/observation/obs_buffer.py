"""Observation buffers as fixed-size arrays carried in the environment state.

composer keeps, per observable, a deque of arrived samples and a sorted list
of in-flight ones, plus a planner that schedules future samples. Here both are
replaced by pure functions of small, fixed-size arrays, in two flavours:

`RingBuffer` (constant `update_interval` u and `delay` d). Samples are taken
at timestamps 0, u, 2u, ... (sub-steps since reset); the sample with index
`m` (timestamp `m*u`) lives in slot `m % capacity`. Because reads happen at
control-step boundaries `t = k*n`, the visible samples are a pure function of
`t`: the newest is `end = u*floor((t - d)/u)`, then `end - u`, ... No
timestamps need storing: they follow from `t`. A static `ConstantSchedule`
says at which sub-steps of a control step a sample can ever become visible
(the others are never evaluated), whether slots depend on the sub-step only
(then writes and reads use static or unbatched indices), and whether a
per-world mask is needed (when u does not divide n).

`ArrivalBuffer` (a `Variation`-valued interval or delay). composer's deque
then keeps the `buffer_size` most recently *arrived* samples, ordered by
arrival time (`timestamp + delay`, ties by timestamp), and samples pushed out
before a read are never seen. At read time `t` that is exactly: the last B,
in (arrival, timestamp) order, of the samples with `arrival <= t`. The buffer
stores `capacity = B + ceil(max_delay / min_interval)` slots of (value,
timestamp, arrival): at most `ceil(max_delay / min_interval)` samples can be
in flight at once, and an arrived sample that is not among the B latest
arrivals can never be seen again, so inserting a sample may always evict an
empty slot or the earliest arrival. (Slots indexed by sample number would
need more: a long-delayed old sample can still be the newest arrival while
almost 2*ceil(max_delay / min_interval) newer samples exist.)

Buffers may hold several "streams" of values that share timestamps (the
corrupted value and, when an observation group asks for it, the clean one).
"""

import dataclasses
import math
from typing import Any, Optional

from flax import struct
import jax
import jax.numpy as jnp
import numpy as np

# ---------------------------------------------------------------------------
# Constant rates: a static schedule and a ring buffer.
# ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class ConstantSchedule:
  """Static plan for an observable with constant interval, delay and size.

  Attributes:
    update_interval: u, sub-steps between samples (>= 1).
    delay: d, sub-steps between taking a sample and seeing it (>= 0).
    buffer_size: B, samples per observation (>= 1).
    n: physics sub-steps per control step.
    capacity: ring slots; `B + max over reads of (newest taken - newest
      visible)`, rounded up to a divisor of n/u when that makes slots static.
    static_slots: slots depend on the sub-step within the control step only
      (u divides n and capacity divides n/u), not on the per-world step count.
    masked: u does not divide n, so whether a sub-step takes a sample depends
      on the per-world step count: the value is computed and written under a
      mask.
    substeps: the sub-steps (1..n) after which a sample may be taken that
      some read at a control-step boundary can see. At all other sub-steps
      the observable is not evaluated.
  """

  update_interval: int
  delay: int
  buffer_size: int
  n: int
  capacity: int
  static_slots: bool
  masked: bool
  substeps: frozenset

  @classmethod
  def plan(
      cls, update_interval: int, delay: int, buffer_size: int, n: int
  ) -> 'ConstantSchedule':
    u, d, b = update_interval, delay, buffer_size
    if u < 1 or d < 0 or b < 1 or n < 1:
      raise ValueError(
          f'Invalid schedule: update_interval={u}, delay={d}, '
          f'buffer_size={b}, n={n}.'
      )
    # Reads happen at t = k*n. The newest *taken* sample is floor(t/u); the
    # newest *visible* one floor((t-d)/u). The ring must hold the visible
    # window plus everything taken after it. kn mod u repeats with period u.
    lag = max((k * n) // u - (k * n - d) // u for k in range(u))
    capacity = b + lag
    static_slots = False
    if n % u == 0:
      per_step = n // u
      divisors = [c for c in range(capacity, per_step + 1) if per_step % c == 0]
      if divisors:
        capacity, static_slots = divisors[0], True
    g = math.gcd(n, u)
    substeps = set()
    for j in range(1, n + 1):
      if j % g:
        continue  # No timestamp kn + j is a multiple of u.
      # A sample taken at s = kn + j is seen by the read at k'n iff
      # k'n - d lies in [s, s + B*u - 1]: the distance from s + d to the next
      # multiple of n must be below B*u.
      if (-(j + d)) % n < b * u:
        substeps.add(j)
    return cls(
        u,
        d,
        b,
        n,
        capacity,
        static_slots,
        masked=(g != u),
        substeps=frozenset(substeps),
    )

  def write_slot(self, t, substep):
    """The ring slot of the sample taken at timestamp `t` (sub-step `substep`).

    With static slots it depends on `substep` only, which is a Python int or
    an unbatched tracer, so the write is a plain dynamic-update-slice.
    """
    if self.static_slots:
      return (substep // self.update_interval) % self.capacity
    return (t // self.update_interval) % self.capacity

  def is_sample_time(self, t):
    """Per-world: whether timestamp `t` is a multiple of the interval."""
    return t % self.update_interval == 0

  def read_indices(self, t):
    """Sample indices visible at control boundary `t`, oldest first.

    Returns:
      `(slots, sample_indices)`: ring slots (static numpy ints when slots are
      static) and sample indices (negative for padding), each of shape (B,).
    """
    u, d, b = self.update_interval, self.delay, self.buffer_size
    offsets = np.arange(-(b - 1), 1)
    newest = jnp.floor_divide(t - d, u)
    indices = newest + offsets
    if self.static_slots:
      # t = k*n and capacity divides n/u, so newest % capacity = (-d//u) % C.
      slots = ((-d) // u + offsets) % self.capacity
    else:
      slots = jnp.mod(indices, self.capacity)
    return slots, indices


@struct.dataclass
class RingBuffer:
  """Carried state of one constant-rate observable.

  Attributes:
    values: `{stream: (capacity, *shape)}`; slot `m % capacity` holds sample
      `m` (timestamp `m * update_interval`) once it has been taken, if it is
      ever visible.
    initial: `{stream: shape}`, the timestamp-0 sample, kept for
      initial-value padding; empty under zero padding.
  """

  values: dict
  initial: dict


def ring_init(
    schedule: ConstantSchedule, samples: dict, pad_with_initial_value: bool
) -> RingBuffer:
  """A ring holding the timestamp-0 sample (index 0, slot 0)."""
  values = {
      name: jnp.zeros((schedule.capacity,) + v.shape, v.dtype).at[0].set(v)
      for name, v in samples.items()
  }
  initial = dict(samples) if pad_with_initial_value else {}
  return RingBuffer(values=values, initial=initial)


def ring_write(
    schedule: ConstantSchedule, buffer: RingBuffer, samples: dict, t, substep
) -> RingBuffer:
  """Stores the samples taken at timestamp `t`, the end of `substep`."""
  slot = schedule.write_slot(t, substep)
  take = schedule.is_sample_time(t) if schedule.masked else None
  values = {}
  for name, old in buffer.values.items():
    new = samples[name]
    if schedule.capacity == 1:
      new = new[None]
      values[name] = new if take is None else jnp.where(take, new, old)
      continue
    if take is not None:
      new = jnp.where(
          take,
          new,
          jax.lax.dynamic_index_in_dim(old, slot, axis=0, keepdims=False),
      )
    values[name] = jax.lax.dynamic_update_index_in_dim(old, new, slot, axis=0)
  return buffer.replace(values=values)


def ring_read(schedule: ConstantSchedule, buffer: RingBuffer, t, stream: str):
  """The buffered observation at control boundary `t`, oldest first.

  Returns:
    `(values, timestamps)` of shapes `(B, *shape)` and `(B,)`; padding
    entries have timestamp -1 and hold zeros or the timestamp-0 sample.
  """
  slots, indices = schedule.read_indices(t)
  ring = buffer.values[stream]
  if isinstance(slots, np.ndarray):
    # Static slots: a slice when they are contiguous, else a constant gather.
    if np.all(np.diff(slots) == 1):
      values = ring[int(slots[0]) : int(slots[-1]) + 1]
    else:
      values = ring[slots]
  else:
    values = jnp.take(ring, slots, axis=0)
  valid = indices >= 0
  timestamps = jnp.where(valid, indices * schedule.update_interval, -1)
  if schedule.delay == 0 and schedule.buffer_size == 1:
    return values, timestamps  # The newest sample, index k*n/u >= 0, exists.
  pad = buffer.initial.get(stream)
  pad = jnp.zeros_like(values[0]) if pad is None else pad
  mask = valid.reshape(valid.shape + (1,) * (values.ndim - 1))
  return jnp.where(mask, values, pad[None]), timestamps


# ---------------------------------------------------------------------------
# Variable rates: arrival-ordered slots.
# ---------------------------------------------------------------------------


@struct.dataclass
class ArrivalBuffer:
  """Carried state of an observable with a varying interval or delay.

  Attributes:
    values: `{stream: (capacity, *shape)}` sample values.
    timestamps: `(capacity,)` int32 timestamps; -1 marks an empty slot.
    arrivals: `(capacity,)` int32 `timestamp + delay` of each sample.
    initial: `{stream: shape}` timestamp-0 samples for initial-value padding.
    next_timestamp: () int32, when the next sample is due.
    interval_state: the state pytree of a stateful interval `Variation`
      (e.g. a `Sequence`'s position), or None.
    delay_state: likewise for the delay.
  """

  values: dict
  timestamps: jax.Array
  arrivals: jax.Array
  initial: dict
  next_timestamp: jax.Array
  interval_state: Any
  delay_state: Any


def arrival_init(
    capacity: int,
    samples: dict,
    delay,
    next_timestamp,
    interval_state,
    delay_state,
    pad_with_initial_value: bool,
) -> ArrivalBuffer:
  """A buffer holding the timestamp-0 sample, arriving at `delay`."""
  values = {
      name: jnp.zeros((capacity,) + v.shape, v.dtype).at[0].set(v)
      for name, v in samples.items()
  }
  timestamps = jnp.full((capacity,), -1, jnp.int32).at[0].set(0)
  arrivals = jnp.zeros((capacity,), jnp.int32).at[0].set(delay)
  return ArrivalBuffer(
      values=values,
      timestamps=timestamps,
      arrivals=arrivals,
      initial=dict(samples) if pad_with_initial_value else {},
      next_timestamp=jnp.asarray(next_timestamp, jnp.int32),
      interval_state=interval_state,
      delay_state=delay_state,
  )


def arrival_insert(
    buffer: ArrivalBuffer, samples: dict, t, delay, take
) -> ArrivalBuffer:
  """Inserts the samples taken at `t` with `delay`, where `take` is true.

  The slot reused is an empty one if any, else the sample that arrived
  earliest (by arrival, then timestamp). With the capacity bound of the
  module docstring that sample can no longer be seen, and in-flight samples
  are never evicted.
  """
  empty = buffer.timestamps < 0
  arrived = jnp.logical_and(~empty, buffer.arrivals <= t)
  # Eviction order: empty slots, then arrived samples oldest arrival first,
  # then in-flight samples (never chosen while the capacity bound holds).
  category = jnp.where(empty, 0, jnp.where(arrived, 1, 2))
  slot = jnp.lexsort((buffer.timestamps, buffer.arrivals, category))[0]
  values = {}
  for name, old in buffer.values.items():
    new = jnp.where(take, samples[name], old[slot])
    values[name] = old.at[slot].set(new)
  timestamps = buffer.timestamps.at[slot].set(
      jnp.where(take, t, buffer.timestamps[slot])
  )
  arrivals = buffer.arrivals.at[slot].set(
      jnp.where(take, t + delay, buffer.arrivals[slot])
  )
  return buffer.replace(values=values, timestamps=timestamps, arrivals=arrivals)


def arrival_read(buffer: ArrivalBuffer, t, buffer_size: int, stream: str):
  """The B latest arrivals at time `t`, in arrival order, padded in front.

  Returns:
    `(values, timestamps)` of shapes `(B, *shape)` and `(B,)`; padding
    entries have timestamp -1.
  """
  arrived = jnp.logical_and(buffer.timestamps >= 0, buffer.arrivals <= t)
  order = jnp.lexsort(
      (buffer.timestamps, buffer.arrivals, arrived.astype(jnp.int32))
  )
  chosen = order[-buffer_size:]
  valid = arrived[chosen]
  ring = buffer.values[stream]
  values = ring[chosen]
  pad = buffer.initial.get(stream)
  pad = jnp.zeros_like(values[0]) if pad is None else pad
  mask = valid.reshape(valid.shape + (1,) * (values.ndim - 1))
  timestamps = jnp.where(valid, buffer.timestamps[chosen], -1)
  return jnp.where(mask, values, pad[None]), timestamps


def arrival_capacity(
    buffer_size: int, max_delay: int, min_interval: int
) -> int:
  """Slots needed: B arrived samples plus every sample that can be in flight."""
  return buffer_size + -(-max_delay // min_interval)


def strip_or_aggregate(
    values, aggregator: Optional[object], strip_singleton: bool
):
  """Applies the aggregator over axis 0, or strips a singleton buffer axis."""
  if aggregator is not None:
    return aggregator(values)
  if strip_singleton and values.shape[0] == 1:
    return values[0]
  return values
