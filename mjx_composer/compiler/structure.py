"""Refusals: variations that a per-world model cannot equal.

MJX fixes part of a model at `put_model` time (static fields such as
`jnt_limited`, `dof_hasfrictionloss`, the mass-matrix sparsity of "simple"
bodies, fluid flags); meshes and height fields would need re-meshing; and
the compiler overrides some attributes (`fromto` poses, orientation
alternatives, `inheritrange`) or derives them by simulation (muscle length
ranges). Variations that would need any of these are refused:

* when binding, from the element itself: the `Refusal`s that the attribute
  catalogue (`attributes.CATALOGUE`) lists per attribute;
* when reset is traced, from the composed model: `check_composed`.
"""

from __future__ import annotations

from typing import Callable, Optional

import mujoco
import numpy as np

from mjx_composer.model import element_index
from mjx_composer.compiler import effects
from mjx_composer.compiler import geoms
from mjx_composer.compiler import inertia
from mjx_composer.compiler import options

_Joint = mujoco.mjtJoint
_QUAT_ORIENTATION = mujoco.mjtOrientation.mjORIENTATION_QUAT

# `spec element -> why its attribute cannot vary, or None`.
Refusal = Callable[[object], Optional[str]]


# -- bind time: the element ---------------------------------------------------


def _limited(flag, autolimits: bool, has_range: bool) -> bool:
  if flag == mujoco.mjtLimited.mjLIMITED_TRUE:
    return True
  if flag == mujoco.mjtLimited.mjLIMITED_FALSE:
    return False
  return bool(autolimits and has_range)


def _has_range(pair) -> bool:
  return not (pair[0] == 0 and pair[1] == 0)


def is_position_like(actuator) -> bool:
  return (
      actuator.gaintype == mujoco.mjtGain.mjGAIN_FIXED
      and actuator.biastype == mujoco.mjtBias.mjBIAS_AFFINE
      and actuator.gainprm[0] == -actuator.biasprm[1]
  )


def is_muscle(actuator) -> bool:
  return (
      actuator.gaintype == mujoco.mjtGain.mjGAIN_MUSCLE
      or actuator.biastype == mujoco.mjtBias.mjBIAS_MUSCLE
  )


def meshlike_geom(geom):
  if geom.type in geoms.MESHLIKE:
    return (
        'mesh, SDF and height-field geoms take their size, '
        'inertia and frame from the asset, which would need '
        're-meshing. Vary a primitive geom instead.'
    )
  return None


def fromto_geom(geom):
  if not np.isnan(geom.fromto[0]):
    return (
        'the geom is placed by `fromto`, which the compiler uses '
        'instead of pos/quat.'
    )
  return None


def orientation_alternative(element):
  if element.alt.type != _QUAT_ORIENTATION:
    kind = element_index.element_kind(element).name
    return (
        f'the {kind} orientation is given by an alternative '
        '(euler/axisangle/xyaxes/zaxis), which the compiler uses '
        'instead of quat.'
    )
  return None


def fluid_ellipsoid(geom):
  if geom.fluid_ellipsoid > 0:
    return (
        'the geom has fluid_ellipsoid interaction, whose '
        'coefficients (geom_fluid) are static in MJX.'
    )
  return None


def world_body(body):
  if (getattr(body, 'name', '') or '') == 'world':
    return (
        'the world body does not vary. To move an attached '
        'entity, bind its attachment frame '
        '(entity.attachment_frame).'
    )
  return None


def full_inertia(body):
  if not np.isnan(body.fullinertia[0]):
    return 'the body inertia is given by fullinertia.'
  return None


def inertial_orientation_alternative(body):
  if body.ialt.type != _QUAT_ORIENTATION:
    return 'the inertial orientation is given by an alternative.'
  return None


def inertia_from_geoms(body):
  if inertia.infers_inertia(body) and any(
      inertia.in_inertia_group(g, body.compiler) for g in body.geoms
  ):
    return (
        'the body infers its mass and inertia from its geoms (the '
        "compiler ignores the body's own mass/inertia). Vary the geoms' "
        'mass, density or size, or give the body an explicit inertial '
        '(set its ipos, mass and inertia in the spec).'
    )
  return None


def no_frictionloss(joint):
  if joint.frictionloss <= 0:
    return (
        'the compiled joint has no friction loss, and MJX fixes '
        'at put_model time which dofs have friction-loss '
        'constraints. Give it a nonzero frictionloss in the spec '
        '(and keep varied values positive).'
    )
  return None


