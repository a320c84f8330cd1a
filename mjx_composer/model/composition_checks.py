"""Checks that composing an entity tree keeps every element it declares.

`Entity.compose` merges the entities' specs with `MjSpec.copy()` and
`MjSpec.attach()`. Both silently drop an element that refers to an element
they cannot find: an actuator whose joint name has a typo, a sensor on a
missing site, a tendon wrapping a missing joint, an equality, an exclude or a
contact pair naming a missing body or geom. `attach` also drops an element of
the attached spec that refers to that spec's worldbody (which, once attached,
is replaced by the attachment frame). Compiling the entity's own spec would
raise in the first case; composing would instead build a model with fewer
actuators or sensors (e.g. `nu == 0`) and no error.

`check_copy` and `check_attach` compare what each step kept with what went in
and raise a `ValueError` that names the element, its entity, the missing
target and what to fix. They only raise when an element was actually dropped,
so a model MuJoCo accepts is never rejected here.

Cross-entity references: as in composer, an entity may declare an equality,
actuator, sensor, exclude or contact pair that refers by full name to an
element of an entity attached below it (a weld between `'arm/hand'` and
`'prop/body'` declared in the arena). Its own spec cannot resolve that name,
so `copy()` would drop it: `cross_entity_elements` finds such elements, and
`Entity.compose` adds a copy of each (`readd`) to the composed spec once the
entities are attached, where compiling resolves (or rejects) the name.
"""

from __future__ import annotations

import difflib
from typing import NamedTuple

import mujoco

# Element lists that copy/attach may shorten, compared by count.
_COUNTED = (
    'geoms',
    'sites',
    'joints',
    'cameras',
    'lights',
    'actuators',
    'sensors',
    'tendons',
    'equalities',
    'excludes',
    'pairs',
)
# Singular names, for messages.
_SINGULAR = {
    'bodies': 'body',
    'geoms': 'geom',
    'sites': 'site',
    'joints': 'joint',
    'cameras': 'camera',
    'lights': 'light',
    'actuators': 'actuator',
    'sensors': 'sensor',
    'tendons': 'tendon',
    'equalities': 'equality',
    'excludes': 'exclude',
    'pairs': 'contact pair',
}
# Object types a sensor or equality may refer to -> the MjSpec finder
# (`spec.body(name)`, ...) and the list that holds them.
_OBJ_KINDS = {
    mujoco.mjtObj.mjOBJ_BODY: ('body', 'bodies'),
    mujoco.mjtObj.mjOBJ_XBODY: ('body', 'bodies'),
    mujoco.mjtObj.mjOBJ_GEOM: ('geom', 'geoms'),
    mujoco.mjtObj.mjOBJ_SITE: ('site', 'sites'),
    mujoco.mjtObj.mjOBJ_JOINT: ('joint', 'joints'),
    mujoco.mjtObj.mjOBJ_CAMERA: ('camera', 'cameras'),
    mujoco.mjtObj.mjOBJ_LIGHT: ('light', 'lights'),
    mujoco.mjtObj.mjOBJ_TENDON: ('tendon', 'tendons'),
    mujoco.mjtObj.mjOBJ_ACTUATOR: ('actuator', 'actuators'),
    mujoco.mjtObj.mjOBJ_FLEX: ('flex', 'flexes'),
}
_KIND_LISTS = {kind: attr for kind, attr in _OBJ_KINDS.values()}
_TRN_TARGET = {
    mujoco.mjtTrn.mjTRN_JOINT: 'joint',
    mujoco.mjtTrn.mjTRN_JOINTINPARENT: 'joint',
    mujoco.mjtTrn.mjTRN_TENDON: 'tendon',
    mujoco.mjtTrn.mjTRN_SITE: 'site',
    mujoco.mjtTrn.mjTRN_SLIDERCRANK: 'site',
    mujoco.mjtTrn.mjTRN_BODY: 'body',
}
_EQ_OBJ = {
    mujoco.mjtEq.mjEQ_CONNECT: 'body',
    mujoco.mjtEq.mjEQ_WELD: 'body',
    mujoco.mjtEq.mjEQ_JOINT: 'joint',
    mujoco.mjtEq.mjEQ_TENDON: 'tendon',
    mujoco.mjtEq.mjEQ_FLEX: 'flex',
    mujoco.mjtEq.mjEQ_FLEXVERT: 'flex',
    mujoco.mjtEq.mjEQ_FLEXSTRAIN: 'flex',
    mujoco.mjtEq.mjEQ_DISTANCE: 'geom',
}
_WRAP_TARGET = {
    mujoco.mjtWrap.mjWRAP_JOINT: 'joint',
    mujoco.mjtWrap.mjWRAP_SITE: 'site',
    mujoco.mjtWrap.mjWRAP_SPHERE: 'geom',
    mujoco.mjtWrap.mjWRAP_CYLINDER: 'geom',
}


