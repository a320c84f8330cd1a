"""PyMJCF (`dm_control.mjcf`) models and elements, converted to MjSpec.

dm_control's entities build an `mjcf.RootElement` and hand out `mjcf.Element`s
(bodies, joints, sites, ...). An entity may do the same here: its PyMJCF model
is converted to a `mujoco.MjSpec` each time the tree is composed, through
MuJoCo's XML (`to_xml_string` and `get_assets`, then `MjSpec.from_string`),
so edits made to the PyMJCF model after construction (by a task, by
`regenerate`) are part of the compiled model. Each PyMJCF element is matched
to the element of the converted spec that has its name: PyMJCF writes every
element's full identifier into the XML, unnamed ones as
`'//unnamed_<namespace>_<n>'`. Those placeholder names are cleared in the
converted spec, so unnamed elements are named like an MjSpec's unnamed
elements when composed.

dm_control is an optional dependency: this module never imports it; it
recognises PyMJCF objects through `sys.modules` (an object can only be a
PyMJCF element if `dm_control.mjcf` has been imported).
"""

from __future__ import annotations

import sys
from typing import Any

import mujoco

# PyMJCF namespaces of the bindable element kinds (`element_index.SPEC_LISTS`
# keys): every kind is its own namespace in PyMJCF.
BINDABLE_NAMESPACES = (
    'body',
    'geom',
    'site',
    'joint',
    'actuator',
    'sensor',
    'tendon',
    'camera',
    'light',
    'equality',
)
# The MjSpec list attribute that holds each kind of element, in order.
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
_UNNAMED_PREFIX = '//unnamed_'


def _mjcf_base():
  module = sys.modules.get('dm_control.mjcf.base')
  return None if module is None else module.Element


def is_element(obj) -> bool:
  """Whether `obj` is a PyMJCF element (a root, a body, a geom, ...)."""
  base = _mjcf_base()
  return base is not None and isinstance(obj, base)


def is_root(obj) -> bool:
  """Whether `obj` is a PyMJCF model (`mjcf.RootElement`)."""
  module = sys.modules.get('dm_control.mjcf.element')
  return module is not None and isinstance(obj, module.RootElement)


def is_dm_control_entity(obj) -> bool:
  """Whether `obj` is a dm_control `composer.Entity` (walker, arena, prop)."""
  module = sys.modules.get('dm_control.composer.entity')
  return module is not None and isinstance(obj, module.Entity)


def is_model(obj) -> bool:
  """Whether `obj` is an entity model: an MjSpec or a PyMJCF root."""
  return isinstance(obj, mujoco.MjSpec) or is_root(obj)


def kind_name(element) -> str | None:
  """The bindable kind of a PyMJCF element (`'body'`, ...), or None.

  A model's `worldbody` is a body; a `freejoint` is a joint; an actuator,
  sensor, tendon or equality of any tag is of its namespace's kind.
  """
  if element.tag == 'worldbody':
    return 'body'
  namespace = element.spec.namespace
  return namespace if namespace in BINDABLE_NAMESPACES else None


def describe(element) -> str:
  """`<tag> '<full identifier>'` of a PyMJCF element, for messages."""
  try:
    name = element.full_identifier
  except (AttributeError, ValueError):
    name = None
  model = getattr(element.root, 'model', None)
  where = f' of PyMJCF model {model!r}' if model else ''
  return f'PyMJCF <{element.tag}> {name!r}{where}'


def model_name(root) -> str:
  """The name of a PyMJCF model (`root.model`), '' when it has none."""
  return root.model or ''


def to_spec(root, frame_names: dict[int, str] | None = None):
  """Converts a PyMJCF model to a fresh MjSpec.

  Args:
    root: an `mjcf.RootElement` that is not attached inside another PyMJCF
      model (attach entities with `Entity.attach`).
    frame_names: `{id(PyMJCF body): name}`: bodies to rename in the spec
      (attachment frames, named `"<child>/"` as in composer, a name PyMJCF
      itself refuses).

  Returns:
    `(spec, aliases)`: the spec, and `{id(PyMJCF element): (element, kind
    name, spec handle)}` for the worldbody and every bindable element of the
    PyMJCF model, including those of PyMJCF models attached inside it.

  Raises:
    ValueError: `root` is attached inside another PyMJCF model, or an
      element of it has no counterpart in the converted spec.
  """
  if root.parent_model is not None:
    raise ValueError(
        f'PyMJCF model {root.model!r} is attached inside PyMJCF model '
        f'{root.parent_model.model!r}: compose the outer model, or attach '
        "the entities with the entity's attach() instead of PyMJCF's."
    )
  xml = root.to_xml_string()
  assets = root.get_assets()
  try:
    spec = mujoco.MjSpec.from_string(xml, assets=assets)
  except ValueError as e:
    raise ValueError(
        f'MuJoCo cannot load PyMJCF model {root.model!r} converted to XML: '
        f'{e}'
    ) from e
  if root.model:
    spec.modelname = root.model
  by_name = {}
  for kind, attr in SPEC_LISTS.items():
    by_name[kind] = {h.name: h for h in getattr(spec, attr) if h.name}
  aliases = {id(root.worldbody): (root.worldbody, 'body', spec.worldbody)}
  for namespace in BINDABLE_NAMESPACES:
    for element in root.find_all(namespace):
      name = element.full_identifier
      handle = by_name[namespace].get(name)
      if handle is None:
        raise ValueError(
            f'{describe(element)} has no {namespace} named {name!r} in the '
            'MjSpec converted from its XML.'
        )
      aliases[id(element)] = (element, namespace, handle)
  for _, _, handle in aliases.values():
    # A placeholder that another element refers to (a touch sensor's site,
    # an actuator's joint) stays: MjSpec refers by name.
    if handle.name.startswith(_UNNAMED_PREFIX) and (
        xml.count(f'"{handle.name}"') == 1
    ):
      handle.name = ''
  for element_id, name in (frame_names or {}).items():
    aliases[element_id][2].name = name
  return spec, aliases


