"""The attribute catalogue: one `Attribute` per supported MJCF attribute.

A record says everything the compiler knows about one (element kind,
attribute) pair: the shape of its value, how to read and write it on the
MjSpec element, the compiled fields it maps to and how it writes them on
the device, what else it makes the compiler recompute (`effects.Effect`),
and why it may be refused at bind time (`structure` refusals). To support
another attribute, add its record to `CATALOGUE` (a new kind of device
write or refusal goes in `writes` or `structure`, for the record to name).

Values are in spec units (e.g. degrees for the joint ranges of a spec whose
compiler uses degrees). Position actuators also take `kp` (gainprm[0], with
biasprm[1] = -kp) and `kv` (biasprm[2] = -kv).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Optional

import jax.numpy as jnp
import numpy as np

from mjx_composer.model import element_index
from mjx_composer.compiler import effects
from mjx_composer.compiler import options
from mjx_composer.compiler import structure
from mjx_composer.compiler import writes

Effect = effects.Effect


# -- bounds -------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Bound:
  """The values an attribute may take (what recompiling would accept).

  Every entry is finite and within `[low, high]`, the lower end exclusive
  where `strict` (for the first entry of each row only, where
  `strict_first`). Data, not a callable, so that the values of several
  bindings are checked together as one array (`limits`).

  Attributes:
    text: the bound, in words, for error messages ('>= 0').
    low: the lowest value (-inf: none).
    high: the highest value (inf: none).
    strict: whether `low` itself is out of bounds.
    strict_first: whether `low` is out of bounds for the first entry of
      each row (along the last axis; the entry itself for a scalar).
  """

  text: str
  low: float = -np.inf
  high: float = np.inf
  strict: bool = False
  strict_first: bool = False

  def limits(self, shape) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`(low, strict, high)` for each entry of a value of `shape`."""
    low = np.full(shape, self.low, np.float32)
    high = np.full(shape, self.high, np.float32)
    strict = np.full(shape, self.strict)
    if self.strict_first:
      if strict.ndim:
        strict[..., 0] = True
      else:
        strict = np.asarray(True)
    return low, strict, high

  def valid(self, value):
    """A bool scalar: every entry of `value` is finite and within the bound.

    Works on numpy values (a numpy bool) and traced JAX values.
    """
    xp = np if isinstance(value, (np.ndarray, np.generic)) else jnp
    return xp.all(within(value, *self.limits(np.shape(value)), xp=xp))

  def describe(self) -> str:
    return 'finite' if self == FINITE else f'finite and {self.text}'


def within(value, low, strict, high, xp=jnp):
  """Where each entry of `value` is finite and within its limits (the
  arrays of `Bound.limits`)."""
  above = xp.where(strict, value > low, value >= low)
  return xp.isfinite(value) & above & (value <= high)


FINITE = Bound('finite')
NONNEGATIVE = Bound('>= 0', low=0.0)
POSITIVE = Bound('> 0', low=0.0, strict=True)
UNIT_INTERVAL = Bound('in [0, 1]', low=0.0, high=1.0)
SIZE = Bound('>= 0 with a first entry > 0', low=0.0, strict_first=True)


def bound_for(bound: Bound, compiled) -> Bound:
  """`bound`, relaxed to one the compiled value meets where it breaks it.

  E.g. an infinite plane's size is 0: its bound becomes `NONNEGATIVE`. A
  value the spec leaves unset (NaN, e.g. a geom's mass when its density
  decides) keeps the bound.
  """
  compiled = np.asarray(compiled, np.float64)
  if bound.valid(compiled) or not np.all(np.isfinite(compiled)):
    return bound
  if bound is SIZE and NONNEGATIVE.valid(compiled):
    return NONNEGATIVE
  return FINITE


