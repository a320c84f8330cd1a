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

Unlike dm_control there is no lazy "dirty" forward: after writing positions or
velocities, call `physics.forward()` (or `physics.kinematics()`) before reading
derived quantities such as `xpos`.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Iterable, Sequence

from flax import struct
import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np


@dataclasses.dataclass(frozen=True)
class _Kind:
  """How one MuJoCo object type is laid out in `mjModel`/`mjData`."""

  name: str  # e.g. 'joint'
  obj: Any  # mujoco.mjtObj value
  prefix: str  # model field prefix, e.g. 'jnt'
  count: str  # model size attribute, e.g. 'njnt'


_KINDS = {
    mujoco.MjsBody: _Kind('body', mujoco.mjtObj.mjOBJ_BODY, 'body', 'nbody'),
    mujoco.MjsGeom: _Kind('geom', mujoco.mjtObj.mjOBJ_GEOM, 'geom', 'ngeom'),
    mujoco.MjsSite: _Kind('site', mujoco.mjtObj.mjOBJ_SITE, 'site', 'nsite'),
    mujoco.MjsJoint: _Kind('joint', mujoco.mjtObj.mjOBJ_JOINT, 'jnt', 'njnt'),
    mujoco.MjsActuator: _Kind(
        'actuator', mujoco.mjtObj.mjOBJ_ACTUATOR, 'actuator', 'nu'
    ),
    mujoco.MjsSensor: _Kind(
        'sensor', mujoco.mjtObj.mjOBJ_SENSOR, 'sensor', 'nsensor'
    ),
    mujoco.MjsTendon: _Kind(
        'tendon', mujoco.mjtObj.mjOBJ_TENDON, 'tendon', 'ntendon'
    ),
    mujoco.MjsCamera: _Kind(
        'camera', mujoco.mjtObj.mjOBJ_CAMERA, 'cam', 'ncam'
    ),
    mujoco.MjsLight: _Kind(
        'light', mujoco.mjtObj.mjOBJ_LIGHT, 'light', 'nlight'
    ),
    mujoco.MjsEquality: _Kind(
        'equality', mujoco.mjtObj.mjOBJ_EQUALITY, 'eq', 'neq'
    ),
}
KINDS_BY_NAME = {kind.name: kind for kind in _KINDS.values()}
# The MjSpec list attribute that holds each kind's elements, in order.
SPEC_LISTS = {
    'body': 'bodies',
    'geom': 'geoms',
    'site': 'sites',
    'joint': 'joints',
    'actuator': 'actuators',
    'sensor': 'sensors',
    'tendon': 'tendons',
    'camera': 'cameras',
    'light': 'lights',
    'equality': 'equalities',
}

# Data fields indexed per element of a kind (first axis = element id).
_DATA_PER_ELEMENT = {
    'body': (
        'xpos',
        'xquat',
        'xmat',
        'xipos',
        'ximat',
        'subtree_com',
        'cvel',
        'xfrc_applied',
    ),
    'joint': ('xanchor', 'xaxis'),
    'geom': ('geom_xpos', 'geom_xmat'),
    'site': ('site_xpos', 'site_xmat'),
    'camera': ('cam_xpos', 'cam_xmat'),
    'actuator': ('ctrl', 'actuator_force', 'actuator_length'),
    'tendon': ('ten_length',),
    'equality': ('eq_active',),
}
# Joint fields addressed through `jnt_qposadr` (width 7/4/1/1 by joint type).
_QPOS_FIELDS = {'data': ('qpos',), 'model': ('qpos0', 'qpos_spring')}
# Joint fields addressed through `jnt_dofadr` (width 6/3/1/1 by joint type).
_DOF_DATA_FIELDS = (
    'qvel',
    'qacc',
    'qacc_warmstart',
    'qfrc_applied',
    'qfrc_bias',
    'qfrc_passive',
    'qfrc_actuator',
    'qfrc_smooth',
    'qacc_smooth',
    'qfrc_constraint',
    'qfrc_inverse',
    'qfrc_gravcomp',
    'qfrc_fluid',
)
_QPOS_WIDTH = {0: 7, 1: 4, 2: 1, 3: 1}  # mjtJoint: free, ball, slide, hinge
_DOF_WIDTH = {0: 6, 1: 3, 2: 1, 3: 1}
# Data fields whose short binding name differs from the data field name.
_DATA_ALIASES = {'tendon': {'length': 'ten_length'}}


