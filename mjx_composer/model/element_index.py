"""`ElementIndex`: MjSpec elements and names resolved to compiled indices.

Hooks, observables and variators refer to elements by the MjSpec handles their
entities keep (`mujoco.MjsBody`, `MjsGeom`, `MjsSite`, `MjsJoint`,
`MjsActuator`, `MjsSensor`, `MjsTendon`, `MjsCamera`, `MjsLight`,
`MjsEquality`), by the PyMJCF elements (`dm_control.mjcf.Element`) of
entities built on PyMJCF (`model/pymjcf.py`), or by fully qualified names
(`'arm/hand'`). `Environment`
builds one `ElementIndex` when it compiles; `Physics` carries it as static
data, so every element resolves to a static integer index (or slice) while
tracing, and nothing on the device looks a name up.

This module also holds the facts about MuJoCo's layout that several modules
need: which model and data fields are indexed per element of each kind, and
how many `qpos`/`dof` entries each joint type takes.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Iterable, Sequence

import mujoco
from mujoco import mjx
import numpy as np

from mjx_composer.model import pymjcf


@dataclasses.dataclass(frozen=True)
class Kind:
  """How one MuJoCo object type is laid out in `mjModel`/`mjData`."""

  name: str  # e.g. 'joint'
  obj: Any  # mujoco.mjtObj value
  prefix: str  # model field prefix, e.g. 'jnt'
  count: str  # model size attribute, e.g. 'njnt'


_KINDS = {
    mujoco.MjsBody: Kind('body', mujoco.mjtObj.mjOBJ_BODY, 'body', 'nbody'),
    mujoco.MjsGeom: Kind('geom', mujoco.mjtObj.mjOBJ_GEOM, 'geom', 'ngeom'),
    mujoco.MjsSite: Kind('site', mujoco.mjtObj.mjOBJ_SITE, 'site', 'nsite'),
    mujoco.MjsJoint: Kind('joint', mujoco.mjtObj.mjOBJ_JOINT, 'jnt', 'njnt'),
    mujoco.MjsActuator: Kind(
        'actuator', mujoco.mjtObj.mjOBJ_ACTUATOR, 'actuator', 'nu'
    ),
    mujoco.MjsSensor: Kind(
        'sensor', mujoco.mjtObj.mjOBJ_SENSOR, 'sensor', 'nsensor'
    ),
    mujoco.MjsTendon: Kind(
        'tendon', mujoco.mjtObj.mjOBJ_TENDON, 'tendon', 'ntendon'
    ),
    mujoco.MjsCamera: Kind('camera', mujoco.mjtObj.mjOBJ_CAMERA, 'cam', 'ncam'),
    mujoco.MjsLight: Kind(
        'light', mujoco.mjtObj.mjOBJ_LIGHT, 'light', 'nlight'
    ),
    mujoco.MjsEquality: Kind(
        'equality', mujoco.mjtObj.mjOBJ_EQUALITY, 'eq', 'neq'
    ),
}
KINDS_BY_NAME = {kind.name: kind for kind in _KINDS.values()}
# The MjSpec list attribute that holds each kind's elements, in order.
SPEC_LISTS = pymjcf.SPEC_LISTS

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
        # Kept by MJX in `data._impl`; `Physics.field` reads or computes them.
        'cinert',
        'crb',
        'subtree_linvel',
        'subtree_angmom',
        'cacc',
        'cfrc_int',
        'cfrc_ext',
    ),
    'joint': ('xanchor', 'xaxis'),
    'geom': ('geom_xpos', 'geom_xmat'),
    'site': ('site_xpos', 'site_xmat'),
    'camera': ('cam_xpos', 'cam_xmat'),
    'actuator': (
        'ctrl',
        'actuator_force',
        'actuator_length',
        'actuator_velocity',
    ),
    'tendon': ('ten_length', 'ten_velocity'),
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
QPOS_WIDTH = {0: 7, 1: 4, 2: 1, 3: 1}  # mjtJoint: free, ball, slide, hinge
DOF_WIDTH = {0: 6, 1: 3, 2: 1, 3: 1}
# Data fields whose short binding name differs from the data field name.
_DATA_ALIASES = {'tendon': {'length': 'ten_length', 'velocity': 'ten_velocity'}}


def element_kind(element) -> Kind:
  """The `Kind` of an MjSpec or PyMJCF element, or a clear TypeError."""
  for cls, kind in _KINDS.items():
    if isinstance(element, cls):
      return kind
  if pymjcf.is_element(element):
    name = pymjcf.kind_name(element)
    if name is not None:
      return KINDS_BY_NAME[name]
    raise TypeError(
        f'Cannot bind {pymjcf.describe(element)}: only PyMJCF '
        f'{", ".join(pymjcf.BINDABLE_NAMESPACES)} elements can be bound.'
    )
  raise TypeError(
      f'Cannot bind {element!r}: expected an MjSpec element handle '
      f'({", ".join(c.__name__ for c in _KINDS)}) or a PyMJCF element.'
  )


@dataclasses.dataclass(frozen=True)
class Address:
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
    self.mj_model = model
    self._handles = handle_names
    self._jnt_type = np.asarray(model.jnt_type)
    self._jnt_qposadr = np.asarray(model.jnt_qposadr)
    self._jnt_dofadr = np.asarray(model.jnt_dofadr)
    self._sensor_adr = np.asarray(model.sensor_adr)
    self._sensor_dim = np.asarray(model.sensor_dim)
    self._actuator_actadr = np.asarray(model.actuator_actadr)
    self._actuator_actnum = np.asarray(model.actuator_actnum)

  # -- element resolution ---------------------------------------------------

  def handles_by_id(self) -> dict[str, dict[int, Any]]:
    """`{kind name: {compiled id: element handle}}` for the composed model.

    A child entity's worldbody stands for its attachment frame in the handle
    table; the frame body's own handle is preferred.
    """
    out = {name: {} for name in KINDS_BY_NAME}
    for handle, kind_name, full_name in self._handles.values():
      if pymjcf.is_element(handle):
        continue  # An alias of the MjSpec handle it was converted to.
      kind = KINDS_BY_NAME[kind_name]
      idx = mujoco.mj_name2id(self.mj_model, kind.obj, full_name)
      if idx < 0:
        continue
      if kind_name == 'body' and idx != 0 and handle.name == 'world':
        continue  # A child's worldbody: its attachment frame has the handle.
      out[kind_name][idx] = handle
    return out

  def full_name(self, element) -> str:
    """Fully qualified compiled name of an element handle."""
    entry = self._handles.get(id(element))
    if (entry is None or entry[0] is not element) and pymjcf.is_element(
        element
    ):
      raise ValueError(
          f'Element {_describe(element)} is not part of the compiled model: '
          'its PyMJCF model is not the model of an entity attached to the '
          "task's root entity, or it was added after the environment was "
          'built (add elements before building the Environment).'
      )
    if entry is None or entry[0] is not element:
      raise ValueError(
          f'Element {_describe(element)} is not part of the compiled model: '
          "it does not belong to any entity attached to the task's root "
          'entity (attach its entity before building the Environment).'
      )
    return entry[2]

  def spec_handle(self, element):
    """The MjSpec handle a PyMJCF element was converted to (compose time).

    MjSpec handles are returned as they are. MJCFVariator reads the spec
    values of attributes through it.
    """
    if not pymjcf.is_element(element):
      return element
    name, kind = self.full_name(element), element_kind(element).name
    for handle, handle_kind, full_name in self._handles.values():
      if (
          handle_kind == kind
          and full_name == name
          and not pymjcf.is_element(handle)
      ):
        return handle
    raise ValueError(f'{_describe(element)} has no MjSpec handle.')

  def element_id(self, kind: Kind, element) -> int:
    """Compiled id of an element handle or a fully qualified name."""
    if isinstance(element, str):
      name = element
    else:
      if element_kind(element) is not kind:
        raise TypeError(f'Expected a {kind.name}, got {_describe(element)}.')
      name = self.full_name(element)
    idx = mujoco.mj_name2id(self.mj_model, kind.obj, name)
    if idx < 0:
      known = [
          mujoco.mj_id2name(self.mj_model, kind.obj, i)
          for i in range(getattr(self.mj_model, kind.count))
      ]
      raise KeyError(
          f'No {kind.name} named {name!r} in the compiled model. '
          f'Known {kind.name}s: {[k for k in known if k]}'
      )
    return idx

  def resolve(self, elements) -> tuple[Kind, list[int], bool]:
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
      self, kind: Kind, attr: str, ids: Sequence[int], is_seq: bool
  ) -> Address:
    """Where `attr` of the elements `ids` lives, as a static index."""
    if kind.name == 'joint':
      if attr in _QPOS_FIELDS['data'] or attr in _QPOS_FIELDS['model']:
        source = 'data' if attr in _QPOS_FIELDS['data'] else 'model'
        return Address(
            source,
            attr,
            self._ranges(
                self._jnt_qposadr,
                [QPOS_WIDTH[int(self._jnt_type[i])] for i in ids],
                ids,
            ),
        )
      dof_field = attr if attr in _DOF_DATA_FIELDS else None
      source = 'data'
      if dof_field is None and hasattr_model(f'dof_{attr}'):
        dof_field, source = f'dof_{attr}', 'model'
      if dof_field is not None:
        return Address(
            source,
            dof_field,
            self._ranges(
                self._jnt_dofadr,
                [DOF_WIDTH[int(self._jnt_type[i])] for i in ids],
                ids,
            ),
        )
    if kind.name == 'sensor' and attr == 'sensordata':
      return Address(
          'data',
          'sensordata',
          self._ranges(
              self._sensor_adr, [int(self._sensor_dim[i]) for i in ids], ids
          ),
      )
    if kind.name == 'actuator' and attr == 'act':
      return Address(
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
        return Address('data', candidate, index)
    if hasattr_model(f'{kind.prefix}_{attr}'):
      return Address('model', f'{kind.prefix}_{attr}', index)
    if kind.name == 'body' and attr in ('mocap_pos', 'mocap_quat'):
      mocap = np.asarray(self.mj_model.body_mocapid)[list(ids)]
      if np.any(mocap < 0):
        raise ValueError('Only mocap bodies have mocap_pos/mocap_quat.')
      return Address('data', attr, _element_index(mocap.tolist(), is_seq))
    raise AttributeError(
        f'A {kind.name} has no attribute {attr!r}. Valid attributes: '
        f'{sorted(self.valid_attributes(kind))}.'
    )

  def valid_attributes(self, kind: Kind) -> set[str]:
    names = set(_DATA_PER_ELEMENT.get(kind.name, ()))
    names |= {
        f[len(kind.prefix) + 1 :]
        for f in MODEL_FIELDS
        if f.startswith(kind.prefix + '_')
    }
    if kind.name == 'joint':
      names |= set(_QPOS_FIELDS['data'] + _QPOS_FIELDS['model'])
      names |= set(_DOF_DATA_FIELDS)
      names |= {f[4:] for f in MODEL_FIELDS if f.startswith('dof_')}
    if kind.name == 'sensor':
      names.add('sensordata')
    if kind.name == 'actuator':
      names.add('act')
    return names

  def named_address(self, source: str, field: str, key) -> Address:
    """Address of `source.field[key]` where key is a name, names or index."""
    if isinstance(key, (int, np.integer, slice)) or (
        isinstance(key, (list, tuple, np.ndarray))
        and len(key)
        and all(isinstance(k, (int, np.integer)) for k in key)
    ):
      return Address(
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

  def _kind_of_field(self, source: str, field: str) -> tuple[Kind, str]:
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


MODEL_FIELDS = frozenset(f.name for f in dataclasses.fields(mjx.Model))


def hasattr_model(field: str) -> bool:
  return field in MODEL_FIELDS


def _element_index(ids: Sequence[int], is_seq: bool):
  if not is_seq:
    return int(ids[0])
  arr = np.asarray(ids)
  if arr.size > 1 and np.all(np.diff(arr) == 1):
    return slice(int(arr[0]), int(arr[-1]) + 1)
  return arr


def _describe(element) -> str:
  if pymjcf.is_element(element):
    return pymjcf.describe(element)
  name = getattr(element, 'name', '')
  return f'{type(element).__name__}({name!r})' if name else repr(element)


def iter_elements(spec: mujoco.MjSpec) -> Iterable[tuple[str, Any]]:
  """Yields `(kind name, handle)` for every bindable element of a spec."""
  for kind_name, attr in SPEC_LISTS.items():
    for element in getattr(spec, attr):
      yield kind_name, element
