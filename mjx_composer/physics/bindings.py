"""What `physics.bind(...)` and `physics.named` read and write.

`Binding` (one element or a list of one kind), `EmptyBinding` (an empty
list, as dm_control's) and `NamedAccess` (`physics.named.data.<field>[name]`)
give composer's view of a `physics.Physics`:

* dm_control's shapes: the rotation matrices `xmat`, `ximat`, `geom_xmat`,
  `site_xmat` and `cam_xmat` are flat 9-vectors (`(9,)` for one element,
  `(n, 9)` for a list), as MuJoCo's `mjData` and
  `dm_control.mujoco.Physics.bind` hold them; MJX keeps `(n, 3, 3)`.
* the fields MJX computes only where a sensor needs them (`subtree_linvel`,
  `subtree_angmom`: `mjx.subtree_vel`; `cacc`, `cfrc_int`, `cfrc_ext`:
  `mjx.rne_postconstraint`) are computed when read, from the data, so they
  hold what MuJoCo's `mj_subtreeVel` / `mj_rnePostConstraint` give on the
  same state; those MJX keeps in its implementation data (`cinert`, `crb`,
  actuator and tendon velocities) are read there.
* composer's dirty flag, recorded: while the runtime traces a control
  step's hooks in composer's order (`recording_dirty_events`), the binding
  writes that mark dm_control's physics dirty, the binding reads that run
  its `mj_forward` and the hooks' own `physics.forward()` calls are
  recorded, so that the runtime can tell whether composer's physics is
  dirty when a control step's sub-steps end
  (`runtime/dirty_forward.py`).
* no stale read: dm_control's bindings run `mj_forward` before reading
  anything after a write of `STATE_INPUT_FIELDS` or of a model field (but
  the visual ones, `marks_stale`). Here a read of a quantity that such a
  write made stale, with no forward pass between, raises `StaleReadError`
  while tracing (`check_fresh`), or, in the `initialize_episode` hooks
  (`Physics.forward_stale_reads`), reads it from the stage of the forward
  pass that computes it (`stale_stage`, `KINEMATICS_FIELDS`).
"""

from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
from mujoco import mjx
import numpy as np

from mjx_composer.model import element_index
from mjx_composer.platform import backend
from mjx_composer.platform import internals

if TYPE_CHECKING:
  from mjx_composer.physics import Physics  # pylint: disable=g-bad-import-order

# Rotation matrices MJX keeps as `(n, 3, 3)` and MuJoCo's `mjData` (so
# dm_control's bindings) as `(n, 9)`: bindings give and take them flat.
FLAT_MATRIX_FIELDS = frozenset(
    {'xmat', 'ximat', 'geom_xmat', 'site_xmat', 'cam_xmat'}
)
# `mjData` fields that MJX keeps in its implementation data (`data._impl`),
# computed by every forward pass.
IMPL_FIELDS = frozenset({'cinert', 'crb', 'actuator_velocity', 'ten_velocity'})
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
# (controls, activations, applied forces) the acceleration stage only. A
# model field (not in `STATE_INPUT_FIELDS`) changes everything, as
# dm_control's bindings treat it.
_INPUT_STAGE = {'qpos': 1, 'qvel': 2}
# Model attributes whose write dm_control's bindings do not mark dirty (its
# `MJMODEL_DOESNT_TRIGGER_DIRTY`): appearance, which no forward pass reads.
_VISUAL_ATTRIBUTES = frozenset({
    'rgba', 'matid', 'emission', 'specular', 'shininess', 'reflectance',
    'needstage',
})  # fmt: skip
# Model attributes the kinematics (`KINEMATICS_FIELDS`) read: frames, joint
# anchors and axes, masses and inertias (centres of mass, composite
# inertias). A write of any other model field (friction, sizes, gains,
# solver parameters) leaves the kinematics fresh: dm_control would run
# `mj_forward` before the read and read the same value.
_KINEMATIC_ATTRIBUTES = frozenset({
    'pos', 'quat', 'ipos', 'iquat', 'axis', 'mass', 'inertia', 'subtreemass',
    'sameframe',
})  # fmt: skip
# What `Physics.kinematics()` computes (`mjx.kinematics`, then
# `mjx.com_pos`): a stale read of one of these needs no more than it.
KINEMATICS_FIELDS = frozenset({
    'xpos', 'xquat', 'xmat', 'xipos', 'ximat', 'xanchor', 'xaxis',
    'geom_xpos', 'geom_xmat', 'site_xpos', 'site_xmat', 'subtree_com',
    'cinert', 'cdof',
})  # fmt: skip
# Of the `KINEMATICS_FIELDS`, those a write of a model field of these
# elements' `_KINEMATIC_ATTRIBUTES` can change: a geom's or a site's frame
# places only that geom or site (MuJoCo's `mj_kinematics` reads `geom_pos`
# for `geom_xpos` alone, `geom_quat` for `geom_xmat`), a body's inertial
# frame and mass only the inertial quantities (`mj_comPos` places `cinert`
# and `cdof` about the subtree's centre of mass). Every other kinematic
# model field (a body's or a joint's frame) may change them all.
_KINEMATICS_WRITTEN = {
    'geom_pos': frozenset({'geom_xpos'}),
    'geom_quat': frozenset({'geom_xmat'}),
    'geom': frozenset({'geom_xpos', 'geom_xmat'}),
    'site_pos': frozenset({'site_xpos'}),
    'site_quat': frozenset({'site_xmat'}),
    'site': frozenset({'site_xpos', 'site_xmat'}),
    'body_ipos': frozenset({'xipos', 'subtree_com', 'cinert', 'cdof'}),
    'body_iquat': frozenset({'ximat', 'cinert'}),
    'body_mass': frozenset({'subtree_com', 'cinert', 'cdof'}),
    'body_subtreemass': frozenset({'subtree_com', 'cinert', 'cdof'}),
    'body_inertia': frozenset({'cinert'}),
}