def count_elements(spec: mujoco.MjSpec) -> dict[str, int]:
  """The number of elements of each checked kind in `spec`."""
  counts = {attr: len(getattr(spec, attr)) for attr in _COUNTED}
  counts['bodies'] = len(spec.bodies)
  return counts


# Element lists whose elements may refer to an attached entity's elements,
# and the MjSpec method that adds one.
_CROSS_ENTITY = {
    'equalities': 'add_equality',
    'actuators': 'add_actuator',
    'sensors': 'add_sensor',
    'excludes': 'add_exclude',
    'pairs': 'add_pair',
}
# Attributes that belong to the spec an element lives in, not to the element.
_NOT_COPIED = frozenset(
    {'id', 'signature', 'classname', 'compiler', 'info', 'plugin', 'frame'}
)


def cross_entity_elements(entity, spec: mujoco.MjSpec) -> list:
  """`(list attr, element)` of `spec` that refer to attached entities.

  An element qualifies when each of its unresolved references names an
  element below one of `entity`'s attached children (`'<child name>/...'`).
  """
  prefixes = tuple(
      child.name + '/'
      for child in entity.iter_entities(exclude_self=True)
      if child.parent is entity
  )
  if not prefixes:
    return []
  unresolved = {}
  for attr, index, element, ref in _dangling_references(spec):
    unresolved.setdefault((attr, index), (element, []))[1].append(ref)
  return [
      (attr, element)
      for (attr, _), (element, refs) in unresolved.items()
      if attr in _CROSS_ENTITY
      and all(r.name and r.name.startswith(prefixes) for r in refs)
  ]


def readd(spec: mujoco.MjSpec, attr: str, element):
  """Adds to `spec` a copy of `element` (from `cross_entity_elements`)."""
  clone = getattr(spec, _CROSS_ENTITY[attr])()
  for name in dir(element):
    if name.startswith('_') or name in _NOT_COPIED:
      continue
    value = getattr(element, name)
    if callable(value):
      continue
    try:
      setattr(clone, name, value)
    except (AttributeError, TypeError):
      pass  # A read-only or derived attribute.
  return clone


def check_copy(
    entity, original: mujoco.MjSpec, copied: mujoco.MjSpec, deferred=()
):
  """Raises ValueError if `copied = original.copy()` lost any element.

  Args:
    entity: the `Entity` that owns `original` (for messages).
    original: the entity's own spec.
    copied: its copy, before anything else is added to it.
    deferred: `cross_entity_elements(entity, original)`: dropped on purpose,
      added back after the attached entities.
  """
  before, after = count_elements(original), count_elements(copied)
  for attr, _ in deferred:
    before[attr] -= 1
  if before == after:
    return
  skip = {id(element) for _, element in deferred}
  problems = [
      _describe_dangling(entity, original, attr, index, element, ref)
      for attr, index, element, ref in _dangling_references(original)
      if id(element) not in skip
  ]
  if not problems:
    problems = _describe_missing(entity, original, copied, '')
  raise ValueError(_join(problems))