@dataclasses.dataclass(frozen=True)
class Attribute:
  """One supported (element kind, MJCF attribute) pair.

  Attributes:
    kind: the element kind ('geom', 'body', 'site', 'joint', 'actuator',
      'option').
    name: the attribute, as the MjSpec element names it (or `kp`/`kv`).
    shape: the shape of its value.
    fields: the compiled `mjx.Model` fields it maps to (`opt.<name>` for the
      option), directly or, for inertial attributes, through the body's
      inertial (`inertia.bodies_inertial`).
    effects: what else the compiler recomputes when it varies.
    refusals: bind-time checks of the element (`structure`), in order.
    set_model: writes `fields` on the device; None when `inertia` derives
      them (the inertial attributes).
    get_spec: reads the value from the element (default: the attribute).
    set_spec: writes the value on the element (default: the attribute).
    bound: the values it may take (`Bound`): a variation that draws
      outside it makes the episode's initialization fail (see
      `variation.variator_base`).
  """

  kind: str
  name: str
  shape: tuple[int, ...]
  fields: tuple[str, ...]
  effects: Effect = Effect.NONE
  refusals: tuple[structure.Refusal, ...] = ()
  set_model: Optional[writes.ModelWrite] = None
  get_spec: Optional[Callable[[Any], Any]] = None
  set_spec: Optional[Callable[[Any, np.ndarray], None]] = None
  bound: Bound = FINITE

  def spec_value(self, element) -> np.ndarray:
    """The attribute's value in the spec, as a float64 array."""
    if self.get_spec is not None:
      value = self.get_spec(element)
    else:
      value = getattr(element, self.name)
    # A copy: MjSpec attributes are views of the spec's memory.
    return np.array(value, np.float64).reshape(self.shape)

  def set_spec_value(self, element, value):
    """Sets the attribute on the spec element (the inverse of `spec_value`).

    For host-side references: set values, recompose, recompile.
    """
    value = np.asarray(value, np.float64)
    if self.set_spec is not None:
      self.set_spec(element, value)
    elif value.shape == ():
      setattr(element, self.name, float(value))
    else:
      setattr(element, self.name, value)

  def refusal(self, element) -> Optional[str]:
    """Why the element's attribute cannot vary, or None."""
    for refuse in self.refusals:
      why = refuse(element)
      if why:
        return why
    return None


# -- spec access --------------------------------------------------------------


def _first_entry(name: str) -> dict[str, Callable]:
  """Spec access to element.<name>[0] (joint damping and stiffness)."""

  def set_spec(element, value):
    current = np.array(getattr(element, name))
    current[0] = value
    setattr(element, name, current)

  return dict(
      get_spec=lambda element: getattr(element, name)[0], set_spec=set_spec
  )


def _set_kp(actuator, value):
  gain, bias = np.array(actuator.gainprm), np.array(actuator.biasprm)
  gain[0], bias[1] = value, -value
  actuator.gainprm, actuator.biasprm = gain, bias


def _set_kv(actuator, value):
  bias = np.array(actuator.biasprm)
  bias[2] = -value
  actuator.biasprm = bias


# -- the catalogue ------------------------------------------------------------

_s = structure
_INERTIAL = ('body_mass', 'body_inertia', 'body_ipos', 'body_iquat')
_GEOM_POSE = Effect.GEOM_INERTIA | Effect.GEOM_FRAME | Effect.KINEMATICS
_GAINS = Effect.ACTUATOR_GAINS


def _record(kind, name, shape, **kwargs) -> Attribute:
  """A record that, unless told otherwise, writes `<prefix>_<name>[id]`."""
  field = f'{element_index.KINDS_BY_NAME[kind].prefix}_{name}'
  kwargs.setdefault('fields', (field,))
  kwargs.setdefault('set_model', writes.put(field))
  if kind == 'body':
    kwargs['refusals'] = (_s.world_body,) + kwargs.get('refusals', ())
  return Attribute(kind, name, shape, **kwargs)


def _pose(kind, part, effects_, **kwargs) -> Attribute:
  """pos or quat of a geom, body or site: a compiled local pose."""
  fields = (f'{kind}_{part}',)
  if kind == 'body':
    fields += ('qpos0', 'qpos_spring')
  return _record(
      kind,
      part,
      (3,) if part == 'pos' else (4,),
      fields=fields,
      effects=effects_,
      set_model=writes.put_pose(kind, part),
      **kwargs,
  )


def _inertial(kind, name, shape, effects_, refusals, fields=None, bound=FINITE):
  """An attribute that `inertia.bodies_inertial` derives the fields from."""
  fields = fields or (f'body_{name}',)
  return _record(
      kind,
      name,
      shape,
      fields=fields,
      effects=effects_,
      refusals=refusals,
      set_model=None,
      bound=bound,
  )