# -- composer's dirty flag, as events recorded while tracing -----------------
#
# dm_control's `mjcf.Physics.bind` marks the physics dirty on a write of an
# attribute that `marks_stale` (its `triggers_dirty`), and runs `mj_forward`,
# clearing the mark, before a read of any other attribute while the mark is
# set; `Physics.forward()` clears it too. `physics.named`, `physics.data`
# and `set_control` neither set nor clear it, and `Physics.step` leaves it.
# Here a binding records these events in every open `recording_dirty_events`
# list, in the order the (pure) hooks call it, which is the order composer's
# hooks run in; nothing is recorded where no list is open.

DIRTYING_WRITE = 'write'
FORWARDING_READ = 'read'
FORWARD = 'forward'

_RECORDINGS: list[list] = []


@contextlib.contextmanager
def recording_dirty_events():
  """Records composer's dirty-flag events while open (see above).

  Yields the list the events are appended to, as `(kind, field)` pairs:
  `(DIRTYING_WRITE, field)` for a binding write that marks dm_control's
  physics dirty, `(FORWARDING_READ, field)` for a binding read that runs
  its forward pass where the physics is dirty, `(FORWARD, '')` for a
  `Physics.forward()`.
  """
  events = []
  _RECORDINGS.append(events)
  try:
    yield events
  finally:
    _RECORDINGS.remove(events)


def record_dirty_event(kind: str, field: str = '') -> None:
  """Appends `(kind, field)` to every open `recording_dirty_events` list."""
  for events in _RECORDINGS:
    events.append((kind, field))


def _record_access(address: element_index.Address, write: bool) -> None:
  """Records a binding's access of `address` (composer's dirty flag)."""
  if not _RECORDINGS:
    return
  triggers = marks_stale(address.source, address.field)
  if write and triggers:
    record_dirty_event(DIRTYING_WRITE, address.field)
  elif not write and not triggers:
    record_dirty_event(FORWARDING_READ, address.field)


class StaleReadError(ValueError):
  """A binding read a derived quantity after a write with no forward pass.

  dm_control's bindings run `mj_forward` lazily before such a read; here a
  step hook must call `physics.forward()` (or `physics.kinematics()`)
  itself (`initialize_episode` hooks read through the forward pass).
  """


def _sensor_stage(mj_model, index) -> int:
  """The last forward-pass stage that `sensordata[index]` needs (1-3)."""
  rows = np.arange(mj_model.nsensordata)[index].reshape(-1)
  if not rows.size:
    return 1
  # The sensor of each row: the last sensor starting at or before it.
  sensors = np.searchsorted(mj_model.sensor_adr, rows, side='right') - 1
  return int(np.max(mj_model.sensor_needstage[sensors]))


def flat(field: str, value):
  """`value` of `field` in dm_control's shape (matrices flat)."""
  if field in FLAT_MATRIX_FIELDS:
    return value.reshape(value.shape[:-2] + (9,))
  return value


def unflat(field: str, value, target_shape):
  """`value` (dm_control's shape, or MJX's) broadcast to MJX's
  `target_shape` of `field`."""
  if field in FLAT_MATRIX_FIELDS:
    if value.shape[-2:] == (3, 3):
      value = value.reshape(value.shape[:-2] + (9,))
    value = jnp.broadcast_to(value, target_shape[:-2] + (9,))
    value = value.reshape(target_shape)
  return jnp.broadcast_to(value, target_shape)


