"""`Physics`: one world's model, data and state, as hooks read and write it.

A `Physics` is a pytree (a `flax.struct` dataclass) that hooks, observables
and rewards receive instead of dm_control's stateful `mjcf.Physics`: reads
through `bind` and `named` (`bindings`), functional writes that return a new
`Physics`, the task's and entities' per-episode state, persistent entries,
scheduled hooks, and the trace-time records of writes that make a read stale
or that a read-only method must not make. The package's docstring shows how
it is used; `world_fields` holds what the runtime carries of it.
"""

from __future__ import annotations

from typing import Any

from flax import struct
import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np

from mjx_composer.model import element_index
from mjx_composer.physics import bindings
from mjx_composer.physics import world_fields as world_fields_lib


class ReadOnlyPhysicsError(TypeError):
  """A write to the physics handed to a method that only reads it (the
  task's outcome methods: `get_reward`, `get_discount`,
  `should_terminate_episode`, `get_metrics`), raised at trace time."""


@struct.dataclass
class Physics:
  """One world: its (possibly per-world) model, its data and its state.

  Attributes:
    model: the `mjx.Model`. Fields that no variation or hook changes are the
      environment's shared compiled constants.
    data: this world's `mjx.Data`.
    task_state: the task's per-episode state (`Task.initial_task_state`),
      e.g. a sampled target position.
    index: static tables resolving elements and names (see
      `element_index.ElementIndex`).
    persistent: per-world entries that survive episodes (auto-resets), keyed
      by their owner's name, e.g. a variator's `Sequence` counter. Entries
      are created in `initialize_episode` (`get_persistent`/`set_persistent`).
    initialization_failed: a bool scalar; an initializer that cannot
      initialize the episode sets it (`fail_initialization`) and the
      environment resamples the episode with a fresh key, up to
      `max_reset_attempts` times (composer's `EpisodeInitializationError`).
    entity_states: each entity's per-episode state (`Entity.initial_state`),
      keyed by the entity's full identifier (`entity_state(entity)`).
    scheduled_hooks: `(name, hook)` pairs registered with
      `schedule_before_step` (static).
    forward_stale_reads: whether a binding read of a quantity that a write
      made stale runs the forward-pass stage that computes it (True in the
      `initialize_episode` hooks) instead of raising `StaleReadError`
      (static).
    read_only: where the physics is read only, the method that received it
      (e.g. `'Task.get_reward'`), else `''` (static). Every write then
      raises `ReadOnlyPhysicsError` at trace time: the outcome methods
      (`get_reward`, `get_discount`, `should_terminate_episode`,
      `get_metrics`) return values, and a physics they wrote would be
      dropped. `forward()` and `kinematics()` stay allowed (they compute
      what a read needs).
  """

  model: mjx.Model
  data: mjx.Data
  task_state: Any = None
  index: element_index.ElementIndex = struct.field(
      pytree_node=False, default=None
  )
  persistent: Any = None
  initialization_failed: Any = None
  entity_states: Any = None
  scheduled_hooks: tuple = struct.field(pytree_node=False, default=())
  forward_stale_reads: bool = struct.field(pytree_node=False, default=False)
  read_only: str = struct.field(pytree_node=False, default='')

  @property
  def mj_model(self) -> mujoco.MjModel:
    """The compiled host model (shared by every world; read it at trace time)."""
    return self.index.mj_model

  def world_fields(self, model_fields) -> dict:
    """The `WorldFields` of this physics, as keyword arguments.

    Args:
      model_fields: names of the model fields that are per-world; the rest
        of the model is the shared constant that `WorldFields.restore`
        takes back.
    """
    return dict(
        data=self.data,
        task_state=self.task_state,
        entity_states=self.entity_states,
        model_fields={f: getattr(self.model, f) for f in model_fields},
        persistent=self.persistent,
        scheduled_hooks=self.scheduled_hooks,
    )

  def carry(self, model_fields) -> world_fields_lib.PhysicsCarry:
    """The per-world parts of this physics, for a scan or a loop.

    Args:
      model_fields: as in `world_fields`.
    """
    return world_fields_lib.PhysicsCarry(
        **self.world_fields(model_fields),
        initialization_failed=self.initialization_failed,
    )

  # -- dm_control-style accessors -------------------------------------------

  def bind(self, elements) -> 'bindings.Binding':
    """A view of one element (or a list of elements of one kind).

    An empty list binds nothing, as in dm_control: every attribute reads as
    an empty array of shape `(0,)`, and `set` changes nothing.
    """
    if isinstance(elements, (list, tuple)) and not elements:
      return bindings.EmptyBinding(self)
    kind, ids, is_seq = self.index.resolve(elements)
    return bindings.Binding(self, kind, tuple(ids), is_seq)

  @property
  def named(self) -> 'bindings.NamedAccess':
    """`physics.named.data.<field>[name]` and `physics.named.model....`."""
    return bindings.NamedAccess(self)

  def time(self) -> jax.Array:
    return self.data.time

  def timestep(self) -> jax.Array:
    return self.model.opt.timestep

  # -- functional updates ---------------------------------------------------

  def set_control(self, control) -> 'Physics':
    """Writes `ctrl` (MuJoCo clamps it to ctrlrange for limited actuators)."""
    control = jnp.asarray(control, dtype=self.data.ctrl.dtype)
    if control.shape != self.data.ctrl.shape:
      raise ValueError(
          f"Control of shape {control.shape} does not match the model's "
          f'{self.data.ctrl.shape[0]} actuators: pass an array of shape '
          f'{self.data.ctrl.shape}.'
      )
    return self._written(
        self.replace(data=self.data.replace(ctrl=control)), 'ctrl'
    )

  def forward(self) -> 'Physics':
    """Recomputes every derived quantity (`mjx.forward`).

    Like dm_control's, it clears composer's dirty flag (recorded for the
    runtime's analysis, `bindings.recording_dirty_events`).
    """
    bindings.record_dirty_event(bindings.FORWARD)
    return self.replace(data=mjx.forward(self.model, self.data))

  def kinematics(self) -> 'Physics':
    """Recomputes positions and orientations only (cheaper than forward)."""
    data = mjx.kinematics(self.model, self.data)
    return self.replace(data=mjx.com_pos(self.model, data))

  def step(self) -> 'Physics':
    """Advances one physics timestep (`mjx.step`)."""
    self._check_writable('step()')
    return self.replace(data=mjx.step(self.model, self.data))

  def update_task_state(self, **values) -> 'Physics':
    """Returns a copy with entries of the (dict) task state replaced."""
    return self._derived(
        self.replace(
            task_state=_updated(
                self.task_state, values, 'Task.initial_task_state()'
            )
        ),
        'update_task_state()',
    )

  def entity_state(self, entity):
    """`entity`'s per-episode state (declared by `Entity.initial_state`)."""
    return self.entity_states[_entity_key(entity, self.entity_states)]

  def update_entity_state(self, entity, **values) -> 'Physics':
    """Returns a copy with entries of `entity`'s (dict) state replaced."""
    key = _entity_key(entity, self.entity_states)
    new = dict(self.entity_states)
    new[key] = _updated(
        new[key], values, f'{type(entity).__name__}' '.initial_state()'
    )
    return self._derived(
        self.replace(entity_states=new), 'update_entity_state()'
    )

  # -- state that outlives an episode, and initialization failures ---------

  def get_persistent(self, name: str, default=None):
    """This world's persistent entry `name`, or `default` if never set.

    Persistent entries survive auto-resets, so they are the place for state
    that spans episodes (a `deterministic.Sequence` counter, a flag saying a
    once-per-world randomization was applied). `default` must have the
    entry's shape and dtype: on a world's first reset nothing is stored yet.
    """
    if self.persistent is not None and name in self.persistent:
      return self.persistent[name]
    return default

  def set_persistent(self, name: str, value) -> 'Physics':
    """Returns a copy with persistent entry `name` set to `value` (a pytree).

    Create entries in `initialize_episode`: the environment fixes the set of
    entries and their shapes at reset, and step hooks may only update them.
    """
    persistent = dict(self.persistent or {})
    persistent[name] = value
    return self._derived(
        self.replace(persistent=persistent), 'set_persistent()'
    )

  def schedule_before_step(self, name: str, hook) -> 'Physics':
    """Registers `hook(physics, key) -> physics` to run at every control step.

    Scheduled hooks run at the start of each `step`, before the task's
    `before_step`, for the rest of the world's life (they survive
    auto-resets with the persistent entries); each gets a key derived from
    `name`. This is how `variation.Schedule.every_steps(k)` registers its
    variator: call it from `initialize_episode`, at trace time. Registering
    the same `(name, hook)` again does nothing.

    Args:
      name: a name unique among scheduled hooks, stable across runs (e.g.
        the owner's persistent entry name).
      hook: a hashable callable, e.g. a bound method (part of the `State`'s
        static structure).
    """
    self._check_writable('schedule_before_step()')
    for known, known_hook in self.scheduled_hooks:
      if known == name:
        if known_hook != hook:
          raise ValueError(
              f'Another hook is already scheduled under the name {name!r}: '
              'give each scheduled hook its own name.'
          )
        return self
    return self.replace(scheduled_hooks=self.scheduled_hooks + ((name, hook),))

  def fail_initialization(self, failed=True) -> 'Physics':
    """Marks this episode's initialization as failed where `failed` is true.

    The jitted counterpart of raising `EpisodeInitializationError`: the
    environment resamples the episode (a fresh key for every
    `initialize_episode` hook) up to `max_reset_attempts` times and counts
    the failures in `metrics['init_failures']`.
    """
    previous = (
        jnp.zeros((), bool)
        if self.initialization_failed is None
        else self.initialization_failed
    )
    return self._derived(
        self.replace(
            initialization_failed=jnp.logical_or(
                previous, jnp.asarray(failed, bool)
            )
        ),
        'fail_initialization()',
    )

  # -- what bindings read and write -------------------------------------------

  def read(self, address: element_index.Address) -> jax.Array:
    """The value at `address`, in dm_control's shape (`FLAT_MATRIX_FIELDS`
    flat; `ON_DEMAND_FIELDS` computed from the data)."""
    if address.source == 'data':
      stage = bindings.stale_stage(
          self.unsynced_writes, address.field, address.index, self.mj_model
      )
      if stage and self.forward_stale_reads:
        return self._synced(address.field).read(address)
      if stage:
        bindings.check_fresh(
            self.unsynced_writes, address.field, address.index, self.mj_model
        )
    if (
        address.source == 'data'
        and self.batch_ndim
        and (address.field in bindings.ON_DEMAND_FIELDS)
    ):
      raise NotImplementedError(
          f'data.{address.field} is computed when read, one world at a time: '
          "read it from one world's physics (env.physics(state) of "
          'jax.tree.map(lambda x: x[i], state)), or inside jax.vmap.'
      )
    value = self.field(address.source, address.field)
    value = value[self._batched(address, value)]
    return bindings.flat(address.field, value)

  @property
  def batch_ndim(self) -> int:
    """How many leading batch axes this physics' data has (0: one world;
    `Environment.physics` of a batched state has them)."""
    return int(jnp.ndim(self.data.qpos)) - 1

  def _batched(self, address: element_index.Address, value) -> tuple:
    """`address.index` behind the batch axes `value` has: a data field has
    the data's; a model field has them only where it is per-world."""
    if address.source == 'data':
      batch = self.batch_ndim
    else:
      per_world = getattr(self.mj_model, address.field, None)
      batch = 0 if per_world is None else jnp.ndim(value) - np.ndim(per_world)
    return (slice(None),) * max(batch, 0) + (address.index,)

  def field(self, source: str, name: str) -> jax.Array:
    """The whole `source` ('data' or 'model') field `name`, in MJX's shape
    (`bindings.read_field`: fields MJX keeps in its implementation data,
    and `ON_DEMAND_FIELDS` computed from this data)."""
    return bindings.read_field(self.model, self.data, source, name)

  def write(self, address: element_index.Address, value) -> 'Physics':
    """A new `Physics` with `value` written at `address`."""
    bindings.check_writable(address.field)
    source = self.data if address.source == 'data' else self.model
    old = getattr(source, address.field)
    where = self._batched(address, old)
    target_shape = jax.eval_shape(lambda a: a[where], old).shape
    value = bindings.unflat(
        address.field, jnp.asarray(value, dtype=old.dtype), target_shape
    )
    new = old.at[where].set(value)
    if address.source == 'data':
      return self._written(
          self.replace(data=self.data.replace(**{address.field: new})),
          address.field,
      )
    new = self._derived(
        self.replace(model=self.model.replace(**{address.field: new})),
        f'a write of {address.field}',
    )
    if bindings.marks_stale('model', address.field):
      new = new.mark_written(address.field)
    return new

  # -- writes a hook must keep, and reads a write makes stale ---------------
  #
  # Two trace-time records kept beside the pytree (plain attributes, not
  # fields: a `jax.tree` round trip drops them, which can only silence a
  # check, never raise a false one):
  #
  # * `_wrote_result`: a write was called on this very object, so its
  #   result was a new `Physics` (`wrote_to_result`; the hooks' runner
  #   refuses a hook that returns the object it received after that).
  # * `_unsynced`: the fields written (`bindings.marks_stale`: the
  #   `STATE_INPUT_FIELDS` and the non-visual model fields) since the data
  #   was last replaced by anything but such a write (a forward pass, a
  #   step, the environment's reset forward); `read` refuses derived fields
  #   then, or computes them (`forward_stale_reads`, `_synced`).
  # * `_synced_cache`: the forward passes `_synced` ran on this object.

  def _derived(self, new: 'Physics', what: str = 'a write') -> 'Physics':
    self._check_writable(what)
    object.__setattr__(self, '_wrote_result', True)
    object.__setattr__(new, '_unsynced', self.unsynced_writes)
    return new

  def _written(self, new: 'Physics', field: str) -> 'Physics':
    new = self._derived(new, f'a write of {field}')
    if field in bindings.STATE_INPUT_FIELDS:
      object.__setattr__(new, '_unsynced', self.unsynced_writes | {field})
    return new

  def mark_written(self, *fields: str) -> 'Physics':
    """This physics, its derived quantities recorded as stale from `fields`.

    A binding read of a quantity derived from them then refuses, or runs
    the forward pass (`forward_stale_reads`). The environment marks what a
    reset writes and recomputes only in part (it computes positions, not
    the velocities' and sensors' stages), and `Physics.write` marks the
    model fields it writes.
    """
    self._check_writable(f'mark_written{fields}')
    new = self.replace()
    object.__setattr__(new, '_unsynced', self.unsynced_writes | set(fields))
    return new

  @property
  def unsynced_writes(self) -> frozenset:
    """The fields written through bindings (or `set_control`; the
    `STATE_INPUT_FIELDS` and the non-visual model fields) since this
    physics' derived quantities were last computed."""
    return getattr(self, '_unsynced', frozenset())

  def _synced(self, field: str) -> 'Physics':
    """This physics with `field` recomputed by the cheapest of
    `kinematics()` and `forward()` that computes it, run once per object
    (its reads share it)."""
    stage = 'kinematics' if field in bindings.KINEMATICS_FIELDS else 'forward'
    cache = getattr(self, '_synced_cache', None)
    if cache is None:
      cache = {}
      object.__setattr__(self, '_synced_cache', cache)
    if stage not in cache:
      cache[stage] = getattr(self, stage)()
    return cache[stage]

  def reading_only(self, method: str) -> 'Physics':
    """This physics, every write refused (`read_only`) with a message
    naming `method` (e.g. `'MyTask.get_reward'`); its record of stale
    reads is kept."""
    new = self.replace(read_only=method)
    object.__setattr__(new, '_unsynced', self.unsynced_writes)
    return new

  def _check_writable(self, what: str = 'a write') -> None:
    """Raises `ReadOnlyPhysicsError` where this physics is `read_only`."""
    if self.read_only:
      raise ReadOnlyPhysicsError(
          f'{self.read_only} received a read-only physics and called '
          f'{what} on it: {self.read_only} returns a value, and the physics '
          'a write returns there would be dropped. Move the write (a step '
          'counter, task or entity state, persistent entries, bindings) '
          "to the task's after_step hook (it runs after the control step's "
          'physics and before the outcome methods, and returns the '
          'physics), and read the written value here.'
      )

  def wrote_to_result(self) -> bool:
    """Whether a write method (a binding's `set`, `set_control`,
    `update_task_state`, ...) was called on this very object: its change
    lives only in the `Physics` that call returned."""
    return getattr(self, '_wrote_result', False)

  def forget_writes(self) -> None:
    """Clears `wrote_to_result` (the hooks' runner, before each hook)."""
    object.__setattr__(self, '_wrote_result', False)


def _entity_key(entity, entity_states) -> str:
  key = entity.full_identifier
  if entity_states is None or key not in entity_states:
    raise KeyError(
        f'{type(entity).__name__} {entity.name!r} has no per-episode state: '
        'declare it by overriding Entity.initial_state() (and attach the '
        'entity before building the Environment).'
    )
  return key


def _updated(state, values: dict, declared_in: str) -> dict:
  """`state` (a dict) with `values` written, keeping shapes and dtypes."""
  if not isinstance(state, dict):
    raise TypeError(f'Updating entries needs a dict state from {declared_in}.')
  unknown = set(values) - set(state)
  if unknown:
    raise KeyError(
        f'Unknown state entries {sorted(unknown)}; declare them in '
        f'{declared_in}.'
    )
  new = dict(state)
  for k, v in values.items():
    old = new[k]
    new[k] = jnp.asarray(v, dtype=jnp.asarray(old).dtype).reshape(
        jnp.shape(old)
    )
  return new