def free_joint_range(joint):
  if joint.type == _Joint.mjJNT_FREE:
    return 'free joints have no range.'
  return None


def unlimited_joint(joint):
  autolimits = joint.compiler.autolimits
  if not _limited(joint.limited, autolimits, _has_range(joint.range)):
    return (
        'the joint is not limited, and jnt_limited is static '
        'in MJX. Give it a range (limited) in the spec.'
    )
  return None


def spring_damper(joint):
  if joint.springdamper[0] or joint.springdamper[1]:
    return (
        'the joint sets springdamper, from which the compiler '
        'derives its stiffness and damping.'
    )
  return None


def muscle(actuator):
  if is_muscle(actuator):
    return (
        'muscle parameters and transmissions feed the '
        "compiler's actuator length-range simulation, which we "
        'do not run on the device.'
    )
  return None


def inherited_ctrlrange(actuator):
  if actuator.inheritrange > 0:
    return (
        'the actuator inherits its ctrlrange from its target ' '(inheritrange).'
    )
  return None


def not_ctrllimited(actuator):
  autolimits = actuator.compiler.autolimits
  has_range = _has_range(actuator.ctrlrange)
  if not _limited(actuator.ctrllimited, autolimits, has_range):
    return (
        'the actuator is not ctrllimited, and that is static '
        'in MJX. Give it a ctrlrange in the spec.'
    )
  return None


def not_forcelimited(actuator):
  autolimits = actuator.compiler.autolimits
  has_range = _has_range(actuator.forcerange)
  if not _limited(actuator.forcelimited, autolimits, has_range):
    return (
        'the actuator is not forcelimited, and that is static '
        'in MJX. Give it a forcerange in the spec.'
    )
  return None


def not_position_like(attr: str) -> Refusal:
  """Refuses `attr` (kp, kv) of actuators that are not position-like."""

  def refusal(actuator):
    if not is_position_like(actuator):
      return (
          f'{attr} is defined for position actuators (fixed gain, '
          'affine bias, gainprm[0] == -biasprm[1]); bind gainprm '
          'and biasprm instead.'
      )
    return None

  return refusal


def dampratio(actuator):
  if actuator.biasprm[2] > 0:
    return (
        'the actuator sets a dampratio (biasprm[2] > 0), from '
        'which the compiler derives its damping.'
    )
  return None


def no_fluid(option):
  if not options.option_has_fluid(option):
    return (
        'the model has no fluid forces (density, viscosity and '
        'wind are zero), which MJX decides statically. Give the '
        'root spec a nonzero option density or viscosity.'
    )
  return None


# -- trace time: the composed model -------------------------------------------


def _error(owner, bound, why):
  return ValueError(f'{owner}: cannot vary {bound.describe}: {why}')


def check_composed(host, plan, bindings, owner: str):
  """Refusals that depend on the composed model.

  Args:
    host: the `context.Host`.
    plan: the `planner.Plan` of the bindings.
    bindings: the `planner.Binding`s.
    owner: the variator's name, for messages.

  Raises:
    ValueError: with the reason.
  """
  m, handles = host.m, host.handles
  _check_inertia_geoms(host, plan, bindings, owner)
  body_of = {
      'body': lambda i: i,
      'geom': lambda i: int(m.geom_bodyid[i]),
      'site': lambda i: int(m.site_bodyid[i]),
  }
  for bound in bindings:
    record = bound.record
    if record.kind in body_of and record.effects & effects.ON_BODY:
      b = body_of[record.kind](bound.obj_id)
      if b > 0:
        check_body(host, bound, b, owner)
    if record.kind == 'option':
      _check_option(host, bound, owner)
    if record.effects & effects.Effect.JOINT_RANGE:
      for a in range(m.nu):
        act = handles['actuator'].get(a)
        if (
            act is not None
            and act.inheritrange > 0
            and m.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT
            and m.actuator_trnid[a, 0] == bound.obj_id
        ):
          raise _error(
              owner,
              bound,
              'an actuator inherits its ctrlrange '
              "from this joint's range (inheritrange).",
          )
  root = handles['body'].get(0)
  if plan.mass_matrix and root is not None and root.compiler.settotalmass > 0:
    raise ValueError(
        f'{owner}: the root spec sets compiler settotalmass, which '
        'rescales every body when any mass changes; varying masses, '
        'inertias, sizes or poses under settotalmass is not supported.'
    )
  if plan.mass_matrix:
    for j in range(m.njnt):
      joint = handles['joint'].get(j)
      if joint is not None and (joint.springdamper[0] or joint.springdamper[1]):
        raise ValueError(
            f'{owner}: joint {joint.name!r} sets springdamper, whose '
            'stiffness and damping the compiler derives from the mass '
            'matrix; varying masses, inertias or poses in this model is '
            'not supported.'
        )
  if plan.length_ranges:
    for a in range(m.nu):
      act = handles['actuator'].get(a)
      if act is not None and is_muscle(act):
        raise ValueError(
            f'{owner}: the model has muscle actuators, whose length '
            'ranges the compiler computes by simulation; varying poses, '
            'sizes, gears or ranges in this model is not supported.'
        )