def check_attach(
    entity,
    child_spec: mujoco.MjSpec,
    parent_counts: dict[str, int],
    parent_spec: mujoco.MjSpec,
):
  """Raises ValueError if attaching `child_spec` lost any of its elements.

  Args:
    entity: the attached (child) `Entity`.
    child_spec: the child's composed spec that was attached.
    parent_counts: `count_elements(parent_spec)` before the attach.
    parent_spec: the spec it was attached to.
  """
  child = count_elements(child_spec)
  expected = {attr: parent_counts[attr] + child[attr] for attr in child}
  expected['bodies'] -= 1  # The child's worldbody becomes the frame.
  if count_elements(parent_spec) == expected:
    return
  prefix = entity.name + '/'
  problems = []
  for attr, index, element, ref in _references(child_spec):
    kept = attr in ('excludes', 'pairs') or (
        element.name
        and any(
            e.name == prefix + element.name for e in getattr(parent_spec, attr)
        )
    )
    if ref.kind == 'body' and ref.name == 'world' and not kept:
      name = _element_name(element, attr, index, entity.full_identifier)
      problems.append(
          f'{name} {ref.verb} the worldbody of entity {entity.name!r}, which '
          'composition replaces by the attachment frame '
          f'{entity.full_identifier!r}, so MuJoCo drops it when it attaches '
          f'the entity: make it refer to a {ref.kind} inside entity '
          f'{entity.name!r} instead'
          + (
              " (an equality's empty second name means the world)"
              if attr == 'equalities'
              else ''
          )
          + '.'
      )
  if not problems:
    problems = _describe_missing(entity, child_spec, parent_spec, prefix)
  raise ValueError(_join(problems))


class _Ref(NamedTuple):
  """One by-name reference of an element: `<verb> <kind> '<name>'`."""

  verb: str  # e.g. 'targets', 'refers to'
  kind: str  # 'joint', 'site', ...
  name: str | None  # None when MuJoCo no longer knows it (a tendon wrap)
  field: str  # what to fix, e.g. 'the target name'
  found: bool


def _lookup(spec, kind, name):
  if kind == 'flex':
    return any(f.name == name for f in spec.flexes)
  finder = getattr(spec, kind, None)
  if finder is None:
    return True  # A kind we cannot look up: assume it resolves.
  return finder(name) is not None


def _ref(spec, verb, kind, name, field):
  return _Ref(verb, kind, name, field, _lookup(spec, kind, name))


def _element_refs(spec, attr, element):
  """The by-name references of one element (empty names are not refs)."""
  refs = []
  if attr == 'actuators':
    kind = _TRN_TARGET.get(element.trntype)
    if kind and element.target:
      refs.append(
          _ref(spec, 'targets', kind, element.target, 'the target name')
      )
    if element.trntype == mujoco.mjtTrn.mjTRN_SITE and element.refsite:
      refs.append(
          _ref(spec, 'refers to', 'site', element.refsite, 'the refsite name')
      )
    if (
        element.trntype == mujoco.mjtTrn.mjTRN_SLIDERCRANK
        and element.slidersite
    ):
      refs.append(
          _ref(
              spec,
              'refers to',
              'site',
              element.slidersite,
              'the slidersite name',
          )
      )
  elif attr == 'sensors':
    for objtype, name, field in (
        (element.objtype, element.objname, "the sensor's objname"),
        (element.reftype, element.refname, "the sensor's refname"),
    ):
      if name and objtype in _OBJ_KINDS:
        verb = 'is attached to' if 'objname' in field else 'refers to'
        refs.append(_ref(spec, verb, _OBJ_KINDS[objtype][0], name, field))
  elif attr == 'equalities':
    kind = _OBJ_KINDS.get(element.objtype, (None,))[0] or _EQ_OBJ.get(
        element.type
    )
    for name, field in (
        (element.name1, "the equality's name1"),
        (element.name2, "the equality's name2"),
    ):
      if kind and name:
        refs.append(_ref(spec, 'constrains', kind, name, field))
  elif attr == 'excludes':
    for name, field in (
        (element.bodyname1, "the exclude's bodyname1"),
        (element.bodyname2, "the exclude's bodyname2"),
    ):
      if name:
        refs.append(_ref(spec, 'excludes', 'body', name, field))
  elif attr == 'pairs':
    for name, field in (
        (element.geomname1, "the pair's geomname1"),
        (element.geomname2, "the pair's geomname2"),
    ):
      if name:
        refs.append(_ref(spec, 'pairs', 'geom', name, field))
  elif attr == 'tendons':
    for i, wrap in enumerate(element.path):
      kind = _WRAP_TARGET.get(wrap.type)
      if kind is not None and wrap.target is None:
        # MuJoCo keeps no name for an unresolved wrap target.
        refs.append(
            _Ref(
                f'wraps (path element {i}{_line(wrap)})',
                kind,
                None,
                f'the {kind} name of path element {i}',
                False,
            )
        )
  return refs