def _option(name, shape, refusals=(), bound=FINITE) -> Attribute:
  return Attribute(
      'option',
      name,
      shape,
      (f'opt.{name}',),
      refusals=refusals,
      set_model=writes.option(name),
      bound=bound,
  )


CATALOGUE: tuple[Attribute, ...] = (
    _record(
        'geom',
        'size',
        (3,),
        fields=('geom_size', 'geom_rbound', 'geom_aabb'),
        effects=Effect.GEOM_INERTIA | Effect.KINEMATICS,
        refusals=(_s.meshlike_geom, _s.fluid_ellipsoid),
        set_model=writes.geom_size,
        bound=SIZE,
    ),
    _record('geom', 'rgba', (4,), bound=UNIT_INTERVAL),
    _record('geom', 'friction', (3,), bound=NONNEGATIVE),
    _inertial(
        'geom',
        'mass',
        (),
        Effect.GEOM_INERTIA,
        (_s.meshlike_geom,),
        _INERTIAL,
        bound=NONNEGATIVE,
    ),
    _inertial(
        'geom',
        'density',
        (),
        Effect.GEOM_INERTIA,
        (_s.meshlike_geom,),
        _INERTIAL,
        bound=NONNEGATIVE,
    ),
    _pose(
        'geom',
        'pos',
        _GEOM_POSE,
        refusals=(_s.meshlike_geom, _s.fromto_geom),
    ),
    _pose(
        'geom',
        'quat',
        _GEOM_POSE,
        refusals=(
            _s.meshlike_geom,
            _s.fromto_geom,
            _s.orientation_alternative,
        ),
    ),
    _record('geom', 'solref', (2,)),
    _record('geom', 'solimp', (5,)),
    _pose('body', 'pos', Effect.BODY_FRAME),
    _pose(
        'body',
        'quat',
        Effect.BODY_FRAME,
        refusals=(_s.orientation_alternative,),
    ),
    _inertial(
        'body',
        'mass',
        (),
        Effect.BODY_INERTIAL,
        (_s.inertia_from_geoms,),
        bound=NONNEGATIVE,
    ),
    _inertial(
        'body',
        'inertia',
        (3,),
        Effect.BODY_INERTIAL,
        (_s.full_inertia, _s.inertia_from_geoms),
        bound=NONNEGATIVE,
    ),
    _inertial(
        'body',
        'ipos',
        (3,),
        Effect.BODY_INERTIAL | Effect.INERTIAL_FRAME,
        (_s.inertia_from_geoms,),
    ),
    _inertial(
        'body',
        'iquat',
        (4,),
        Effect.BODY_INERTIAL | Effect.INERTIAL_FRAME,
        (
            _s.full_inertia,
            _s.inertial_orientation_alternative,
            _s.inertia_from_geoms,
        ),
    ),
    _pose('site', 'pos', Effect.KINEMATICS),
    _pose(
        'site',
        'quat',
        Effect.KINEMATICS,
        refusals=(_s.orientation_alternative,),
    ),
    _record(
        'joint',
        'damping',
        (),
        fields=('dof_damping',),
        refusals=(_s.spring_damper,),
        set_model=writes.put_dofs('dof_damping'),
        bound=NONNEGATIVE,
        **_first_entry('damping'),
    ),
    _record(
        'joint',
        'stiffness',
        (),
        refusals=(_s.spring_damper,),
        bound=NONNEGATIVE,
        **_first_entry('stiffness'),
    ),
    _record(
        'joint',
        'armature',
        (),
        fields=('dof_armature',),
        effects=Effect.MASS_MATRIX,
        set_model=writes.put_dofs('dof_armature'),
        bound=NONNEGATIVE,
    ),
    _record(
        'joint',
        'frictionloss',
        (),
        fields=('dof_frictionloss',),
        refusals=(_s.no_frictionloss,),
        set_model=writes.put_dofs('dof_frictionloss'),
        bound=NONNEGATIVE,
    ),
    _record(
        'joint',
        'range',
        (2,),
        effects=Effect.JOINT_RANGE,
        refusals=(_s.free_joint_range, _s.unlimited_joint),
        set_model=writes.joint_range,
    ),
    _record(
        'actuator',
        'gear',
        (6,),
        effects=Effect.TRANSMISSION,
        refusals=(_s.muscle,),
    ),
    _record(
        'actuator',
        'ctrlrange',
        (2,),
        refusals=(_s.inherited_ctrlrange, _s.not_ctrllimited),
    ),
    _record('actuator', 'forcerange', (2,), refusals=(_s.not_forcelimited,)),
    _record(
        'actuator',
        'kp',
        (),
        fields=('actuator_gainprm', 'actuator_biasprm'),
        effects=_GAINS,
        refusals=(_s.not_position_like('kp'),),
        set_model=writes.kp,
        get_spec=lambda actuator: actuator.gainprm[0],
        set_spec=_set_kp,
    ),
    _record(
        'actuator',
        'kv',
        (),
        fields=('actuator_biasprm',),
        effects=_GAINS,
        refusals=(_s.not_position_like('kv'), _s.dampratio),
        set_model=writes.kv,
        get_spec=lambda actuator: -actuator.biasprm[2],
        set_spec=_set_kv,
    ),
    _record(
        'actuator', 'gainprm', (10,), effects=_GAINS, refusals=(_s.muscle,)
    ),
    _record(
        'actuator', 'biasprm', (10,), effects=_GAINS, refusals=(_s.muscle,)
    ),
    _option('gravity', (3,)),
    _option('wind', (3,), refusals=(_s.no_fluid,)),
    _option('density', (), refusals=(_s.no_fluid,), bound=NONNEGATIVE),
    _option('viscosity', (), refusals=(_s.no_fluid,), bound=NONNEGATIVE),
)

