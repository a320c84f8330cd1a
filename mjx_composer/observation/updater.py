"""The observation updater: composer's timing contract as pure functions.

`Updater` is built once on the host from the enabled observables. Its
`reset`, `update` and `get_observation` are pure functions of an
`UpdaterState` (fixed-size ring buffers and a step counter) that the
environment carries per world, so they can be jitted, vmapped and scanned.

Timing contract (composer's, `updater_test.testObservation`). Let n be the
physics sub-steps per control step and t the number of sub-steps since reset.
`reset` takes the sample with timestamp 0; the environment then calls
`update` after every physics sub-step (after the `after_step` hooks for the
last one) and reads observations at control-step boundaries t = k*n. For an
observable with constant `update_interval` u, `delay` d and `buffer_size` B:

* samples are taken at timestamps 0, u, 2u, ... (counted from reset);
* a sample taken at s becomes visible at s + d;
* the observation at t holds the samples with timestamps
  end - (B-1)*u, ..., end - u, end, oldest first, where
  end = u * floor((t - d) / u);
* entries with negative timestamps are padding: zeros
  (`ObservationPadding.ZERO`), or the timestamp-0 sample
  (`ObservationPadding.INITIAL_VALUE`, even while that sample is itself
  still delayed);
* the observation has shape (B, *shape); with `strip_singleton_buffer_dim`
  and B == 1 it has the sample's shape; an aggregator reduces the buffer axis.

Each sample passes through the observable's corruptor before it is buffered,
so aggregators and delays see corrupted values.

With a `Variation`-valued `update_interval` or `delay` (re-drawn for every
sample; the first delay at reset, the next interval whenever a sample is
taken), the observation holds the B samples that arrived (timestamp + delay
<= t) most recently, ordered by arrival time and then timestamp, padded in
front. A sample that arrived but was pushed out by B later arrivals before a
read is never seen. The variations need static bounds (`static_bounds()`),
which size the buffer: `B + ceil(max_delay / min_interval)` slots.

Work per sub-step. Whether a sample taken after sub-step j of a control step
can ever be seen at a boundary is static (it depends on j, n, u, d and B
only), so observables are evaluated only at those sub-steps; the rest cost
nothing. The sub-step index `substep` passed to `update` is a Python int or
an *unbatched* tracer (the environment's scan counter), so the choice is a
Python branch or a `lax.switch` that stays a real branch under `vmap`. Where
the choice depends on the per-world step count (u not dividing n, or a varying
rate) the value is computed and written under a mask. Conditionals are not
free on GPUs (each reads its predicate back to the host at every scan
iteration), so a caller
that scans sub-steps 1..n-1 should pass `substep_bounds=(1, n - 1)`: when the
same observables are sampled at all of those sub-steps (usually none), no
conditional is emitted.

Randomness. The sample taken at timestamp t uses
`fold_in(fold_in(key, t), uid)`, where `uid` hashes the observable's key and
the purpose (corruptor, delay or interval draw): adding or removing other
observables never changes an observable's noise, and samples differ even if
the caller reuses `key`. `fold_in(key, t)` is shared by all observables.

Where things live: `plan` reads each observable's options into a static
`plan.Entry` (rates, schedule, capacity, streams, key uids), `obs_buffer`
holds the buffers and their pure read/write functions, `obs_spec` builds the
`dm_env` specs; this module ties them into `Updater`.
"""

import dataclasses
import enum
from typing import Mapping, Optional

from flax import struct
import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer.observation import obs_buffer
from mjx_composer.observation import obs_spec
from mjx_composer.observation import plan
from mjx_composer.observation.groups import ObservationGroup
from mjx_composer.observation.observable import base as observable_base
from mjx_composer.observation.plan import DEFAULT_BUFFER_SIZE
from mjx_composer.observation.plan import DEFAULT_DELAY
from mjx_composer.observation.plan import DEFAULT_UPDATE_INTERVAL

# The defaults of the observables' options live in `plan`, which applies
# them; they are re-exported here, where composer has them.
__all__ = [
    'DEFAULT_BUFFER_SIZE',
    'DEFAULT_DELAY',
    'DEFAULT_UPDATE_INTERVAL',
    'ObservationPadding',
    'Updater',
    'UpdaterState',
]


