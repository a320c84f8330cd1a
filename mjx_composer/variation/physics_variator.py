"""`PhysicsVariator`: variations bound to compiled model fields, per world.

    self._physics_variator = variation.PhysicsVariator()
    self._physics_variator.bind_attributes(
        geom, friction=distributions.Uniform([0.5, 0.001, 0.001],
                                             [1.5, 0.01, 0.01]))
    self._physics_variator.bind_attributes(joint, damping=noises.Multiplicative(
        distributions.LogNormal(0., 0.1)))

    def initialize_episode(self, physics, key):
      return self._physics_variator.apply_variations(physics, key)

Attribute names are those of composer's `physics.bind(element)`: the
`mjModel` field without the element kind's prefix (`friction` for
`geom_friction`, `mass` for `body_mass`, `damping` for a joint's
`dof_damping`, `gear`, `rgba`, ...); the full field name (`body_mass`) is
accepted too. The option (`spec.option` of the root entity) binds its
physical fields (`gravity`, `wind`, `magnetic`, `density`, `viscosity`,
`impratio`).

Like composer's, this variator writes the fields and nothing else: quantities
MuJoCo's compiler derives from them (`body_subtreemass`, `dof_invweight0`,
...) keep their compiled values. Use `MJCFVariator` for variations that must
equal a recompiled model. Initial values are the compiled model's values;
current values are the world's. See `variator_base` for schedules, and for
invalid draws (values outside `FIELD_BOUNDS`, or not finite): at reset they
fail the episode's initialization, in step they are dropped.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
from mujoco import mjx
import numpy as np

from mjx_composer.model import element_index
from mjx_composer.compiler import attributes
from mjx_composer.compiler import options
from mjx_composer.variation import variator_base

# Option fields a variator may write: the physical ones. `timestep` is
# static for the environment (its control timestep), flags and solver
# settings are static in MJX.
OPTION_FIELDS = (
    'gravity',
    'wind',
    'magnetic',
    'density',
    'viscosity',
    'impratio',
)

# The bound of each compiled field (`opt.<name>` for the option) a draw
# must meet (see `variator_base`: an invalid draw fails the episode's
# initialization); fields not listed must be finite. `opt.timestep` is
# listed for completeness: it is not bindable (static for the environment).
_B = attributes
FIELD_BOUNDS: dict[str, attributes.Bound] = {
    'body_mass': _B.NONNEGATIVE,
    'body_inertia': _B.NONNEGATIVE,
    'geom_size': _B.SIZE,
    'geom_friction': _B.NONNEGATIVE,
    'geom_rgba': _B.UNIT_INTERVAL,
    'dof_damping': _B.NONNEGATIVE,
    'dof_armature': _B.NONNEGATIVE,
    'dof_frictionloss': _B.NONNEGATIVE,
    'jnt_stiffness': _B.NONNEGATIVE,
    'tendon_damping': _B.NONNEGATIVE,
    'tendon_stiffness': _B.NONNEGATIVE,
    'tendon_armature': _B.NONNEGATIVE,
    'tendon_frictionloss': _B.NONNEGATIVE,
    'opt.timestep': _B.POSITIVE,
    'opt.density': _B.NONNEGATIVE,
    'opt.viscosity': _B.NONNEGATIVE,
}


@dataclasses.dataclass
class _Target:
  """Where one binding writes: a model field slice or an option field."""

  address: Any  # physics._Address, or None for the option
  option_field: str | None


class _Plan:
  """Trace-time resolution of a PhysicsVariator's bindings."""

  def __init__(self, variator, physics):
    index = physics.index
    mj_model = index.mj_model
    self.targets = []
    self.initial_values = []
    self.bounds = []
    for binding in variator.bindings:
      element, attr = binding.element, binding.attr
      if isinstance(element, options.SPEC_OPTION):
        if attr in options.FLUID_FIELDS and not options.option_has_fluid(
            mj_model.opt
        ):
          raise ValueError(
              f'{variator.label}: cannot vary option {attr}: the '
              'compiled model has no fluid forces (density, viscosity and '
              'wind are all zero), and MJX decides that statically. Give the '
              'root spec a nonzero option density or viscosity.'
          )
        compiled = np.asarray(getattr(mj_model.opt, attr), np.float64)
        if not np.allclose(
            np.asarray(getattr(element, attr), np.float64),
            compiled,
            rtol=1e-9,
            atol=1e-12,
        ):
          raise ValueError(
              f'{variator.label}: the MjOption bound to {attr} does '
              "not hold the compiled model's values: bind the root "
              "entity's `mjcf_model.option` (options of attached entities "
              'are not compiled).'
          )
        field = getattr(physics.model.opt, attr)
        initial = compiled.astype(field.dtype)
        self.targets.append(_Target(None, attr))
        self.initial_values.append(initial.reshape(jnp.shape(field)))
        self.bounds.append(_field_bound(f'opt.{attr}', initial))
        continue
      try:
        kind, ids, is_seq = index.resolve(element)
      except (ValueError, KeyError) as e:
        raise ValueError(
            f'{variator.label}: cannot apply the '
            f'variation bound to {binding.describe()}: {e}'
        ) from e
      address = index.address(kind, _short_name(kind, attr), ids, is_seq)
      if address.source != 'model':
        raise ValueError(
            f'{variator.label}: {binding.describe()} is a data '
            f'field ({address.field}); a PhysicsVariator varies compiled '
            'model fields. Write data in initialize_episode instead.'
        )
      field = getattr(physics.model, address.field)
      if not hasattr(field, 'dtype') or isinstance(field, np.ndarray):
        raise ValueError(
            f'{variator.label}: model field {address.field} is '
            'static in MJX (part of the compiled structure) and cannot vary '
            'per world.'
        )
      host = np.asarray(getattr(mj_model, address.field))
      host = host.reshape(field.shape).astype(field.dtype)
      self.targets.append(_Target(address, None))
      self.initial_values.append(np.asarray(host[address.index]))
      self.bounds.append(_field_bound(address.field, self.initial_values[-1]))

  def read_current(self, physics, entry):
    del entry  # The current values are the world's model fields.
    values = []
    for target in self.targets:
      if target.address is None:
        values.append(getattr(physics.model.opt, target.option_field))
      else:
        values.append(physics.read(target.address))
    return values

  def write(self, physics, values):
    opt_updates = {}
    for target, value in zip(self.targets, values):
      if target.address is None:
        opt_updates[target.option_field] = value
      else:
        physics = physics.write(target.address, value)
    if opt_updates:
      model = physics.model
      physics = physics.replace(
          model=model.replace(opt=model.opt.replace(**opt_updates))
      )
    return physics, {}