def element_kind(element) -> _Kind:
  """The `_Kind` of an MjSpec element handle, or a clear TypeError."""
  for cls, kind in _KINDS.items():
    if isinstance(element, cls):
      return kind
  raise TypeError(
      f'Cannot bind {element!r}: expected an MjSpec element handle '
      f'({", ".join(c.__name__ for c in _KINDS)}).'
  )


@dataclasses.dataclass(frozen=True)
class _Address:
  """Where an attribute of some elements lives: `source.field[index]`."""

  source: str  # 'data' or 'model'
  field: str
  index: Any  # int, slice or np.ndarray of ints (static)


class ElementIndex:
  """Static tables that resolve elements and names to compiled indices.

  Built once on the host by `Environment` from the compiled `mujoco.MjModel`
  and the map from each entity's own element handles to their fully qualified
  names. It is carried in `Physics` as static (non-pytree) data, so resolution
  happens at trace time.
  """

  def __init__(self, model: mujoco.MjModel, handle_names: dict[int, tuple]):
    """Args:
    model: the compiled host model.
    handle_names: `id(handle) -> (handle, kind name, full name)` for every
      element of every entity in the composed tree. The handle is kept so
      that its `id` stays unique for the life of this index.
    """
    self.model = model
    self._handles = handle_names
    self._jnt_type = np.asarray(model.jnt_type)
    self._jnt_qposadr = np.asarray(model.jnt_qposadr)
    self._jnt_dofadr = np.asarray(model.jnt_dofadr)
    self._sensor_adr = np.asarray(model.sensor_adr)
    self._sensor_dim = np.asarray(model.sensor_dim)
    self._actuator_actadr = np.asarray(model.actuator_actadr)
    self._actuator_actnum = np.asarray(model.actuator_actnum)

  # -- element resolution ---------------------------------------------------

  def full_name(self, element) -> str:
    """Fully qualified compiled name of an element handle."""
    entry = self._handles.get(id(element))
    if entry is None or entry[0] is not element:
      raise ValueError(
          f'Element {_describe(element)} is not part of the compiled model: '
          "it does not belong to any entity attached to the task's root "
          'entity (attach its entity before building the Environment).'
      )
    return entry[2]

  def element_id(self, kind: _Kind, element) -> int:
    """Compiled id of an element handle or a fully qualified name."""
    if isinstance(element, str):
      name = element
    else:
      if element_kind(element) is not kind:
        raise TypeError(f'Expected a {kind.name}, got {_describe(element)}.')
      name = self.full_name(element)
    idx = mujoco.mj_name2id(self.model, kind.obj, name)
    if idx < 0:
      known = [
          mujoco.mj_id2name(self.model, kind.obj, i)
          for i in range(getattr(self.model, kind.count))
      ]
      raise KeyError(
          f'No {kind.name} named {name!r} in the compiled model. '
          f'Known {kind.name}s: {[k for k in known if k]}'
      )
    return idx

  def resolve(self, elements) -> tuple[_Kind, list[int], bool]:
    """Returns (kind, ids, is_sequence) for an element or a list of them."""
    is_seq = isinstance(elements, (list, tuple))
    items = list(elements) if is_seq else [elements]
    if not items:
      raise ValueError('Cannot bind an empty list of elements.')
    kinds = {element_kind(e) for e in items}
    if len(kinds) != 1:
      raise TypeError(
          'All elements bound together must be of one kind; got '
          f'{sorted(k.name for k in kinds)}.'
      )
    kind = kinds.pop()
    return kind, [self.element_id(kind, e) for e in items], is_seq

  # -- attribute addressing -------------------------------------------------

  def address(
      self, kind: _Kind, attr: str, ids: Sequence[int], is_seq: bool
  ) -> _Address:
    """Where `attr` of the elements `ids` lives, as a static index."""
    if kind.name == 'joint':
      if attr in _QPOS_FIELDS['data'] or attr in _QPOS_FIELDS['model']:
        source = 'data' if attr in _QPOS_FIELDS['data'] else 'model'
        return _Address(
            source,
            attr,
            self._ranges(
                self._jnt_qposadr,
                [_QPOS_WIDTH[int(self._jnt_type[i])] for i in ids],
                ids,
            ),
        )
      dof_field = attr if attr in _DOF_DATA_FIELDS else None
      source = 'data'
      if dof_field is None and hasattr_model(f'dof_{attr}'):
        dof_field, source = f'dof_{attr}', 'model'
      if dof_field is not None:
        return _Address(
            source,
            dof_field,
            self._ranges(
                self._jnt_dofadr,
                [_DOF_WIDTH[int(self._jnt_type[i])] for i in ids],
                ids,
            ),
        )
    if kind.name == 'sensor' and attr == 'sensordata':
      return _Address(
          'data',
          'sensordata',
          self._ranges(
              self._sensor_adr, [int(self._sensor_dim[i]) for i in ids], ids
          ),
      )
    if kind.name == 'actuator' and attr == 'act':
      return _Address(
          'data',
          'act',
          self._ranges(
              self._actuator_actadr,
              [int(self._actuator_actnum[i]) for i in ids],
              ids,
          ),
      )
    index = _element_index(ids, is_seq)
    alias = _DATA_ALIASES.get(kind.name, {}).get(attr)
    per_element = _DATA_PER_ELEMENT.get(kind.name, ())
    for candidate in (alias, f'{kind.prefix}_{attr}', attr):
      if candidate in per_element:
        return _Address('data', candidate, index)
    if hasattr_model(f'{kind.prefix}_{attr}'):
      return _Address('model', f'{kind.prefix}_{attr}', index)
    if kind.name == 'body' and attr in ('mocap_pos', 'mocap_quat'):
      mocap = np.asarray(self.model.body_mocapid)[list(ids)]
      if np.any(mocap < 0):
        raise ValueError('Only mocap bodies have mocap_pos/mocap_quat.')
      return _Address('data', attr, _element_index(mocap.tolist(), is_seq))
    raise AttributeError(
        f'A {kind.name} has no attribute {attr!r}. Valid attributes: '
        f'{sorted(self.valid_attributes(kind))}.'
    )

  def valid_attributes(self, kind: _Kind) -> set[str]:
    names = set(_DATA_PER_ELEMENT.get(kind.name, ()))
    names |= {
        f[len(kind.prefix) + 1 :]
        for f in _MODEL_FIELDS
        if f.startswith(kind.prefix + '_')
    }
    if kind.name == 'joint':
      names |= set(_QPOS_FIELDS['data'] + _QPOS_FIELDS['model'])
      names |= set(_DOF_DATA_FIELDS)
      names |= {f[4:] for f in _MODEL_FIELDS if f.startswith('dof_')}
    if kind.name == 'sensor':
      names.add('sensordata')
    if kind.name == 'actuator':
      names.add('act')
    return names

  def named_address(self, source: str, field: str, key) -> _Address:
    """Address of `source.field[key]` where key is a name, names or index."""
    if isinstance(key, (int, np.integer, slice)) or (
        isinstance(key, (list, tuple, np.ndarray))
        and len(key)
        and all(isinstance(k, (int, np.integer)) for k in key)
    ):
      return _Address(
          source,
          field,
          key if not isinstance(key, (list, tuple)) else np.asarray(key),
      )
    kind, attr = self._kind_of_field(source, field)
    names = list(key) if isinstance(key, (list, tuple)) else [key]
    ids = [self.element_id(kind, n) for n in names]
    address = self.address(kind, attr, ids, isinstance(key, (list, tuple)))
    if address.field != field:  # e.g. 'qfrc_applied' on a body is not a thing
      raise KeyError(f'{source}.{field} cannot be indexed by name.')
    return address

  def _kind_of_field(self, source: str, field: str) -> tuple[_Kind, str]:
    if field in _QPOS_FIELDS[source] or (
        source == 'data' and field in _DOF_DATA_FIELDS
    ):
      return KINDS_BY_NAME['joint'], field
    if source == 'model' and field.startswith('dof_'):
      return KINDS_BY_NAME['joint'], field[4:]
    if source == 'data':
      if field == 'sensordata':
        return KINDS_BY_NAME['sensor'], field
      if field == 'act':
        return KINDS_BY_NAME['actuator'], field
      for kind_name, fields in _DATA_PER_ELEMENT.items():
        if field in fields:
          kind = KINDS_BY_NAME[kind_name]
          short = (
              field[len(kind.prefix) + 1 :]
              if field.startswith(kind.prefix + '_')
              else field
          )
          return kind, short
    else:
      for kind in KINDS_BY_NAME.values():
        if field.startswith(kind.prefix + '_'):
          return kind, field[len(kind.prefix) + 1 :]
    raise KeyError(f'{source}.{field} is not indexed by element names.')

  @staticmethod
  def _ranges(adr: np.ndarray, widths: list[int], ids: Sequence[int]):
    starts = [int(adr[i]) for i in ids]
    flat = np.concatenate([np.arange(s, s + w) for s, w in zip(starts, widths)])
    if flat.size and np.all(np.diff(flat) == 1):
      return slice(int(flat[0]), int(flat[-1]) + 1)  # a static slice, no gather
    return flat