# {kind: {attribute: record}}, in catalogue order.
BY_KIND: dict[str, dict[str, Attribute]] = {
    kind: {r.name: r for r in CATALOGUE if r.kind == kind}
    for kind in dict.fromkeys(r.kind for r in CATALOGUE)
}


def supported_text() -> str:
  """The supported attributes, for error messages."""
  return '; '.join(
      f'{kind}: {", ".join(attrs)}' for kind, attrs in BY_KIND.items()
  )


def kind_of(element) -> str:
  """'option' for an `MjOption`, else the element's kind name."""
  if isinstance(element, options.SPEC_OPTION):
    return 'option'
  try:
    kind = element_index.element_kind(element).name
  except TypeError as e:
    raise TypeError(
        f'MJCFVariator cannot bind {element!r}: expected an MjSpec element '
        f"handle or the root spec's option. Supported: {supported_text()}."
    ) from e
  if kind not in BY_KIND:
    raise ValueError(
        f'MJCFVariator cannot vary a {kind}. Supported: {supported_text()}.'
    )
  return kind


def lookup(element, attr: str) -> Attribute:
  """The record of an element's attribute.

  Raises:
    TypeError: for something that is not an element or the option.
    ValueError: for an unsupported kind or attribute.
  """
  kind = kind_of(element)
  record = BY_KIND[kind].get(attr)
  if record is None:
    raise ValueError(
        f'MJCFVariator cannot vary {kind} attribute {attr!r}: it is not one '
        'that maps onto compiled model fields we can re-derive on the device. '
        f'Supported {kind} attributes: {sorted(BY_KIND[kind])}. '
        f'(All supported: {supported_text()}.) To write a compiled field '
        'without re-deriving anything, use PhysicsVariator.'
    )
  return record


def check_attribute(element, attr: str) -> str:
  """Bind-time checks of one attribute; returns the element kind.

  Raises:
    ValueError: with the reason and what is supported instead.
  """
  record = lookup(element, attr)
  why = record.refusal(element)
  if why:
    name = getattr(element, 'name', '') or ''
    what = f'{record.kind} {name!r}' if name else record.kind
    raise ValueError(f'MJCFVariator cannot vary {attr!r} of {what}: {why}')
  return record.kind


def bound_of(element, attr: str) -> Bound:
  """The bound of an element's attribute (its record's)."""
  return lookup(element, attr).bound


def spec_value(element, kind: str, attr: str) -> np.ndarray:
  """The attribute's value in the spec, as a float64 array."""
  return BY_KIND[kind][attr].spec_value(element)


def set_spec_value(element, kind: str, attr: str, value):
  """Sets the attribute on the spec element (the inverse of `spec_value`)."""
  BY_KIND[kind][attr].set_spec_value(element, value)
