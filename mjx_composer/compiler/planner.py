"""`ModelCompiler`: plans, from the catalogue, what to recompute; runs it.

Built once per compiled model (at trace time) from the bound attributes:
each binding's record (`attributes.CATALOGUE`) gives the fields it writes
and its effects (`effects.Effect`), which combine into a static `Plan`.
Calling the compiler with one value per binding writes those fields, then
re-derives what the plan says can change: body inertials (`inertia`),
`body_subtreemass` and `mj_setConst`'s quantities (`set_const`). Only
fields that can change are returned, so only they become per-world.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Sequence

import jax
import jax.numpy as jnp
from mujoco import mjx
import numpy as np

from mjx_composer.model import element_index
from mjx_composer.compiler import attributes
from mjx_composer.compiler import context
from mjx_composer.compiler import effects
from mjx_composer.compiler import inertia
from mjx_composer.compiler import set_const
from mjx_composer.compiler import structure

Effect = effects.Effect


@dataclasses.dataclass(frozen=True)
class Binding:
  """One bound attribute resolved against the compiled model."""

  element: Any
  record: attributes.Attribute
  obj_id: int  # compiled id (-1 for the option)
  describe: str


@dataclasses.dataclass(frozen=True)
class Plan:
  """What the device recomputes, decided statically from the bindings.

  Attributes:
    inertia_bodies: the bodies whose inertial is recomputed, sorted.
    inertia: whether any is (and so `body_subtreemass`).
    body_frames: whether a body frame varies.
    mass_matrix: whether the joint-space inertia at qpos0 can change.
    kinematics: whether positions at qpos0 can change.
    moments: whether actuator moments at qpos0 can change.
    dampratio_actuators: actuators whose spec may set a dampratio.
    dampratios: whether the dampings derived from dampratios can change.
    length_ranges: whether what muscle length ranges derive from changes.
    set_const: whether `set_const.update` runs.
  """

  inertia_bodies: tuple[int, ...]
  inertia: bool
  body_frames: bool
  mass_matrix: bool
  kinematics: bool
  moments: bool
  dampratio_actuators: tuple[int, ...]
  dampratios: bool
  length_ranges: bool
  set_const: bool


def make_plan(host: context.Host, bindings: Sequence[Binding]) -> Plan:
  """Combines the effects of the bound attributes (see `effects`)."""
  m = host.m

  def ids(kind, effect):
    return {
        b.obj_id
        for b in bindings
        if b.record.kind == kind and b.record.effects & effect
    }

  def bound(effect):
    return any(b.record.effects & effect for b in bindings)

  inertia_bodies = ids('body', Effect.BODY_INERTIAL)
  for g in ids('geom', Effect.GEOM_INERTIA):
    b = int(m.geom_bodyid[g])
    body = host.handles['body'].get(b)
    if b > 0 and body is not None and inertia.infers_inertia(body):
      inertia_bodies.add(b)
  # Bodies whose inertial copies the body pose (no geoms to infer from).
  for b in ids('body', Effect.BODY_FRAME):
    if host.copies_body_frame(b):
      inertia_bodies.add(b)
  changes_inertia = bool(inertia_bodies)
  body_frames = bound(Effect.BODY_FRAME)
  mass_matrix = changes_inertia or body_frames or bound(Effect.MASS_MATRIX)
  kinematics = changes_inertia or body_frames or bound(Effect.KINEMATICS)
  moments = kinematics or bound(Effect.TRANSMISSION)
  gains = bound(Effect.ACTUATOR_GAINS)
  dampratio = tuple(set_const.dampratio_actuators(host))
  return Plan(
      inertia_bodies=tuple(sorted(inertia_bodies)),
      inertia=changes_inertia,
      body_frames=body_frames,
      mass_matrix=mass_matrix,
      kinematics=kinematics,
      moments=moments,
      dampratio_actuators=dampratio,
      dampratios=mass_matrix or moments or gains,
      length_ranges=moments or bound(Effect.JOINT_RANGE),
      set_const=mass_matrix or moments or (gains and bool(dampratio)),
  )


class ModelCompiler:
  """Derives the compiled fields of a model from varied MJCF attributes.

  Built once per compiled model (at trace time) from the bound attributes;
  calling it with one value per binding returns the model fields to replace.

  Args:
    index: the environment's `ElementIndex` (compiled host model and the
      element handles of every entity).
    bindings: `(element, attr, description)` per binding.
    owner: the variator's name, for messages.

  Raises:
    ValueError: for bindings that the composed model cannot vary
      (`structure.check_composed`).
  """

  def __init__(
      self,
      index,
      bindings: Sequence[tuple[Any, str, str]],
      owner: str = 'MJCFVariator',
  ):
    self._owner = owner
    self._host = context.Host(index)
    resolved = []
    for element, attr, describe in bindings:
      record = attributes.lookup(element, attr)
      obj_id = -1
      if record.kind != 'option':
        kind = element_index.KINDS_BY_NAME[record.kind]
        try:
          obj_id = index.element_id(kind, element)
        except (ValueError, KeyError) as e:
          raise ValueError(
              f'{owner}: cannot apply the variation bound to '
              f'{describe}: {e}'
          ) from e
      resolved.append(Binding(element, record, obj_id, describe))
    self._bindings = tuple(resolved)
    self.initial_values = [
        b.record.spec_value(b.element).astype(np.float32)
        for b in self._bindings
    ]
    self.plan = make_plan(self._host, self._bindings)
    structure.check_composed(self._host, self.plan, self._bindings, owner)
    self._auto_stat = None  # which statistics the compiler computed (lazy)

  def _statistics(self) -> dict[str, bool]:
    if self._auto_stat is None:
      self._auto_stat = set_const.auto_stat(self._host.m)
    return self._auto_stat

  @jax.named_scope('model_compiler')
  def __call__(self, model: mjx.Model, values: Sequence[jax.Array]) -> dict:
    """The model fields to replace, for one world.

    Args:
      model: the world's current mjx.Model (fields that are not recomputed
        are read from it).
      values: one value per binding, in the attribute's spec units.

    Returns:
      `{field name: new value}`; `opt` and `stat` come as whole structs.
    """
    plan = self.plan
    fields = context.Fields(self._host, model)
    for bound, value in zip(self._bindings, values):
      record = bound.record
      value = jnp.asarray(value, jnp.float32)
      per_kind = fields.values.setdefault(record.kind, {})
      per_kind.setdefault(bound.obj_id, {})[record.name] = value
      if record.set_model is not None:
        record.set_model(fields, bound.obj_id, value)
    with jax.named_scope('inertia'):
      bodies = plan.inertia_bodies
      if bodies:
        inertial = inertia.bodies_inertial(fields, bodies, self._owner)
        for name, value in zip(
            ('body_mass', 'body_inertia', 'body_ipos', 'body_iquat'), inertial
        ):
          fields.put(name, np.asarray(bodies), value)
      if plan.inertia:
        fields.fields['body_subtreemass'] = inertia.subtreemass(
            self._host.m, fields.get('body_mass')
        )
    if plan.set_const:
      set_const.update(self._host, plan, fields, self._statistics)
    if fields.opt:
      fields.fields['opt'] = model.opt.replace(**fields.opt)
    return fields.fields
