"""`Physics`: one world's model, data and task state, with dm_control-style access.

A `Physics` is a pytree (a `flax.struct` dataclass) that hooks, observables and
rewards receive instead of dm_control's stateful `mjcf.Physics`. Reads look like
dm_control::

    physics.bind(hand_site).xpos              # (3,)
    physics.bind([j1, j2]).qpos               # (2,)
    physics.named.data.qpos['arm/shoulder']   # (1,)
    physics.named.model.body_mass[['arm/upper', 'arm/lower']]

and writes are functional: they return a new `Physics`::

    physics = physics.bind(joint).set(qpos=0.3)
    physics = physics.named.data.set('qvel', 'arm/shoulder', 0.0)

Elements are MjSpec handles (`mujoco.MjsBody`, `MjsGeom`, `MjsSite`, `MjsJoint`,
`MjsActuator`, `MjsSensor`, `MjsTendon`, `MjsCamera`, `MjsLight`, `MjsEquality`)
taken from an entity's own spec, or fully qualified names. They are resolved to
static integer indices while tracing, through the `ElementIndex` built once when
the environment compiles; nothing on the device looks a name up.

Shapes are dm_control's: `physics.bind(...)` and `physics.named` give the
rotation matrices `xmat`, `ximat`, `geom_xmat`, `site_xmat` and `cam_xmat` as
flat 9-vectors (`(9,)` for one element, `(n, 9)` for a list), as
`dm_control.mujoco.Physics.bind` does; `physics.data` is the raw `mjx.Data`,
whose matrices are `(n, 3, 3)`.

Fields that MJX computes only when a sensor needs them (`subtree_linvel`,
`subtree_angmom`: `mjx.subtree_vel`; `cacc`, `cfrc_int`, `cfrc_ext`:
`mjx.rne_postconstraint`) are computed from the data when read through a
binding, so they hold what MuJoCo's `mj_forward` followed by
`mj_subtreeVel` / `mj_rnePostConstraint` gives on the same state.

Unlike dm_control there is no lazy "dirty" forward: after writing positions or
velocities (`qpos`, `qvel`, `act`, `ctrl`, `qfrc_applied`, `xfrc_applied`),
call `physics.forward()` (or `physics.kinematics()`) before reading derived
quantities such as `xpos`. A binding read of a derived quantity after such a
write, with no forward pass between, raises at trace time (`StaleReadError`)
where dm_control would have run `mj_forward` first.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from flax import struct
import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np

from mjx_composer.model import element_index
from mjx_composer.platform import internals

_MODEL_FIELD_NAMES = tuple(f.name for f in dataclasses.fields(mjx.Model))

# Rotation matrices MJX keeps as `(n, 3, 3)` and MuJoCo's `mjData` (so
# dm_control's bindings) as `(n, 9)`: bindings give and take them flat.
FLAT_MATRIX_FIELDS = frozenset(
    {'xmat', 'ximat', 'geom_xmat', 'site_xmat', 'cam_xmat'}
)
# `mjData` fields that MJX keeps in its implementation data (`data._impl`),
# computed by every forward pass.
_IMPL_FIELDS = frozenset({'cinert', 'crb', 'actuator_velocity', 'ten_velocity'})
# `mjData` fields that MJX computes only where a sensor needs them, and the
# public MJX function that computes them from a forwarded `mjx.Data` (what
# MuJoCo's `mj_subtreeVel` / `mj_rnePostConstraint` compute).
ON_DEMAND_FIELDS = {
    'subtree_linvel': mjx.subtree_vel,
    'subtree_angmom': mjx.subtree_vel,
    'cacc': mjx.rne_postconstraint,
    'cfrc_int': mjx.rne_postconstraint,
    'cfrc_ext': mjx.rne_postconstraint,
}
# What dm_control's bindings mark dirty when written (its
# `MJDATA_TRIGGERS_DIRTY`): its next read of anything else runs `mj_forward`.
STATE_INPUT_FIELDS = frozenset(
    {'qpos', 'qvel', 'act', 'ctrl', 'qfrc_applied', 'xfrc_applied'}
)
# Data fields no forward pass computes: a binding reads them as they are.
_NOT_DERIVED = STATE_INPUT_FIELDS | {
    'time',
    'mocap_pos',
    'mocap_quat',
    'eq_active',
    'qacc_warmstart',
    'userdata',
    'plugin_state',
    'history',
}
# The stage of MuJoCo's forward pass that computes each derived field a
# binding can read (1 position, 2 velocity; every other derived field 3,
# acceleration), as `mjModel.sensor_needstage` numbers them.
_FIELD_STAGE = {
    **dict.fromkeys(
        (
            'xpos', 'xquat', 'xmat', 'xipos', 'ximat', 'xanchor', 'xaxis',
            'geom_xpos', 'geom_xmat', 'site_xpos', 'site_xmat', 'cam_xpos',
            'cam_xmat', 'subtree_com', 'cinert', 'crb', 'cdof', 'ten_length',
            'actuator_length', 'qfrc_gravcomp',
        ),
        1,
    ),
    **dict.fromkeys(
        (
            'cvel', 'cdof_dot', 'ten_velocity', 'actuator_velocity',
            'subtree_linvel', 'subtree_angmom', 'qfrc_bias', 'qfrc_passive',
            'qfrc_fluid',
        ),
        2,
    ),
}  # fmt: skip
# The first stage that a write of each input makes stale: positions change
# everything, velocities the velocity and acceleration stages, the rest
# (controls, activations, applied forces) the acceleration stage only.
_INPUT_STAGE = {'qpos': 1, 'qvel': 2}


class StaleReadError(ValueError):
  """A binding read a derived quantity after a write with no forward pass.

  dm_control's bindings run `mj_forward` lazily before such a read; here
  the hook must call `physics.forward()` (or `physics.kinematics()`) itself.
  """


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

  def carry(self, model_fields) -> 'PhysicsCarry':
    """The per-world parts of this physics, for a scan or a loop.

    Args:
      model_fields: as in `world_fields`.
    """
    return PhysicsCarry(
        **self.world_fields(model_fields),
        initialization_failed=self.initialization_failed,
    )

  # -- dm_control-style accessors -------------------------------------------

  def bind(self, elements) -> 'Binding':
    """A view of one element (or a list of elements of one kind).

    An empty list binds nothing, as in dm_control: every attribute reads as
    an empty array of shape `(0,)`, and `set` changes nothing.
    """
    if isinstance(elements, (list, tuple)) and not elements:
      return EmptyBinding(self)
    kind, ids, is_seq = self.index.resolve(elements)
    return Binding(self, kind, tuple(ids), is_seq)

  @property
  def named(self) -> '_NamedAccess':
    """`physics.named.data.<field>[name]` and `physics.named.model....`."""
    return _NamedAccess(self)

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
    """Recomputes every derived quantity (`mjx.forward`)."""
    return self.replace(data=mjx.forward(self.model, self.data))

  def kinematics(self) -> 'Physics':
    """Recomputes positions and orientations only (cheaper than forward)."""
    data = mjx.kinematics(self.model, self.data)
    return self.replace(data=mjx.com_pos(self.model, data))

  def step(self) -> 'Physics':
    """Advances one physics timestep (`mjx.step`)."""
    return self.replace(data=mjx.step(self.model, self.data))

  def update_task_state(self, **values) -> 'Physics':
    """Returns a copy with entries of the (dict) task state replaced."""
    return self._derived(
        self.replace(
            task_state=_updated(
                self.task_state, values, 'Task.initial_task_state()'
            )
        )
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
    return self._derived(self.replace(entity_states=new))

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
    return self._derived(self.replace(persistent=persistent))

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
        )
    )

  # -- what bindings read and write -------------------------------------------

  def read(self, address: element_index.Address) -> jax.Array:
    """The value at `address`, in dm_control's shape (`FLAT_MATRIX_FIELDS`
    flat; `ON_DEMAND_FIELDS` computed from the data)."""
    if address.source == 'data':
      self._check_fresh(address.field, address.index)
    value = self.field(address.source, address.field)[address.index]
    if address.field in FLAT_MATRIX_FIELDS:
      value = value.reshape(value.shape[:-2] + (9,))
    return value

  def field(self, source: str, name: str) -> jax.Array:
    """The whole `source` ('data' or 'model') field `name`, in MJX's shape.

    Reads fields that MJX keeps in its implementation data, and computes
    `ON_DEMAND_FIELDS` (`mjx.subtree_vel`, `mjx.rne_postconstraint` on this
    data: what MuJoCo's `mj_subtreeVel` / `mj_rnePostConstraint` give).
    """
    if source == 'model':
      return getattr(self.model, name)
    if name in ON_DEMAND_FIELDS or name in _IMPL_FIELDS:
      if self.data.impl == mjx.Impl.WARP:
        raise NotImplementedError(
            f'data.{name} cannot be read on MuJoCo Warp '
            "(ExecutionOptions(impl='warp')): MJX keeps it only in its "
            "JAX implementation's data. Use impl='jax', or a sensor that "
            'measures it (e.g. a subtreelinvel sensor for subtree_linvel).'
        )
      data = self.data
      if name in ON_DEMAND_FIELDS:
        data = ON_DEMAND_FIELDS[name](self.model, data)
      return getattr(internals.data_impl(data), name)
    return getattr(self.data, name)

  def write(self, address: element_index.Address, value) -> 'Physics':
    """A new `Physics` with `value` written at `address`."""
    if address.field in ON_DEMAND_FIELDS or address.field in _IMPL_FIELDS:
      raise AttributeError(
          f'data.{address.field} is computed by the forward pass and cannot '
          'be written.'
      )
    source = self.data if address.source == 'data' else self.model
    old = getattr(source, address.field)
    target_shape = jax.eval_shape(lambda a: a[address.index], old).shape
    value = jnp.asarray(value, dtype=old.dtype)
    if address.field in FLAT_MATRIX_FIELDS:
      flat = target_shape[:-2] + (9,)
      value = jnp.broadcast_to(
          value.reshape(value.shape[:-2] + (9,))
          if value.shape[-2:] == (3, 3)
          else value,
          flat,
      )
      value = value.reshape(target_shape)
    value = jnp.broadcast_to(value, target_shape)
    new = old.at[address.index].set(value)
    if address.source == 'data':
      return self._written(
          self.replace(data=self.data.replace(**{address.field: new})),
          address.field,
      )
    return self._derived(
        self.replace(model=self.model.replace(**{address.field: new}))
    )

  # -- writes a hook must keep, and reads a write makes stale ---------------
  #
  # Two trace-time records kept beside the pytree (plain attributes, not
  # fields: a `jax.tree` round trip drops them, which can only silence a
  # check, never raise a false one):
  #
  # * `_wrote_result`: a write was called on this very object, so its
  #   result was a new `Physics` (`wrote_to_result`; the hooks' runner
  #   refuses a hook that returns the object it received after that).
  # * `_unsynced`: the `STATE_INPUT_FIELDS` written since the data was last
  #   replaced by anything but such a write (a forward pass, a step, the
  #   environment's reset forward); `read` refuses derived fields then.

  def _derived(self, new: 'Physics') -> 'Physics':
    object.__setattr__(self, '_wrote_result', True)
    object.__setattr__(new, '_unsynced', self.unsynced_writes)
    return new

  def _written(self, new: 'Physics', field: str) -> 'Physics':
    new = self._derived(new)
    if field in STATE_INPUT_FIELDS:
      object.__setattr__(new, '_unsynced', self.unsynced_writes | {field})
    return new

  @property
  def unsynced_writes(self) -> frozenset:
    """The `STATE_INPUT_FIELDS` written through bindings (or `set_control`)
    since this physics' derived quantities were last computed."""
    return getattr(self, '_unsynced', frozenset())

  def wrote_to_result(self) -> bool:
    """Whether a write method (a binding's `set`, `set_control`,
    `update_task_state`, ...) was called on this very object: its change
    lives only in the `Physics` that call returned."""
    return getattr(self, '_wrote_result', False)

  def forget_writes(self) -> None:
    """Clears `wrote_to_result` (the hooks' runner, before each hook)."""
    object.__setattr__(self, '_wrote_result', False)

  def _check_fresh(self, field: str, index):
    unsynced = self.unsynced_writes
    if not unsynced or field in _NOT_DERIVED:
      return
    stale_from = min(_INPUT_STAGE.get(name, 3) for name in unsynced)
    if field == 'sensordata':
      stage = _sensor_stage(self.index.mj_model, index)
    else:
      stage = _FIELD_STAGE.get(field, 3)
    if stage >= stale_from:
      raise StaleReadError(
          f'This physics wrote {sorted(unsynced)} and then read {field!r}, '
          'which is derived from them, with no forward pass between: it '
          'would read the value from before the write. dm_control runs '
          'mj_forward before such a read; here call `physics = '
          'physics.forward()` (or `physics.kinematics()` for positions '
          'only) after the write and read from the result.'
      )


def changed_model_fields(before: mjx.Model, after: mjx.Model) -> list[str]:
  """The fields of `after` that are not `before`'s (by identity).

  A hook that writes a model field returns a model whose field is a new
  array; the fields it leaves alone are the same objects. So this tells,
  while tracing, which fields a hook wrote.
  """
  return [
      name
      for name in _MODEL_FIELD_NAMES
      if getattr(after, name) is not getattr(before, name)
  ]


@struct.dataclass
class WorldFields:
  """What one world carries of its `Physics`: everything but the shared
  model constants and the static index tables.

  `runtime.state.State` (carried between steps) and `PhysicsCarry` (carried
  through a loop) extend it; `Physics.world_fields` makes its fields and
  `restore` takes them back. Its leaves come first in both, in this order.

  Attributes:
    data: the world's `mjx.Data`.
    task_state: the task's per-episode state (`Task.initial_task_state`).
    entity_states: each entity's per-episode state (`Entity.initial_state`),
      keyed by the entity's full identifier ('' for the root entity).
    model_fields: per-world values of the model fields that hooks or
      variations write (`{field name: value}`); every other model field is
      the environment's shared constant.
    persistent: per-world entries that survive auto-resets
      (`Physics.get_persistent`), keyed by their owner's name.
    scheduled_hooks: hooks registered by `Physics.schedule_before_step`
      (static: part of the pytree's structure, not of its leaves).
  """

  data: mjx.Data
  task_state: Any
  entity_states: Any
  model_fields: dict
  persistent: Any
  scheduled_hooks: tuple = struct.field(
      pytree_node=False, default=(), kw_only=True
  )

  def restore(
      self, model: mjx.Model, index: element_index.ElementIndex
  ) -> Physics:
    """The `Physics` with these parts over the shared `model`."""
    if self.model_fields:
      model = model.replace(**self.model_fields)
    return Physics(
        model=model,
        data=self.data,
        task_state=self.task_state,
        index=index,
        persistent=self.persistent,
        initialization_failed=self._initialization_failed(),
        entity_states=self.entity_states,
        scheduled_hooks=self.scheduled_hooks,
    )

  def _initialization_failed(self):
    return None


@struct.dataclass
class PhysicsCarry(WorldFields):
  """The per-world parts of a `Physics`, and whether its initialization
  failed: what a `lax.scan` over sub-steps or a reset's retry loop carries.
  Made by `Physics.carry`; `restore` rebuilds the `Physics`.
  """

  initialization_failed: Any

  def _initialization_failed(self):
    return self.initialization_failed


def _sensor_stage(mj_model, index) -> int:
  """The last forward-pass stage that `sensordata[index]` needs (1-3)."""
  rows = np.arange(mj_model.nsensordata)[index].reshape(-1)
  if not rows.size:
    return 1
  # The sensor of each row: the last sensor starting at or before it.
  sensors = np.searchsorted(mj_model.sensor_adr, rows, side='right') - 1
  return int(np.max(mj_model.sensor_needstage[sensors]))


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


class Binding:
  """Attribute access for bound elements, like dm_control's `physics.bind`."""

  __slots__ = ('_physics', '_kind', '_ids', '_is_seq')

  def __init__(
      self, physics: Physics, kind: element_index.Kind, ids: tuple, is_seq: bool
  ):
    self._physics = physics
    self._kind = kind
    self._ids = ids
    self._is_seq = is_seq

  def _address(self, attr: str) -> element_index.Address:
    return self._physics.index.address(
        self._kind, attr, self._ids, self._is_seq
    )

  def __getattr__(self, attr: str) -> jax.Array:
    if attr.startswith('_'):
      raise AttributeError(attr)
    return self._physics.read(self._address(attr))

  def __setattr__(self, attr, value):
    if attr in Binding.__slots__:
      object.__setattr__(self, attr, value)
      return
    raise AttributeError(
        'Physics is immutable: use `physics = physics.bind(el).set('
        f'{attr}=value)` instead of assigning to a binding.'
    )

  @property
  def element_ids(self) -> tuple:
    """The compiled ids of the bound elements."""
    return self._ids

  def set(self, **values) -> Physics:
    """Returns a new Physics with the given attributes written."""
    physics = self._physics
    for attr, value in values.items():
      physics = physics.write(self._address(attr), value)
    return physics


class EmptyBinding:
  """The binding of an empty list of elements (dm_control's `_EmptyBinding`).

  Every attribute reads as an empty float array of shape `(0,)`; `set`
  returns the physics unchanged.
  """

  __slots__ = ('_physics',)

  def __init__(self, physics: Physics):
    object.__setattr__(self, '_physics', physics)

  def __getattr__(self, attr: str) -> jax.Array:
    if attr.startswith('_'):
      raise AttributeError(attr)
    return jnp.zeros((0,), self._physics.data.qpos.dtype)

  def __setattr__(self, attr, value):
    raise AttributeError(
        'Physics is immutable: use `physics = physics.bind(el).set('
        f'{attr}=value)` instead of assigning to a binding.'
    )

  @property
  def element_ids(self) -> tuple:
    return ()

  def set(self, **values) -> Physics:
    del values
    return self._physics


class _NamedAccess:
  """`physics.named.data` / `physics.named.model`."""

  def __init__(self, physics: Physics):
    self.data = _NamedSource(physics, 'data')
    self.model = _NamedSource(physics, 'model')


class _NamedSource:

  def __init__(self, physics: Physics, source: str):
    self._physics = physics
    self._source = source

  def __getattr__(self, field: str) -> '_NamedField':
    if field.startswith('_'):
      raise AttributeError(field)
    return _NamedField(self._physics, self._source, field)

  def set(self, field: str, key, value) -> Physics:
    """Returns a new Physics with `<source>.<field>[key] = value`."""
    address = self._physics.index.named_address(self._source, field, key)
    return self._physics.write(address, value)


class _NamedField:

  def __init__(self, physics: Physics, source: str, field: str):
    self._physics = physics
    self._source = source
    self._field = field

  def __getitem__(self, key) -> jax.Array:
    address = self._physics.index.named_address(self._source, self._field, key)
    return self._physics.read(address)

  def __array__(self, dtype=None):
    value = np.asarray(
        self._physics.field(self._source, self._field), dtype=dtype
    )
    if self._field in FLAT_MATRIX_FIELDS:
      value = value.reshape(value.shape[:-2] + (9,))
    return value