def spec_handle_of(element):
  """`(spec, handle)`: a PyMJCF element's model converted now, its handle.

  For checks that read MjSpec attributes before the tree is composed. Keep
  the spec while using the handle: the handle lives in the spec's memory.
  """
  spec, aliases = to_spec(element.root)
  entry = aliases.get(id(element))
  if entry is None:
    raise ValueError(f'{describe(element)} is not a bindable element.')
  return spec, entry[2]


def attachment_frame(model, site, owner: str):
  """Adds an (unnamed) attachment frame body at a PyMJCF site or body.

  The frame takes a site's pose (`pos`, `quat` and the alternative
  orientations); under a body it sits at the body's origin. Its composed
  name (`"<child>/"`) is set in the converted spec (`to_spec`).

  Args:
    model: the parent entity's own model (an MjSpec or a PyMJCF root).
    site: the PyMJCF site or body to attach at.
    owner: the parent entity's name, for messages.

  Raises:
    TypeError: `model` is an MjSpec, or `site` is no PyMJCF site or body.
    ValueError: `site` belongs to another PyMJCF model.
  """
  if not is_root(model):
    raise TypeError(
        f'attach_site {describe(site)} is a PyMJCF element, but '
        f"{owner!r}'s model is an MjSpec: pass one of its MjsSite or "
        'MjsBody handles.'
    )
  if not is_element(site) or site.tag not in ('site', 'body', 'worldbody'):
    raise TypeError(
        f"{owner!r}'s model is a PyMJCF model: attach_site must be one of "
        f'its PyMJCF sites or bodies, got {site!r}.'
    )
  if site.root is not model:
    raise ValueError(
        f"attach_site {describe(site)} is not an element of {owner!r}'s "
        'own PyMJCF model.'
    )
  if site.tag == 'site':
    attributes = {
        key: getattr(site, key)
        for key in ('pos', 'quat', 'axisangle', 'xyaxes', 'zaxis', 'euler')
        if getattr(site, key) is not None
    }
    return site.parent.add('body', **attributes)
  return site.add('body')


def freejoint(frame) -> Any:
  """The freejoint of a PyMJCF attachment frame body, or None."""
  for joint in frame.find_all('joint', immediate_children_only=True):
    if joint.tag == 'freejoint' or joint.type == 'free':
      return joint
  return None


def elements(model, attr: str) -> list:
  """An entity model's elements of one list (`'geoms'`, `'joints'`, ...).

  `getattr(spec, attr)` for an MjSpec; for a PyMJCF model, its elements of
  that namespace, those of PyMJCF models attached inside it included.
  """
  if is_root(model):
    namespace = {a: k for k, a in SPEC_LISTS.items()}[attr]
    return model.find_all(namespace)
  return list(getattr(model, attr))


def own_joints(root) -> list:
  """The joints of a PyMJCF model, not those of models attached inside it."""
  return root.find_all('joint', exclude_attachments=True)


def spec_attribute_error(error: AttributeError, where: str):
  """A PyMJCF name asked of an MjSpec object, with what to use instead.

  Args:
    error: an `AttributeError` raised while building an entity.
    where: what raised it, for the message (`'Ant._build'`).

  Returns:
    A new `AttributeError` when `error` is a PyMJCF name (`find_all`,
    `add`, ...) asked of a `mujoco.MjSpec` or an `Mjs*` element, else None.
  """
  obj = getattr(error, 'obj', None)
  name = getattr(error, 'name', None)
  is_spec_object = isinstance(obj, mujoco.MjSpec) or (
      type(obj).__module__.startswith('mujoco')
      and type(obj).__name__.startswith('Mjs')
  )
  hint = _SPEC_HINTS.get(name)
  if not is_spec_object or hint is None:
    return None
  return AttributeError(
      f'{where}: {type(obj).__name__} has no {name!r}, a PyMJCF (dm_control '
      f'mjcf) name. On a mujoco.MjSpec use {hint}; or build the entity on '
      'PyMJCF (an mjcf.RootElement as mjcf_model), which composes as well.'
  )


_SPEC_HINTS = {
    'find_all': (
        'spec.<kind>s (spec.geoms, spec.bodies, spec.joints, ...) or a '
        "body's find_all(mujoco.mjtObj.mjOBJ_GEOM)"
    ),
    'find': 'spec.geom(name), spec.body(name), spec.joint(name), ...',
    'add': 'body.add_body / add_geom / add_site / add_joint, spec.add_actuator',
    'to_xml_string': 'spec.to_xml()',
    'get_assets': 'spec.assets',
    'model': 'spec.modelname',
    'full_identifier': (
        "the element's name (composed names read '<child>/<element>')"
    ),
}