def read_field(model, data, source: str, name: str) -> jax.Array:
  """The whole `source` ('data' or 'model') field `name`, in MJX's shape.

  Reads fields that MJX keeps in its implementation data, and computes
  `ON_DEMAND_FIELDS` from `data` (a forwarded `mjx.Data`).
  """
  if source == 'model':
    return getattr(model, name)
  if name in ON_DEMAND_FIELDS or name in IMPL_FIELDS:
    if not backend.of(data).jax_data_fields:
      raise NotImplementedError(
          f'data.{name} cannot be read on MuJoCo Warp '
          "(ExecutionOptions(impl='warp')): MJX keeps it only in its "
          "JAX implementation's data. Use impl='jax', or a sensor that "
          'measures it (e.g. a subtreelinvel sensor for subtree_linvel).'
      )
    if name in ON_DEMAND_FIELDS:
      data = ON_DEMAND_FIELDS[name](model, data)
    return getattr(internals.data_impl(data), name)
  return getattr(data, name)


def check_writable(field: str) -> None:
  if field in ON_DEMAND_FIELDS or field in IMPL_FIELDS:
    raise AttributeError(
        f'data.{field} is computed by the forward pass and cannot be '
        'written.'
    )


def marks_stale(source: str, field: str) -> bool:
  """Whether writing `source` ('data' or 'model') field `field` makes
  derived quantities stale until the next forward pass: the
  `STATE_INPUT_FIELDS`, and every model field but the visual ones (what
  dm_control's bindings mark dirty)."""
  if source == 'data':
    return field in STATE_INPUT_FIELDS
  return field.split('_', 1)[-1] not in _VISUAL_ATTRIBUTES


def kinematics_written(name: str) -> frozenset:
  """The `KINEMATICS_FIELDS` that a write of `name` (a
  `STATE_INPUT_FIELDS` field or a model field) can change."""
  if name in STATE_INPUT_FIELDS:
    return KINEMATICS_FIELDS if name == 'qpos' else frozenset()
  element, _, attribute = name.partition('_')
  if attribute not in _KINEMATIC_ATTRIBUTES:
    return frozenset()
  return _KINEMATICS_WRITTEN.get(
      name, _KINEMATICS_WRITTEN.get(element, KINEMATICS_FIELDS)
  )


def stale_stage(unsynced, field: str, index, mj_model) -> int:
  """The forward-pass stage (1-3) that `field[index]` needs where the
  `unsynced` writes (`marks_stale` fields written with no forward pass
  since) made it stale; 0 where it is fresh."""
  if field in KINEMATICS_FIELDS:
    unsynced = [name for name in unsynced if field in kinematics_written(name)]
  if not unsynced or field in _NOT_DERIVED:
    return 0
  stale_from = min(
      _INPUT_STAGE.get(name, 3 if name in STATE_INPUT_FIELDS else 1)
      for name in unsynced
  )
  if field == 'sensordata':
    stage = _sensor_stage(mj_model, index)
  else:
    stage = _FIELD_STAGE.get(field, 3)
  return stage if stage >= stale_from else 0


def check_fresh(unsynced, field: str, index, mj_model) -> None:
  """Raises `StaleReadError` where `field[index]` is derived from the
  `unsynced` writes and would read its value from before them."""
  if stale_stage(unsynced, field, index, mj_model):
    raise StaleReadError(
        f'This physics wrote {sorted(unsynced)} and then read {field!r}, '
        'which is derived from them, with no forward pass between: it '
        'would read the value from before the write. dm_control runs '
        'mj_forward before such a read; here call `physics = '
        'physics.forward()` (or `physics.kinematics()` for positions '
        'only) after the write and read from the result. (In '
        'initialize_episode hooks the read runs that forward pass itself.)'
    )


def _renamed_element_id() -> AttributeError:
  return AttributeError(
      "dm_control's `binding.element_id` is `binding.element_ids` here: the "
      'compiled ids of the bound elements, a tuple (`element_ids[0]` for one '
      'element, `np.array(binding.element_ids)` where an array is needed).'
  )


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
    if attr == 'element_id':
      raise _renamed_element_id()
    address = self._address(attr)
    _record_access(address, write=False)
    return self._physics.read(address)

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
    """The compiled ids of the bound elements (dm_control's
    `element_id`, which is refused with this name)."""
    return self._ids

  def set(self, **values) -> Physics:
    """Returns a new Physics with the given attributes written."""
    physics = self._physics
    for attr, value in values.items():
      address = self._address(attr)
      _record_access(address, write=True)
      physics = physics.write(address, value)
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
    if attr == 'element_id':
      raise _renamed_element_id()
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


class NamedAccess:
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
    return np.asarray(
        flat(self._field, self._physics.field(self._source, self._field)),
        dtype=dtype,
    )