def _check_inertia_geoms(host, plan, bindings, owner):
  """Bodies whose inertial is re-derived must not infer it from meshes."""
  for b in plan.inertia_bodies:
    body = host.handles['body'][b]
    bound_ipos = any(
        x.record.kind == 'body' and x.record.name == 'ipos' and x.obj_id == b
        for x in bindings
    )
    if bound_ipos or not inertia.infers_inertia(body):
      continue
    for g in host.inertia_geoms(b):
      geom = host.handles['geom'][g]
      if geom.type in geoms.MESHLIKE:
        raise ValueError(
            f'{owner}: body {body.name!r} infers its inertia from a '
            f'mesh geom ({geom.name!r}) too; re-deriving it needs the '
            "mesh's inertia, which the compiled model does not keep. Give "
            'the body an explicit inertial, or vary geoms of another body.'
        )


def check_body(host, bound, b: int, owner: str):
  """Refusals for a binding that changes compiled body `b` (b > 0)."""
  m = host.m
  body = host.handles['body'].get(b)
  effect = bound.record.effects
  # Judge from the compiled model: an attachment frame's handle does not
  # hold the attached entity's geoms and bodies.
  has_children = bool(np.any(np.asarray(m.body_parentid)[b + 1 :] == b))
  if effect & effects.Effect.BODY_INERTIAL and host.infers_from_geoms(b):
    raise _error(
        owner,
        bound,
        'the body infers its mass and inertia from its geoms (here '
        'those of the attached entity), so the compiler ignores its own '
        "mass/inertia. Vary the geoms' mass, density or size instead.",
    )
  # Free-joint alignment moves the body frame to the inertial frame.
  if body is not None and len(body.joints) == 1 and not has_children:
    joint = body.joints[0]
    if joint.type == _Joint.mjJNT_FREE and (
        joint.align == mujoco.mjtAlignFree.mjALIGNFREE_TRUE
        or (
            joint.align == mujoco.mjtAlignFree.mjALIGNFREE_AUTO
            and body.compiler.alignfree
        )
    ):
      raise _error(
          owner,
          bound,
          f'body {body.name!r} has an aligned free '
          'joint (compiler alignfree), which moves the body '
          'frame with its inertia.',
      )
  if int(m.body_simple[b]) == 0:
    return
  simple_why = (
      f'body {host.body_name(b)!r} is '
      'compiled as a "simple" body (its inertial frame is its body frame), '
      "so MJX's mass matrix omits couplings that this variation would "
      'create. Set `simple = 0` on that MjsBody in the spec to vary it.'
  )
  if effect & effects.Effect.INERTIAL_FRAME:
    raise _error(owner, bound, simple_why)
  if effect & effects.Effect.BODY_FRAME and host.copies_body_frame(b):
    raise _error(owner, bound, simple_why)
  if (
      effect & effects.Effect.GEOM_INERTIA
      and body is not None
      and inertia.infers_inertia(body)
  ):
    selected = host.inertia_geoms(b, body.compiler)
    if effect & effects.Effect.GEOM_FRAME or len(selected) > 1:
      raise _error(owner, bound, simple_why)


def _check_option(host, bound, owner):
  compiled = np.asarray(getattr(host.m.opt, bound.record.name), np.float64)
  value = bound.record.spec_value(bound.element)
  if not np.allclose(
      compiled.reshape(value.shape), value, rtol=1e-9, atol=1e-12
  ):
    raise _error(
        owner,
        bound,
        'this MjOption does not hold the compiled '
        f"model's {bound.record.name} ({value} vs {compiled}): bind "
        "the root entity's `mjcf_model.option` (options of "
        'attached entities are not compiled).',
    )