def _references(spec):
  """Yields (list attr, index, element, _Ref) for every by-name reference."""
  for attr in ('actuators', 'sensors', 'tendons', 'equalities'):
    for index, element in enumerate(getattr(spec, attr)):
      for ref in _element_refs(spec, attr, element):
        yield attr, index, element, ref
  for attr in ('excludes', 'pairs'):
    for index, element in enumerate(getattr(spec, attr)):
      for ref in _element_refs(spec, attr, element):
        yield attr, index, element, ref


def _dangling_references(spec):
  return [r for r in _references(spec) if not r[3].found]


def _line(element):
  info = getattr(element, 'info', '')
  return f', MJCF {info}' if info else ''


def _element_name(element, attr, index, full_identifier):
  kind = _SINGULAR[attr].capitalize()
  if element.name:
    return f'{kind} {full_identifier + element.name!r}'
  return f'{kind} #{index} (unnamed{_line(element)})'


def _describe_dangling(entity, spec, attr, index, element, ref):
  """The message for one reference that does not resolve."""
  full = entity.full_identifier
  name = _element_name(element, attr, index, full)
  where = f'entity {entity.name!r} ({type(entity).__name__})'
  if ref.name is None:
    return (
        f'{name} {ref.verb} a {ref.kind} that does not exist in {where}, '
        'so composition would drop the tendon silently: fix '
        f'{ref.field} in {where}.'
    )
  if '/' in ref.name:
    return (
        f'{name} {ref.verb} {ref.kind} {ref.name!r}, which is not an element '
        f'of the own spec of {where}, so composition would drop the '
        f'{_SINGULAR[attr]}: an element can refer to elements of its own '
        'entity, and by full name to those of entities attached below it. '
        f'Declare the {_SINGULAR[attr]} in an entity that {ref.name!r} is '
        f'part of or attached below, or fix {ref.field} in {where}.'
    )
  message = (
      f'{name} {ref.verb} {ref.kind} {full + ref.name!r}, which does not '
      f'exist in the composed model: fix {ref.field} in {where}'
  )
  known = [e.name for e in getattr(spec, _KIND_LISTS[ref.kind]) if e.name]
  close = difflib.get_close_matches(ref.name, known, n=3)
  if close:
    message += f' (did you mean {" or ".join(repr(c) for c in close)}?)'
  message += (
      '. MjSpec.copy() and attach() drop such an element silently, so the '
      'compiled model would lack it.'
  )
  return message


def _describe_missing(entity, original, composed, prefix):
  """A generic message: which elements of `original` `composed` lacks."""
  lines = []
  for attr in ('bodies',) + _COUNTED:
    if attr in ('excludes', 'pairs'):
      if not prefix and len(getattr(original, attr)) > len(
          getattr(composed, attr)
      ):
        lines.append(f'{_SINGULAR[attr]}s')
      continue
    names = {e.name for e in getattr(composed, attr)}
    missing = [
        prefix + e.name
        for e in getattr(original, attr)
        if e.name and e.name != 'world' and prefix + e.name not in names
    ]
    if missing:
      lines.append(f'{attr} {missing}')
  what = '; '.join(lines) or 'some elements'
  return [
      f'Composing entity {entity.name!r} ({type(entity).__name__}) dropped '
      f'{what}: MuJoCo drops an element that refers to something it cannot '
      f"find. Compile entity {entity.name!r}'s own spec "
      '(`entity.mjcf_model.compile()`) to see which reference is wrong, and '
      'fix it in that entity.'
  ]


def _join(problems):
  if len(problems) == 1:
    return problems[0]
  return f'Composition would drop {len(problems)} elements:\n' + '\n'.join(
      f'- {p}' for p in problems
  )
