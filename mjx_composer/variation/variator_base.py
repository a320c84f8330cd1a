"""What `MJCFVariator` and `PhysicsVariator` share: bindings, schedules, state.

A variator binds variations to attributes of elements and, when applied,
samples them for one world and writes the result into that world's model.
Everything that must outlive an episode (when to resample, the state of
stateful variations such as `deterministic.Sequence`, the current values of
MJCF attributes) is kept in the world's persistent entries
(`Physics.get_persistent`), under one entry per variator, created at reset
with its final shapes. The entry's name derives from what the variator
binds (its class, and the compiled names and attributes of its bindings),
so it does not depend on construction order; pass `name=` to choose it.

Schedules (`Schedule`) say when a variator resamples:

* `Schedule.per_episode()` (the default): every call from
  `initialize_episode` draws fresh values, so every episode of every world
  gets its own (unlike Playground's randomize-once wrapper).
* `Schedule.once_per_world()`: the first reset of a world draws; later
  (auto-)resets keep the world's values. `Environment.reset(key)` starts a
  world afresh, so it draws again.
* `Schedule.every_steps(k)`: the reset call draws, restarts the count and
  schedules the variator to run at every control step
  (`Physics.schedule_before_step`, before the task's `before_step`); it
  draws again every k control steps: at the start of control steps k+1,
  2k+1, ... of the episode (so every draw holds for k steps, the last one
  until the episode ends). Outside an `Environment`, make that per-step call
  yourself: `apply_variations(physics, key, in_step=True)`.

Inside jit a skipped draw is a `jnp.where` between the new and the current
values: the sampling (and, for an `MJCFVariator`, the re-derivation of
compiled fields) still runs, its result is just not used. An every-k-steps
MJCFVariator with derived attributes (sizes, masses, poses) therefore pays
for that re-derivation at every control step.

Initial values are the compiled defaults (never the values of a previous
episode), so non-cumulative variations never compound across episodes;
`current_value` is the world's current value, which cumulative variations
(`noises.Additive(..., cumulative=True)`) build on.

Invalid draws. Every bound attribute has a bound (`compiler.attributes.Bound`:
the MJCF catalogue's record for an `MJCFVariator`, `physics_variator.
FIELD_BOUNDS` by compiled field for a `PhysicsVariator`): every value must be
finite, and mass, density, inertia, friction, damping, stiffness, armature,
frictionloss, option density and viscosity must be >= 0, a geom size >= 0
with a first entry > 0, rgba in [0, 1], the timestep > 0 (other attributes:
finite only). Where the compiled value itself breaks its bound (e.g. the
zero size of an infinite plane), the binding's bound is relaxed to what the
compiled value meets (size: >= 0; else finite only). A draw is *invalid*
when any of the variator's sampled values breaks its bound (a skipped draw,
once per world or between every-k-steps draws, is never invalid):

* in a call from `initialize_episode`, the values are written as drawn and
  the episode's initialization is marked failed
  (`physics.fail_initialization(invalid)`): `Environment(max_reset_attempts=
  N)` resamples the episode with a fresh key and counts the failed attempts
  in `metrics['init_failures']` (`metrics['init_failed']` when the last
  attempt fails too, and the world then keeps what its reset started from,
  never running the invalid values: `Transitions.initialize`), as
  recompiling an invalid MJCF would refuse it;
* in a per-step call (every k steps), the draw is dropped: the world keeps
  its current values and variation states (a running episode cannot be
  resampled).

A constant bound value that breaks its bound is refused at bind time
(`ValueError`, naming the attribute and the bound), when the bound is known
then (always for an `MJCFVariator`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer.compiler import attributes
from mjx_composer.platform import internals_jax
from mjx_composer.utils import stable_id as stable_id_lib
from mjx_composer.variation import base
from mjx_composer.variation import rounds
from mjx_composer.variation import structures


@dataclasses.dataclass(frozen=True)
class Schedule:
  """When a variator draws new values (see the module docstring).

  Build one with `Schedule.per_episode()`, `Schedule.once_per_world()` or
  `Schedule.every_steps(k)`.
  """

  mode: str = 'episode'
  interval: int = 0

  def __post_init__(self):
    if self.mode not in ('episode', 'world', 'steps'):
      raise ValueError(
          f'Unknown schedule mode {self.mode!r}: use '
          'Schedule.per_episode(), Schedule.once_per_world() or '
          'Schedule.every_steps(k).'
      )
    if self.mode == 'steps' and (
        int(self.interval) != self.interval or self.interval < 1
    ):
      raise ValueError(
          'Schedule.every_steps(k) needs a positive integer k, '
          f'got {self.interval!r}.'
      )

  @classmethod
  def per_episode(cls) -> 'Schedule':
    """Draw at every reset (composer's behaviour)."""
    return cls('episode')

  @classmethod
  def once_per_world(cls) -> 'Schedule':
    """Draw at a world's first reset only; auto-resets keep the values."""
    return cls('world')

  @classmethod
  def every_steps(cls, k: int) -> 'Schedule':
    """Draw at reset and then every `k` control steps (see module doc)."""
    return cls('steps', k)

  def __str__(self):
    if self.mode == 'steps':
      return f'Schedule.every_steps({self.interval})'
    return {
        'episode': 'Schedule.per_episode()',
        'world': 'Schedule.once_per_world()',
    }[self.mode]


@dataclasses.dataclass
class Binding:
  """One variation bound to one attribute of one element.

  Attributes:
    element: the element handle (or `MjOption`) as the user passed it.
    attr: the attribute name.
    variation: a variation, a constant, or a nested structure of them.
    slot: a number fixed at bind time; the binding's key is
      `fold_in(key, slot)`, so (un)binding other attributes never changes
      the values this one draws.
  """

  element: Any
  attr: str
  variation: Any
  slot: int

  def describe(self) -> str:
    return f'{describe_element(self.element)}.{self.attr}'


def _compiled_name(element, index) -> str:
  """`kind:full name` of a bound element (the option has no name)."""
  kind = type(element).__name__
  try:
    return f'{kind}:{index.full_name(element)}'
  except (ValueError, TypeError, AttributeError):
    return kind


def describe_element(element) -> str:
  name = getattr(element, 'name', '')
  kind = type(element).__name__
  return f'{kind}({name!r})' if name else kind


class Variator:
  """Base class: bindings, schedules and the persistent state protocol.

  Subclasses implement `_check_binding(element, attr, variation)` (bind-time
  validation), optionally `_bound(element, attr)` (the attribute's `Bound`
  if known at bind time, for constants) and `_prepare(physics)`, the
  trace-time resolution, which returns a plan with `initial_values` (one
  numpy array per binding, the compiled default), `bounds` (one `Bound` per
  binding), `read_current(physics, entry)` (the world's current values) and
  `write(physics, values) -> (physics, extra entries)`.

  The persistent entry (`persistent_name`) holds `states` (the bindings'
  variation states), `applied` (once per world) or `count` (every k steps),
  and whatever `write` returns (MJCF attribute values).
  """

  def __init__(self, schedule: Schedule | None = None, name: str | None = None):
    """Initializes the variator.

    Args:
      schedule: when to draw (a `Schedule`); defaults to every episode.
      name: the name of this variator's persistent entry. Defaults to one
        derived from its bindings (see the module docstring).
    """
    if schedule is None:
      schedule = Schedule.per_episode()
    if not isinstance(schedule, Schedule):
      raise TypeError(
          'schedule must be a variation.Schedule (e.g. '
          'Schedule.every_steps(10)), got '
          f'{type(schedule).__name__}.'
      )
    self._schedule = schedule
    self._name = name
    self._derived_name = None
    self._bindings: dict[tuple[int, str], Binding] = {}
    self._next_slot = 0
    self._plans: dict[int, Any] = {}

  @property
  def schedule(self) -> Schedule:
    return self._schedule

  @property
  def persistent_name(self) -> str:
    """The key of this variator's entry in `physics.persistent`.

    Without an explicit `name`, it is known once the variator has been
    applied to an environment's physics (its bindings' compiled names).
    """
    if self._name is not None:
      return self._name
    if self._derived_name is None:
      raise ValueError(
          f'This {type(self).__name__} has not been applied yet, so its '
          "persistent name (derived from its bindings' compiled names) is "
          'not known: apply it (trace reset) first, or pass name=.'
      )
    return self._derived_name

  @property
  def label(self) -> str:
    """How error messages name this variator (its name once known)."""
    return self._name or self._derived_name or type(self).__name__

  def _persistent_name(self, physics) -> str:
    """The entry name for this physics' compiled model."""
    if self._name is not None:
      return self._name
    parts = sorted(
        f'{_compiled_name(b.element, physics.index)}.{b.attr}'
        for b in self.bindings
    )
    digest = stable_id_lib.stable_digest('|'.join(parts))
    more = f',+{len(parts) - 1}' if len(parts) > 1 else ''
    self._derived_name = f'{type(self).__name__}[{parts[0]}{more}]#{digest:08x}'
    return self._derived_name

  @property
  def bindings(self) -> tuple[Binding, ...]:
    return tuple(self._bindings.values())

  def bind_attributes(self, element, **variations):
    """Binds variations to attributes of `element`.

    Args:
      element: the element whose attributes vary.
      **variations: `attribute=variation`, where a variation is a
        `Variation`, any callable `(initial_value, current_value, key)`, a
        constant, or a nested structure of them. `attribute=None` unbinds an
        attribute bound before.

    Raises:
      ValueError, TypeError: for an attribute this variator cannot vary, a
        value whose shape can never match the attribute's, or a constant
        value that breaks the attribute's bound (see the module docstring).
    """
    for attr, variation in variations.items():
      key = (id(element), attr)
      if variation is None:
        self._bindings.pop(key, None)
        continue
      self._check_binding(element, attr, variation)
      self._check_constant(element, attr, variation)
      old = self._bindings.get(key)
      if old is not None:
        old.variation = variation
      else:
        self._bindings[key] = Binding(element, attr, variation, self._next_slot)
        self._next_slot += 1
    self._plans.clear()

  def clear(self):
    """Removes every binding."""
    self._bindings.clear()
    self._plans.clear()

  def _check_binding(self, element, attr, variation):
    raise NotImplementedError

  def _bound(self, element, attr):
    """The attribute's `Bound` if known at bind time, else None."""
    del element, attr
    return None

  def _check_constant(self, element, attr, variation):
    """Refuses a constant value that breaks the attribute's bound."""
    bound = self._bound(element, attr)
    value = _constant_value(variation)
    if bound is None or value is None or bound.valid(value):
      return
    raise ValueError(
        f'{self.label}: the constant {variation!r} bound to '
        f'{describe_element(element)}.{attr} is invalid: {attr} must be '
        f'{bound.describe()}.'
    )

  def _prepare(self, physics):
    raise NotImplementedError

  def _plan(self, physics):
    """The trace-time plan for this physics' compiled model (cached)."""
    index = physics.index
    plan = self._plans.get(id(index))
    if plan is None or plan[0] is not index:
      plan = (index, self._prepare(physics))
      self._plans[id(index)] = plan
    return plan[1]

  # -- applying -------------------------------------------------------------

  @jax.named_scope('apply_variations')
  def apply_variations(self, physics, key, *, in_step: bool = False):
    """Samples the bound attributes for this world, per the schedule.

    Call it from `initialize_episode`. With `Schedule.every_steps(k)` that
    call also schedules the per-step draws (see the module docstring).

    Args:
      physics: the world's `Physics`.
      key: a JAX PRNG key (the hook's key).
      in_step: True for the per-control-step call of an every-k-steps
        schedule; an `Environment` makes it itself.

    Returns:
      The `Physics` with the varied model fields and this variator's
      persistent entry.
    """
    if not self._bindings:
      return physics
    schedule = self._schedule
    name = self._persistent_name(physics)
    entry = physics.get_persistent(name)
    if in_step:
      if schedule.mode != 'steps':
        raise ValueError(
            f'{name}: apply_variations(..., in_step=True) only applies to '
            f'Schedule.every_steps(k); this variator draws on '
            f'{schedule}. Call it from initialize_episode only.'
        )
      if entry is None:
        raise ValueError(
            f'{name}: call apply_variations(physics, key) from '
            'initialize_episode as well: it creates the step counter that '
            'the in-step calls advance.'
        )
    plan = self._plan(physics)
    bindings = self.bindings
    initial = plan.initial_values
    current = plan.read_current(physics, entry)
    fresh_states = tuple(
        structures.initial_state(b.variation, initial[i])
        for i, b in enumerate(bindings)
    )
    states = (
        fresh_states
        if entry is None or 'states' not in entry
        else entry['states']
    )

    new_entry = {}
    if schedule.mode == 'episode':
      draw = True
    elif schedule.mode == 'world':
      applied = jnp.zeros((), bool) if entry is None else entry['applied']
      draw = jnp.logical_not(applied)
      new_entry['applied'] = jnp.ones((), bool)
    else:
      if in_step:
        # `count` is the number of control steps completed this episode.
        done = entry['count']
        draw = (done > 0) & (done % schedule.interval == 0)
        count = done + 1
      else:
        count, draw = jnp.zeros((), jnp.int32), True
      new_entry['count'] = jnp.asarray(count, jnp.int32)

    drawn = _draw(bindings, states, key, initial, current)
    values = [
        _conform(value, initial[i], binding, name)
        for i, (binding, (value, _)) in enumerate(zip(bindings, drawn))
    ]
    new_states = tuple(state for _, state in drawn)
    invalid = invalid_draw(values, plan.bounds)
    if draw is not True:
      invalid = jnp.logical_and(draw, invalid)
    if in_step:
      # A running episode cannot be resampled: drop an invalid draw.
      draw = jnp.logical_and(draw, jnp.logical_not(invalid))
    if draw is not True:
      values = [jnp.where(draw, v, c) for v, c in zip(values, current)]
      new_states = jax.tree.map(
          lambda a, b: jnp.where(draw, a, b), new_states, tuple(states)
      )
    if not in_step:
      physics = physics.fail_initialization(invalid)
    new_entry['states'] = new_states
    physics, extra = plan.write(physics, values)
    new_entry.update(extra)
    physics = physics.set_persistent(name, new_entry)
    if schedule.mode == 'steps' and not in_step:
      physics = physics.schedule_before_step(name, self._draw_in_step)
    return physics

  def _draw_in_step(self, physics, key):
    """The per-control-step call of an every-k-steps schedule."""
    return self.apply_variations(physics, key, in_step=True)


def _draw(bindings, states, key, initial, current):
  """`[(value, new_state), ...]` of each binding's variation: its key folded
  from `key` with the binding's slot, all drawn in one evaluation round
  (`structures.sample_each`)."""
  keys = stable_id_lib.fold_in_each(key, [binding.slot for binding in bindings])
  with rounds.evaluation_round(key):
    return structures.sample_each(
        [binding.variation for binding in bindings],
        states,
        keys,
        initial,
        current,
    )


def draws_read_current(bindings, initial_values) -> bool:
  """Whether drawing `bindings`' variations reads the current values.

  A cumulative noise builds on them, and a callable may read its
  `current_value`; distributions and noises of the initial value do not.
  From an abstract trace of the draws, by dead-code elimination: True where
  some draw's value depends on a current value (or where this JAX has no
  dead-code elimination to call). Where none does, an episode's draws need
  no current values, and a world need not keep them between episodes.
  """
  if internals_jax.dce_jaxpr is None:
    return True
  initial = [np.asarray(v) for v in initial_values]
  states = tuple(
      structures.initial_state(b.variation, i)
      for b, i in zip(bindings, initial)
  )

  def draw(key, current):
    drawn = _draw(bindings, states, key, initial, current)
    return [value for value, _ in drawn]

  key = jax.random.key(0)
  closed, values = jax.make_jaxpr(draw, return_shape=True)(key, initial)
  used = [True] * len(jax.tree.leaves(values))
  _, used_inputs = internals_jax.dce_jaxpr(
      closed.jaxpr, used, instantiate=False
  )
  # The first input is the key; the rest are the current values.
  return any(used_inputs[1:])


def invalid_draw(values, bounds) -> jax.Array:
  """A bool scalar: some value breaks its binding's bound.

  One reduction over every value (of each dtype), against the bounds'
  limits laid out entry by entry (`attributes.Bound.limits`). Checked one
  value at a time, the check is a chain of elementwise work that XLA
  copies into every fusion that reads the flag on a CPU: the fall-back
  select of each leaf of the carry, and through it the forward pass's
  gathers of the model fields (walk's randomized reset: 60,433 HLO
  instructions against 34,676, docs/performance.md).
  """
  groups = {}
  for value, bound in zip(values, bounds):
    value = jnp.asarray(value)
    groups.setdefault(value.dtype, []).append((value, bound))
  invalid = jnp.zeros((), bool)
  for group in groups.values():
    flat = jnp.concatenate([jnp.ravel(value) for value, _ in group])
    limits = [bound.limits(value.shape) for value, bound in group]
    low, strict, high = (
        np.concatenate([np.ravel(part[k]) for part in limits]) for k in range(3)
    )
    ok = jnp.all(attributes.within(flat, low, strict, high))
    invalid = jnp.logical_or(invalid, jnp.logical_not(ok))
  return invalid


def _constant_value(variation):
  """The value of a constant (numbers, nested lists of them), else None."""
  if callable(variation) or isinstance(variation, base.Variation):
    return None
  try:
    value = np.asarray(variation, np.float64)
  except (TypeError, ValueError):
    return None
  return value


def _conform(value, initial: np.ndarray, binding: Binding, owner: str):
  """`value` as an array of the attribute's shape and dtype, or an error."""
  try:
    array = jnp.asarray(value, dtype=initial.dtype)
  except (TypeError, ValueError) as e:
    raise ValueError(
        f'{owner}: the variation bound to {binding.describe()} gave '
        f'{value!r}, which is not an array of numbers.'
    ) from e
  shape = np.shape(initial)
  if not _broadcasts(array.shape, shape):
    raise ValueError(
        f'{owner}: the variation bound to {binding.describe()} gives values '
        f'of shape {array.shape}, but the attribute has shape {shape}.'
    )
  return jnp.broadcast_to(array, shape)


def _broadcasts(source: tuple, target: tuple) -> bool:
  try:
    return np.broadcast_shapes(source, target) == tuple(target)
  except ValueError:
    return False


def check_static_shape(
    variation, initial: np.ndarray, describe: str, owner: str
):
  """Bind-time shape check when the attribute's value is known.

  Evaluates the shape of the variation's output abstractly (no sampling)
  with the attribute's value as initial and current value.
  """
  shape = np.shape(initial)

  def draw(key):
    value, _ = structures.sample(
        variation,
        structures.initial_state(variation, initial),
        key,
        initial,
        initial,
    )
    return jnp.asarray(value)

  try:
    out = jax.eval_shape(draw, jax.random.key(0))
  except (
      jax.errors.ConcretizationTypeError,
      jax.errors.TracerArrayConversionError,
      jax.errors.TracerBoolConversionError,
      jax.errors.TracerIntegerConversionError,
  ):
    # Needs concrete values (e.g. a numpy callable): the shape is checked
    # when reset is traced.
    return
  except (TypeError, ValueError) as e:
    raise ValueError(
        f'{owner}: the variation bound to {describe} cannot give a value for '
        f'an attribute of shape {shape}: {e}'
    ) from e
  if not _broadcasts(out.shape, shape):
    raise ValueError(
        f'{owner}: the variation bound to {describe} gives values of shape '
        f'{out.shape}, but the attribute has shape {shape}.'
    )