_MODEL_FIELDS = frozenset(f.name for f in dataclasses.fields(mjx.Model))


def hasattr_model(field: str) -> bool:
  return field in _MODEL_FIELDS


def _element_index(ids: Sequence[int], is_seq: bool):
  if not is_seq:
    return int(ids[0])
  arr = np.asarray(ids)
  if arr.size > 1 and np.all(np.diff(arr) == 1):
    return slice(int(arr[0]), int(arr[-1]) + 1)
  return arr


def _describe(element) -> str:
  name = getattr(element, 'name', '')
  return f'{type(element).__name__}({name!r})' if name else repr(element)


@struct.dataclass
class Physics:
  """One world: the (possibly per-world) model, the data and the task state.

  Attributes:
    model: the `mjx.Model`. Fields that no variation or hook changes are the
      environment's shared compiled constants.
    data: this world's `mjx.Data`.
    task_state: a pytree of per-world task/entity state declared by the task
      (`Task.initial_task_state`), e.g. a sampled target position.
    index: static tables resolving elements and names (see `ElementIndex`).
    persistent: per-world state that survives episodes (auto-resets), keyed
      by owner, e.g. a variator's `Sequence` counter. Entries are created in
      `initialize_episode` (see `get_persistent`/`set_persistent`).
    initialization_failed: a bool scalar; an initializer that cannot
      initialize the episode sets it (`fail_initialization`) and the
      environment resamples the episode with a fresh key, up to
      `max_reset_attempts` times (composer's `EpisodeInitializationError`).
  """

  model: mjx.Model
  data: mjx.Data
  task_state: Any = None
  index: ElementIndex = struct.field(pytree_node=False, default=None)
  persistent: Any = None
  initialization_failed: Any = None

  # -- dm_control-style accessors -------------------------------------------

  def bind(self, elements) -> 'Binding':
    """A view of one element (or a list of elements of one kind)."""
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
    return self.replace(data=self.data.replace(ctrl=control))

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
    if not isinstance(self.task_state, dict):
      raise TypeError('update_task_state needs a dict task state.')
    unknown = set(values) - set(self.task_state)
    if unknown:
      raise KeyError(
          f'Unknown task state entries {sorted(unknown)}; declare '
          'them in Task.initial_task_state().'
      )
    new = dict(self.task_state)
    for k, v in values.items():
      old = new[k]
      new[k] = jnp.asarray(v, dtype=jnp.asarray(old).dtype).reshape(
          jnp.shape(old)
      )
    return self.replace(task_state=new)

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
    return self.replace(persistent=persistent)

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
    return self.replace(
        initialization_failed=jnp.logical_or(
            previous, jnp.asarray(failed, bool)
        )
    )

  def read(self, address: _Address) -> jax.Array:
    source = self.data if address.source == 'data' else self.model
    return getattr(source, address.field)[address.index]

  def write(self, address: _Address, value) -> 'Physics':
    source = self.data if address.source == 'data' else self.model
    old = getattr(source, address.field)
    target_shape = jax.eval_shape(lambda a: a[address.index], old).shape
    value = jnp.broadcast_to(jnp.asarray(value, dtype=old.dtype), target_shape)
    new = old.at[address.index].set(value)
    if address.source == 'data':
      return self.replace(data=self.data.replace(**{address.field: new}))
    return self.replace(model=self.model.replace(**{address.field: new}))


class Binding:
  """Attribute access for bound elements, like dm_control's `physics.bind`."""

  __slots__ = ('_physics', '_kind', '_ids', '_is_seq')

  def __init__(self, physics: Physics, kind: _Kind, ids: tuple, is_seq: bool):
    self._physics = physics
    self._kind = kind
    self._ids = ids
    self._is_seq = is_seq

  def _address(self, attr: str) -> _Address:
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
    source = getattr(self._physics, self._source)
    return np.asarray(getattr(source, self._field), dtype=dtype)


def iter_elements(spec: mujoco.MjSpec) -> Iterable[tuple[str, Any]]:
  """Yields `(kind name, handle)` for every bindable element of a spec."""
  for kind_name, attr in SPEC_LISTS.items():
    for element in getattr(spec, attr):
      yield kind_name, element