def _field_bound(field: str, compiled) -> attributes.Bound:
  """A field's bound, relaxed to what its compiled value meets."""
  return attributes.bound_for(
      FIELD_BOUNDS.get(field, attributes.FINITE), compiled
  )


def _field_name(kind, short: str) -> str | None:
  """The compiled field a binding name maps to (`dof_damping`), or None."""
  prefixes = ('dof', kind.prefix) if kind.name == 'joint' else (kind.prefix,)
  for prefix in prefixes:
    if element_index.hasattr_model(f'{prefix}_{short}'):
      return f'{prefix}_{short}'
  return None


def _short_name(kind, attr: str) -> str:
  """`body_mass` -> `mass` for a body, `dof_damping` -> `damping` for joints."""
  prefixes = (kind.prefix, 'dof') if kind.name == 'joint' else (kind.prefix,)
  for prefix in prefixes:
    if attr.startswith(prefix + '_') and element_index.hasattr_model(attr):
      return attr[len(prefix) + 1 :]
  return attr


class PhysicsVariator(variator_base.Variator):
  """Binds variations to compiled model fields (composer's PhysicsVariator).

  Args:
    schedule: when to draw (`variation.Schedule`); every episode by default.
    name: the name of this variator's persistent entry (derived from its
      bindings by default).
  """

  def _check_binding(self, element, attr, variation):
    del variation  # Shapes are known once the model is compiled.
    if isinstance(element, options.SPEC_OPTION):
      if attr not in OPTION_FIELDS:
        raise ValueError(
            f'Cannot vary option attribute {attr!r} per world. Supported '
            f'option attributes: {list(OPTION_FIELDS)}.'
        )
      return
    kind = element_index.element_kind(element)  # TypeError for non-elements.
    short = _short_name(kind, attr)
    valid = _model_attributes(kind)
    if short not in valid:
      raise ValueError(
          f'A {kind.name} has no compiled model attribute {attr!r} that can '
          f'vary per world. Valid attributes: {sorted(valid)}.'
      )

  def _bound(self, element, attr):
    if isinstance(element, options.SPEC_OPTION):
      return FIELD_BOUNDS.get(f'opt.{attr}', attributes.FINITE)
    kind = element_index.element_kind(element)
    field = _field_name(kind, _short_name(kind, attr))
    if field is None:
      return None
    return FIELD_BOUNDS.get(field, attributes.FINITE)

  def _prepare(self, physics):
    return _Plan(self, physics)


def _model_attributes(kind) -> set[str]:
  """Binding names of a kind's mjx.Model array fields (per element)."""
  names = set()
  for field in dataclasses.fields(mjx.Model):
    if field.type is not jax.Array:
      continue  # static numpy metadata: structure, not variable per world
    name = field.name
    if name.startswith(kind.prefix + '_'):
      names.add(name[len(kind.prefix) + 1 :])
    elif kind.name == 'joint' and name.startswith('dof_'):
      names.add(name[4:])
    elif kind.name == 'joint' and name in ('qpos0', 'qpos_spring'):
      names.add(name)
  return names