class ObservationPadding(enum.Enum):
  """How to pad buffer entries that precede the first visible sample."""

  INITIAL_VALUE = -1
  ZERO = 0


@struct.dataclass
class UpdaterState:
  """What the environment carries per world for the observations.

  Attributes:
    t: () int32, physics sub-steps since reset (0 right after `reset`).
    buffers: one buffer per observable, in `Updater.keys` order: an
      `obs_buffer.RingBuffer` for constant rates, an
      `obs_buffer.ArrivalBuffer` for varying ones.
  """

  t: jax.Array
  buffers: tuple


def _static_int(value) -> Optional[int]:
  """`value` as a Python int if it is concrete, None if it is a tracer."""
  try:
    return int(value)
  except (
      jax.errors.ConcretizationTypeError,
      jax.errors.TracerIntegerConversionError,
  ):
    return None


class Updater:
  """Samples, buffers, delays and aggregates observables; pure and batched.

  See the module docstring for the timing contract.

  Args:
    observables: a dict (e.g. `OrderedDict`) `{key: Observable}`, or a list
      or tuple of such dicts. Only enabled observables are kept; outputs keep
      the container types. Options are read here, once.
    physics_steps_per_control_step: n, the physics sub-steps per control
      step.
    strip_singleton_buffer_dim: observations of buffer size 1 (without an
      aggregator) drop the buffer axis.
    pad_with_initial_value: pad with the timestamp-0 sample instead of zeros
      (a bool, or an `ObservationPadding`).
    groups: optional `{name: ObservationGroup}` (only with a dict of
      observables). Then `get_observation` returns `{name: group's
      observation}` and observables outside every group are never
      evaluated.
    physics: optional `Physics` (concrete or abstract) used to infer the
      shapes that `observation_spec()` needs. Without it, shapes are learnt
      when `reset` is first traced, or from `observation_spec(physics)`.
  """

  def __init__(
      self,
      observables,
      physics_steps_per_control_step=1,
      strip_singleton_buffer_dim=False,
      pad_with_initial_value=False,
      groups: Optional[Mapping[str, ObservationGroup]] = None,
      physics=None,
  ):
    if isinstance(observables, dict):
      dicts, self._is_sequence = [observables], False
    elif isinstance(observables, (list, tuple)) and all(
        isinstance(d, dict) for d in observables
    ):
      dicts, self._is_sequence = list(observables), True
    else:
      raise ValueError(
          '`observables` must be a dict, or a list or tuple of dicts, got '
          f'{type(observables).__name__}.'
      )
    n = int(physics_steps_per_control_step)
    if n < 1 or n != physics_steps_per_control_step:
      raise ValueError(
          'physics_steps_per_control_step must be a positive '
          f'int, got {physics_steps_per_control_step!r}.'
      )
    if isinstance(pad_with_initial_value, ObservationPadding):
      pad_with_initial_value = (
          pad_with_initial_value == ObservationPadding.INITIAL_VALUE
      )
    self._n = n
    self._strip = bool(strip_singleton_buffer_dim)
    self._pad = bool(pad_with_initial_value)
    self._observables = observables
    self._container_types = [type(d) for d in dicts]

    # (dict index, key, observable) of every enabled observable.
    enabled = [
        (i, k, obs)
        for i, d in enumerate(dicts)
        for k, obs in d.items()
        if obs.enabled
    ]
    self._groups = self._check_groups(groups, dicts, enabled)

    self._entries = []
    self._layout = [[] for _ in dicts]  # per dict: [(key, entry or None)]
    for i, key, obs in enabled:
      streams = plan.needed_streams(key, obs, self._groups)
      if not streams:
        self._layout[i].append((key, None))
        continue
      entry = plan.make_entry(
          len(self._entries),
          i,
          key,
          obs,
          streams,
          n=self._n,
          is_sequence=self._is_sequence,
      )
      self._entries.append(entry)
      self._layout[i].append((key, entry))
    self._by_key = {
        (i, k): e
        for i, layout in enumerate(self._layout)
        for k, e in layout
        if e is not None
    }
    if physics is not None:
      self._infer_shapes(physics)

  # -- configuration (host) --------------------------------------------------

  def _check_groups(self, groups, dicts, enabled):
    if not groups:
      return None
    if self._is_sequence:
      raise ValueError(
          'Observation groups need a dict of observables, not a '
          f'{type(self._observables).__name__} of dicts.'
      )
    enabled_keys = [k for _, k, _ in enabled]
    checked = {}
    for name, group in groups.items():
      if not isinstance(group, ObservationGroup):
        raise TypeError(
            f'Group {name!r} must be an ObservationGroup, got '
            f'{type(group).__name__}.'
        )
      keys = list(enabled_keys if group.keys is None else group.keys)
      for key in keys:
        if key not in dicts[0]:
          raise KeyError(
              f'Observation group {name!r} refers to {key!r}, '
              f'which is not an observable. Known: {list(dicts[0])}'
          )
        if key not in enabled_keys:
          raise ValueError(
              f'Observation group {name!r} refers to {key!r}, '
              'which is not enabled; enable it first.'
          )
      if len(set(keys)) != len(keys):
        raise ValueError(f'Observation group {name!r} lists a key twice.')
      checked[name] = dataclasses.replace(group, keys=tuple(keys))
    return checked

  # -- introspection ---------------------------------------------------------

  @property
  def physics_steps_per_control_step(self) -> int:
    return self._n

  @property
  def keys(self) -> tuple:
    """Keys of the buffered observables, in `UpdaterState.buffers` order."""
    return tuple(e.key for e in self._entries)

  def capacity(self, key: str, dict_index: int = 0) -> int:
    """The number of ring slots kept for an observable."""
    return self._by_key[(dict_index, key)].capacity

  def active_substeps(self, key: str, dict_index: int = 0) -> tuple:
    """The sub-steps (1..n) after which `update` evaluates an observable."""
    entry = self._by_key[(dict_index, key)]
    return tuple(j for j in range(1, self._n + 1) if self._is_active(entry, j))

  def _is_active(self, entry: plan.Entry, substep: int) -> bool:
    return entry.schedule is None or substep in entry.schedule.substeps

  # -- sampling --------------------------------------------------------------

  def _sample(self, entry: plan.Entry, physics, corruptor_key) -> dict:
    """Evaluates one observable once; returns `{stream: value}`.

    `corruptor_key`: the key of its corruptor's draw (`_corruptor_keys`).
    """
    raw = entry.observable.raw_observation_callable(physics)()
    samples = {}
    if plan.CLEAN in entry.streams:
      samples[plan.CLEAN] = self._conform(entry, raw, plan.CLEAN)
    if plan.VALUE in entry.streams:
      value = raw
      if entry.corruptor is not None:
        value = observable_base.corrupt(entry.corruptor, raw, corruptor_key)
      samples[plan.VALUE] = self._conform(entry, value, plan.VALUE)
    return samples

  def _conform(self, entry: plan.Entry, value, stream: str):
    """Casts a sample to its buffer's dtype and shape; records the shape."""
    value = jnp.asarray(value)
    spec = entry.array_spec
    if spec is not None:
      value = jnp.broadcast_to(
          value.astype(plan.canonical_dtype(spec.dtype)), tuple(spec.shape)
      )
    entry.shapes.setdefault(
        stream, jax.ShapeDtypeStruct(value.shape, value.dtype)
    )
    return value

  def _infer_shapes(self, physics):
    """Fills in sample shapes by tracing the observables abstractly."""
    missing = [
        e for e in self._entries if any(s not in e.shapes for s in e.streams)
    ]
    if not missing:
      return

    def sample_all(physics):
      key = jax.random.key(0)
      return [self._sample(e, physics, key) for e in missing]

    jax.eval_shape(sample_all, physics)

  def _corruptor_keys(self, entries, step_key) -> dict:
    """`{entry.index: key}` of the corruptor draws of `entries` at the
    timestamp of `step_key` (`plan.fold_each`)."""
    corrupted = [
        e
        for e in entries
        if e.corruptor is not None and plan.VALUE in e.streams
    ]
    return plan.fold_each(step_key, corrupted, plan.CORRUPTOR)

  # -- pure functions --------------------------------------------------------

  def reset(self, physics, key=None) -> UpdaterState:
    """Fresh buffers holding the timestamp-0 sample of every observable."""
    t = jnp.zeros((), jnp.int32)
    needs_key = any(e.needs_key for e in self._entries)
    step_key = plan.step_key(key, t) if needs_key else None
    buffers = []
    corruptor_keys = self._corruptor_keys(self._entries, step_key)
    for entry in self._entries:
      samples = self._sample(entry, physics, corruptor_keys.get(entry.index))
      if entry.schedule is not None:
        buffers.append(obs_buffer.ring_init(entry.schedule, samples, self._pad))
        continue
      delay, delay_state = entry.delay.draw(
          entry.delay.initial_state(),
          lambda: plan.fold(step_key, entry, plan.DELAY),
      )  # pylint: disable=cell-var-from-loop
      interval, interval_state = entry.interval.draw(
          entry.interval.initial_state(),
          lambda: plan.fold(step_key, entry, plan.INTERVAL),
      )  # pylint: disable=cell-var-from-loop
      buffers.append(
          obs_buffer.arrival_init(
              entry.capacity,
              samples,
              delay,
              interval,
              interval_state,
              delay_state,
              self._pad,
          )
      )
    return UpdaterState(t=t, buffers=tuple(buffers))

  @jax.named_scope('observation_update')
  def update(
      self, state: UpdaterState, physics, key, substep, *, substep_bounds=None
  ) -> UpdaterState:
    """Advances one physics sub-step, sampling what may become visible.

    Args:
      state: the current `UpdaterState`.
      physics: the `Physics` right after the sub-step (after the `after_step`
        hooks for the control step's last sub-step).
      key: a PRNG key for this sub-step (corruptors, varying rates). May be
        None if no observable needs one.
      substep: the 1-based index (1..n) of the sub-step just completed within
        the control step: a Python int, or an int32 tracer that is not
        batched (e.g. the environment's `lax.scan` counter).
      substep_bounds: optional static `(low, high)` range that a traced
        `substep` is known to lie in, e.g. `(1, n - 1)` inside the
        environment's sub-step scan: branches for other sub-steps are not
        built, and if the same observables (often none) are sampled at every
        sub-step of that range, no conditional is emitted at all.

    Returns:
      The new state, with `t` incremented.
    """
    n = self._n
    state = state.replace(t=state.t + 1)
    j = _static_int(substep)
    if j is not None:
      if not 1 <= j <= n:
        raise ValueError(f'substep must be in 1..{n}, got {j}.')
      return self._apply(self._active(j), state, physics, key, j)
    low, high = substep_bounds if substep_bounds is not None else (1, n)
    if not 1 <= low <= high <= n:
      raise ValueError(
          f'substep_bounds must satisfy 1 <= low <= high <= {n}, '
          f'got {substep_bounds!r}.'
      )
    signatures = [self._active(j) for j in range(low, high + 1)]
    distinct = list(dict.fromkeys(signatures))
    if len(distinct) == 1:
      return self._apply(distinct[0], state, physics, key, substep)
    table = np.asarray([distinct.index(s) for s in signatures], np.int32)
    branch = jnp.asarray(table)[jnp.clip(substep - low, 0, high - low)]
    branches = [
        (lambda active: lambda s, p, k, j: self._apply(active, s, p, k, j))(a)
        for a in distinct
    ]
    return jax.lax.switch(branch, branches, state, physics, key, substep)

  def _active(self, substep: int) -> tuple:
    """Indices of the observables evaluated after sub-step `substep`."""
    return tuple(e.index for e in self._entries if self._is_active(e, substep))

  def _apply(self, active, state, physics, key, substep) -> UpdaterState:
    buffers = list(state.buffers)
    t = state.t
    needs_key = any(self._entries[i].needs_key for i in active)
    step_key = plan.step_key(key, t) if needs_key else None
    corruptor_keys = self._corruptor_keys(
        [self._entries[i] for i in active], step_key
    )
    for index in active:
      entry = self._entries[index]
      buffer = buffers[index]
      samples = self._sample(entry, physics, corruptor_keys.get(index))
      if entry.schedule is not None:
        buffers[index] = obs_buffer.ring_write(
            entry.schedule, buffer, samples, t, substep
        )
        continue
      take = t == buffer.next_timestamp
      delay, delay_state = entry.delay.draw(
          buffer.delay_state, lambda: plan.fold(step_key, entry, plan.DELAY)
      )  # pylint: disable=cell-var-from-loop
      interval, interval_state = entry.interval.draw(
          buffer.interval_state,
          lambda: plan.fold(step_key, entry, plan.INTERVAL),
      )  # pylint: disable=cell-var-from-loop
      buffer = obs_buffer.arrival_insert(buffer, samples, t, delay, take)
      select = lambda new, old: jax.tree.map(  # pylint: disable=cell-var-from-loop
          lambda a, b: jnp.where(take, a, b), new, old
      )
      buffers[index] = buffer.replace(
          next_timestamp=jnp.where(take, t + interval, buffer.next_timestamp),
          delay_state=select(delay_state, buffer.delay_state),
          interval_state=select(interval_state, buffer.interval_state),
      )
    return state.replace(buffers=tuple(buffers))

  # -- reading ---------------------------------------------------------------

  def _read(self, entry: plan.Entry, state: UpdaterState, stream: str):
    buffer = state.buffers[entry.index]
    if entry.schedule is not None:
      return obs_buffer.ring_read(entry.schedule, buffer, state.t, stream)
    return obs_buffer.arrival_read(buffer, state.t, entry.buffer_size, stream)

  def _observe(self, entry: plan.Entry, state: UpdaterState, corrupted: bool):
    values, _ = self._read(entry, state, entry.stream(corrupted))
    return obs_buffer.strip_or_aggregate(values, entry.aggregator, self._strip)

  def get_observation(self, state: UpdaterState):
    """The observation of one world at a control-step boundary.

    Reads are only defined where `state.t` is a multiple of n (after `reset`
    or after the update of a control step's last sub-step): samples that no
    such read can see are never taken.

    Returns:
      Without groups, the structure of `observables` (same container types)
      holding the enabled observables. With groups, `{group name: dict}` (or
      a flat vector for `flatten=True` groups).
    """
    return self._structure(
        lambda e, corrupted: self._observe(e, state, corrupted),
        flat=self._flatten_values,
    )

  def buffer_timestamps(self, state: UpdaterState):
    """Like `get_observation`, but the timestamps of the buffered samples.

    Each entry is an int32 array `(B,)`, oldest first, -1 for padding; no
    aggregation or stripping. Handy for checking timing.
    """
    return self._structure(
        lambda e, corrupted: self._read(e, state, e.stream(corrupted))[1],
        flat=None,
    )

  def observation_spec(self, physics=None):
    """`dm_env` specs matching `get_observation`.

    Shapes come from `array_spec`s, from a traced `reset`, or by tracing the
    observables on `physics` (a `Physics`, concrete or abstract) with
    `jax.eval_shape`; no observation is computed.
    """
    if physics is not None:
      self._infer_shapes(physics)
    missing = [
        e.key
        for e in self._entries
        if any(s not in e.shapes for s in e.streams)
    ]
    if missing:
      raise RuntimeError(
          f'The shapes of observables {missing} are not known yet: pass a '
          'Physics to observation_spec(physics) or to Updater(..., '
          'physics=...), or trace reset first.'
      )
    return self._structure(
        lambda e, corrupted: obs_spec.observable_spec(
            e, corrupted, self._strip
        ),
        flat=obs_spec.flat_group_spec,
    )

  # -- structure -------------------------------------------------------------

  def _structure(self, leaf, flat):
    """Builds the output structure, calling `leaf(entry, corrupted)`."""
    if self._groups is None:
      out = []
      for container_type, layout in zip(self._container_types, self._layout):
        d = container_type()
        for key, entry in layout:
          d[key] = leaf(entry, True)
        out.append(d)
      return type(self._observables)(out) if self._is_sequence else out[0]
    result = {}
    for name, group in self._groups.items():
      d = self._container_types[0]()
      for key in group.keys:
        d[key] = leaf(self._by_key[(0, key)], group.corrupted)
      result[name] = flat(name, d) if (group.flatten and flat) else d
    return result

  @staticmethod
  def _flatten_values(name, values):
    del name
    if not values:
      return jnp.zeros((0,), jnp.float32)
    return jnp.concatenate(
        [jnp.ravel(v).astype(jnp.float32) for v in values.values()]
    )
