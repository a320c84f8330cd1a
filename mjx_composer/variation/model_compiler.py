"""A slice of MuJoCo's model compiler, as pure JAX functions, for variations.

We compile an MjSpec once. To vary an MJCF attribute per world and still get
the model that MuJoCo would compile from the edited spec, this module maps
each supported attribute onto the compiled fields it sets and recomputes, on
the device, every field that the compiler derives from it:

* attribute transforms: frames of attached entities and `MjsFrame`s (a
  compiled pose is `frame * local pose`), degrees to radians for joint
  ranges, `fromto`-fixed geom sizes, normalized quaternions;
* geom mass and inertia from size, density or mass (`mjCGeom::SetInertia`),
  and the body inertial frame inferred from its geoms (total mass, centre of
  mass, principal axes by MuJoCo's own Jacobi iteration, `mjuu_eig3`), or an
  explicit inertial, with `boundmass`, `boundinertia` and `balanceinertia`;
* `body_subtreemass`, `geom_rbound`, `geom_aabb`, the qpos0 of free joints;
* `mj_setConst` at qpos0, with MJX's kinematics: `dof_M0`,
  `body_invweight0`, `dof_invweight0`, `tendon_invweight0`,
  `actuator_acc0`, `tendon_length0`, automatic tendon spring lengths,
  camera and light `*_pos0/_poscom0/_mat0/_dir0`, body connect/weld
  `eq_data`, `biasprm[2]` of position actuators given a `dampratio` (MuJoCo
  3.17 uses the reflected inertia `1 / (moment . M^-1 . moment)`), and the
  statistics (`meaninertia`, `meanmass`, `meansize`, `extent`, `center`)
  unless the spec sets them.

The derivations follow MuJoCo's `user_objects.cc` (`mjCGeom::Compile`,
`mjCBody::Compile`, `InertiaFromGeom`), `user_util.cc` (`mjuu_eig3`) and
`engine_setconst.c`, and are checked field by field against the compiler in
`tests/test_variation_model_compiler.py`, which is the reference when the two
disagree (e.g. the dampratio formula above differs from newer sources).

Which of these run is decided statically from the bound attributes, and only
fields that can change are returned (so only they become per-world).

What cannot be made equal is refused when binding (or, when it depends on
the composed model, when reset is traced), with a message: attributes that
change the structure MJX fixes at `put_model` time (static fields such as
`jnt_limited`, `dof_hasfrictionloss`, the mass-matrix sparsity of "simple"
bodies, fluid flags), meshes and height fields, and attributes the compiler
overrides (`fromto` poses, orientation alternatives, `inheritrange`).

Float32 on the device against the compiler's float64 agrees to about 1e-6
relative. Where the answer is not unique the result may differ in a way that
is physically the same: the sign of a quaternion, or the principal axes of an
inertia with (nearly) equal principal moments.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Sequence

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np

from mjx_composer import element_index

_EPS = 1e-14  # mjEPS (user_util.h)
_MINVAL = 1e-15  # mjMINVAL
_MAXVAL = 1e10  # mjMAXVAL

# The class of `MjSpec.option` (not `mujoco.MjOption`, the compiled struct).
SPEC_OPTION = type(mujoco.MjSpec().option)

_Geom = mujoco.mjtGeom
_Joint = mujoco.mjtJoint

# Supported MJCF attributes, by element kind. Values are the shape of the
# attribute as a variation sees it.
ATTRIBUTES = {
    'geom': {
        'size': (3,),
        'rgba': (4,),
        'friction': (3,),
        'mass': (),
        'density': (),
        'pos': (3,),
        'quat': (4,),
        'solref': (2,),
        'solimp': (5,),
    },
    'body': {
        'pos': (3,),
        'quat': (4,),
        'mass': (),
        'inertia': (3,),
        'ipos': (3,),
        'iquat': (4,),
    },
    'site': {'pos': (3,), 'quat': (4,)},
    'joint': {
        'damping': (),
        'stiffness': (),
        'armature': (),
        'frictionloss': (),
        'range': (2,),
    },
    'actuator': {
        'gear': (6,),
        'ctrlrange': (2,),
        'forcerange': (2,),
        'kp': (),
        'kv': (),
        'gainprm': (10,),
        'biasprm': (10,),
    },
    'option': {'gravity': (3,), 'wind': (3,), 'density': (), 'viscosity': ()},
}


def supported_text() -> str:
  """The supported attributes, for error messages."""
  return '; '.join(
      f'{kind}: {", ".join(attrs)}' for kind, attrs in ATTRIBUTES.items()
  )


def kind_of(element) -> str:
  """'option' for an `MjOption`, else the element's kind name."""
  if isinstance(element, SPEC_OPTION):
    return 'option'
  try:
    kind = element_index.element_kind(element).name
  except TypeError as e:
    raise TypeError(
        f'MJCFVariator cannot bind {element!r}: expected an MjSpec element '
        f"handle or the root spec's option. Supported: {supported_text()}."
    ) from e
  if kind not in ATTRIBUTES:
    raise ValueError(
        f'MJCFVariator cannot vary a {kind}. Supported: {supported_text()}.'
    )
  return kind


def spec_value(element, kind: str, attr: str) -> np.ndarray:
  """The attribute's value in the spec, as a float64 array."""
  if kind == 'joint' and attr in ('damping', 'stiffness'):
    return np.array(getattr(element, attr)[0], np.float64)
  if kind == 'actuator' and attr == 'kp':
    return np.array(element.gainprm[0], np.float64)
  if kind == 'actuator' and attr == 'kv':
    return np.array(-element.biasprm[2], np.float64)
  # A copy: MjSpec attributes are views of the spec's memory.
  value = np.array(getattr(element, attr), np.float64)
  return value.reshape(ATTRIBUTES[kind][attr])


def set_spec_value(element, kind: str, attr: str, value):
  """Sets the attribute on the spec element (the inverse of `spec_value`).

  For host-side references: set values, recompose, recompile.
  """
  value = np.asarray(value, np.float64)
  if kind == 'joint' and attr in ('damping', 'stiffness'):
    current = np.array(getattr(element, attr))
    current[0] = value
    setattr(element, attr, current)
  elif kind == 'actuator' and attr == 'kp':
    gain, bias = np.array(element.gainprm), np.array(element.biasprm)
    gain[0], bias[1] = value, -value
    element.gainprm, element.biasprm = gain, bias
  elif kind == 'actuator' and attr == 'kv':
    bias = np.array(element.biasprm)
    bias[2] = -value
    element.biasprm = bias
  elif value.shape == ():
    setattr(element, attr, float(value))
  else:
    setattr(element, attr, value)


def _limited(flag, autolimits: bool, has_range: bool) -> bool:
  if flag == mujoco.mjtLimited.mjLIMITED_TRUE:
    return True
  if flag == mujoco.mjtLimited.mjLIMITED_FALSE:
    return False
  return bool(autolimits and has_range)


def _is_position_like(actuator) -> bool:
  return (
      actuator.gaintype == mujoco.mjtGain.mjGAIN_FIXED
      and actuator.biastype == mujoco.mjtBias.mjBIAS_AFFINE
      and actuator.gainprm[0] == -actuator.biasprm[1]
  )


def _is_muscle(actuator) -> bool:
  return (
      actuator.gaintype == mujoco.mjtGain.mjGAIN_MUSCLE
      or actuator.biastype == mujoco.mjtBias.mjBIAS_MUSCLE
  )


def _option_has_fluid(opt) -> bool:
  return bool(opt.density > 0 or opt.viscosity > 0 or np.any(opt.wind))


_MESHLIKE = (_Geom.mjGEOM_MESH, _Geom.mjGEOM_SDF, _Geom.mjGEOM_HFIELD)
_QUAT_ORIENTATION = mujoco.mjtOrientation.mjORIENTATION_QUAT
_INERTIA_ATTRS = ('mass', 'inertia', 'ipos', 'iquat')


def check_attribute(element, attr: str) -> str:
  """Bind-time checks of one attribute; returns the element kind.

  Raises:
    ValueError: with the reason and what is supported instead.
  """
  kind = kind_of(element)
  if attr not in ATTRIBUTES[kind]:
    raise ValueError(
        f'MJCFVariator cannot vary {kind} attribute {attr!r}: it is not one '
        'that maps onto compiled model fields we can re-derive on the device. '
        f'Supported {kind} attributes: {sorted(ATTRIBUTES[kind])}. '
        f'(All supported: {supported_text()}.) To write a compiled field '
        'without re-deriving anything, use PhysicsVariator.'
    )
  name = getattr(element, 'name', '') or ''
  what = f'{kind} {name!r}' if name else kind
  refuse = lambda why: ValueError(
      f'MJCFVariator cannot vary {attr!r} of ' f'{what}: {why}'
  )
  if kind == 'geom':
    if element.type in _MESHLIKE and attr in (
        'size',
        'mass',
        'density',
        'pos',
        'quat',
    ):
      raise refuse(
          'mesh, SDF and height-field geoms take their size, '
          'inertia and frame from the asset, which would need '
          're-meshing. Vary a primitive geom instead.'
      )
    if not np.isnan(element.fromto[0]) and attr in ('pos', 'quat'):
      raise refuse(
          'the geom is placed by `fromto`, which the compiler uses '
          'instead of pos/quat.'
      )
    if attr == 'quat' and element.alt.type != _QUAT_ORIENTATION:
      raise refuse(
          'the geom orientation is given by an alternative '
          '(euler/axisangle/xyaxes/zaxis), which the compiler uses '
          'instead of quat.'
      )
    if attr == 'size' and element.fluid_ellipsoid > 0:
      raise refuse(
          'the geom has fluid_ellipsoid interaction, whose '
          'coefficients (geom_fluid) are static in MJX.'
      )
  elif kind == 'body':
    if name == 'world':
      raise refuse(
          'the world body does not vary. To move an attached '
          'entity, bind its attachment frame '
          '(entity.attachment_frame).'
      )
    if attr == 'quat' and element.alt.type != _QUAT_ORIENTATION:
      raise refuse(
          'the body orientation is given by an alternative '
          '(euler/axisangle/xyaxes/zaxis), which the compiler uses '
          'instead of quat.'
      )
    if attr in ('inertia', 'iquat') and not np.isnan(element.fullinertia[0]):
      raise refuse('the body inertia is given by fullinertia.')
    if attr == 'iquat' and element.ialt.type != _QUAT_ORIENTATION:
      raise refuse('the inertial orientation is given by an alternative.')
    if (
        attr in _INERTIA_ATTRS
        and _body_infers_inertia(element)
        and any(
            _geom_in_inertia_group(g, element.compiler) for g in element.geoms
        )
    ):
      raise refuse(
          'the body infers its mass and inertia from its geoms (the '
          "compiler ignores the body's own mass/inertia). Vary the geoms' "
          'mass, density or size, or give the body an explicit inertial '
          '(set its ipos, mass and inertia in the spec).'
      )
  elif kind == 'site':
    if attr == 'quat' and element.alt.type != _QUAT_ORIENTATION:
      raise refuse(
          'the site orientation is given by an alternative '
          '(euler/axisangle/xyaxes/zaxis), which the compiler uses '
          'instead of quat.'
      )
  elif kind == 'joint':
    if attr == 'frictionloss' and element.frictionloss <= 0:
      raise refuse(
          'the compiled joint has no friction loss, and MJX fixes '
          'at put_model time which dofs have friction-loss '
          'constraints. Give it a nonzero frictionloss in the spec '
          '(and keep varied values positive).'
      )
    if attr == 'range':
      if element.type == _Joint.mjJNT_FREE:
        raise refuse('free joints have no range.')
      has_range = not (element.range[0] == 0 and element.range[1] == 0)
      if not _limited(element.limited, element.compiler.autolimits, has_range):
        raise refuse(
            'the joint is not limited, and jnt_limited is static '
            'in MJX. Give it a range (limited) in the spec.'
        )
    if attr in ('damping', 'stiffness') and (
        element.springdamper[0] or element.springdamper[1]
    ):
      raise refuse(
          'the joint sets springdamper, from which the compiler '
          'derives its stiffness and damping.'
      )
  elif kind == 'actuator':
    if _is_muscle(element) and attr in ('gear', 'gainprm', 'biasprm'):
      raise refuse(
          'muscle parameters and transmissions feed the '
          "compiler's actuator length-range simulation, which we "
          'do not run on the device.'
      )
    if attr == 'ctrlrange':
      if element.inheritrange > 0:
        raise refuse(
            'the actuator inherits its ctrlrange from its target '
            '(inheritrange).'
        )
      has_range = not (element.ctrlrange[0] == 0 and element.ctrlrange[1] == 0)
      if not _limited(
          element.ctrllimited, element.compiler.autolimits, has_range
      ):
        raise refuse(
            'the actuator is not ctrllimited, and that is static '
            'in MJX. Give it a ctrlrange in the spec.'
        )
    if attr == 'forcerange':
      has_range = not (
          element.forcerange[0] == 0 and element.forcerange[1] == 0
      )
      if not _limited(
          element.forcelimited, element.compiler.autolimits, has_range
      ):
        raise refuse(
            'the actuator is not forcelimited, and that is static '
            'in MJX. Give it a forcerange in the spec.'
        )
    if attr in ('kp', 'kv') and not _is_position_like(element):
      raise refuse(
          f'{attr} is defined for position actuators (fixed gain, '
          'affine bias, gainprm[0] == -biasprm[1]); bind gainprm '
          'and biasprm instead.'
      )
    if attr == 'kv' and element.biasprm[2] > 0:
      raise refuse(
          'the actuator sets a dampratio (biasprm[2] > 0), from '
          'which the compiler derives its damping.'
      )
  elif kind == 'option':
    if attr in ('density', 'viscosity', 'wind') and not _option_has_fluid(
        element
    ):
      raise refuse(
          'the model has no fluid forces (density, viscosity and '
          'wind are zero), which MJX decides statically. Give the '
          'root spec a nonzero option density or viscosity.'
      )
  return kind


def _body_infers_inertia(body) -> bool:
  """Whether the compiler infers this body's inertial from its geoms."""
  mode = body.compiler.inertiafromgeom
  return mode == mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_TRUE or (
      mode == mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_AUTO
      and np.isnan(body.ipos[0])
  )


def _geom_in_inertia_group(geom, compiler) -> bool:
  low, high = compiler.inertiagrouprange
  return low <= geom.group <= high


# -------------------------------------------------------------------------
# Small float64 host helpers (constants) and JAX helpers.


def _quat_mul_np(a, b):
  w1, x1, y1, z1 = a
  w2, x2, y2, z2 = b
  return np.array(
      [
          w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
          w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
          w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
          w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
      ]
  )


def _quat_to_mat_np(q):
  mat = np.zeros(9)
  mujoco.mju_quat2Mat(mat, np.asarray(q, np.float64))
  return mat.reshape(3, 3)


def _normalize_quat_np(q):
  q = np.asarray(q, np.float64)
  n = np.linalg.norm(q)
  if n < _EPS:
    return q
  return q / n if abs(n - 1) > _EPS else q


def _frame_between(compiled_pos, compiled_quat, local_pos, local_quat):
  """(pos, quat) of F with compiled = F * local (MuJoCo's frameaccum)."""
  local_quat = _normalize_quat_np(local_quat)
  conj = local_quat * np.array([1, -1, -1, -1])
  fq = _quat_mul_np(np.asarray(compiled_quat, np.float64), conj)
  fp = np.asarray(compiled_pos, np.float64) - _quat_to_mat_np(fq) @ np.asarray(
      local_pos, np.float64
  )
  return fp, fq


def _quat_mul(a, b):
  w1, x1, y1, z1 = a[0], a[1], a[2], a[3]
  w2, x2, y2, z2 = b[0], b[1], b[2], b[3]
  return jnp.stack(
      [
          w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
          w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
          w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
          w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
      ]
  )


def _quat_to_mat(q):
  w, x, y, z = q[0], q[1], q[2], q[3]
  return jnp.array(
      [
          [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
          [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
          [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
      ]
  )


def _normalize_quat(q):
  """MuJoCo's `mjuu_normvec`: leave (near-)unit and (near-)zero alone."""
  norm = jnp.sqrt(jnp.sum(q * q))
  scale = jnp.where(
      (norm < _EPS) | (jnp.abs(norm - 1) <= _EPS),
      1.0,
      1.0 / jnp.maximum(norm, _EPS),
  )
  return q * scale


def _apply_frame(frame, pos=None, quat=None):
  """Compiled pose of a local pose under a constant frame (pos, quat)."""
  fp, fq = frame
  out = []
  if pos is not None:
    rot = jnp.asarray(_quat_to_mat_np(fq), pos.dtype)
    out.append(jnp.asarray(fp, pos.dtype) + rot @ pos)
  if quat is not None:
    out.append(_quat_mul(jnp.asarray(fq, quat.dtype), _normalize_quat(quat)))
  return out[0] if len(out) == 1 else tuple(out)


def eig3(mat, iterations=24):
  """Principal moments and axes of a symmetric 3x3 matrix, as MuJoCo does.

  A float32 port of `mjuu_eig3`: Jacobi rotations accumulated in a
  quaternion from the identity, then eigenvalues sorted in decreasing order
  by quarter turns. The termination threshold is relative here (float32
  cannot reach the compiler's absolute 1e-12; an off-diagonal below 1e-7 of
  the diagonal is float32 noise), and a fixed iteration budget with a
  converged flag replaces the loop so it vmaps.

  Returns:
    `(eigenvalues (3,), quaternion (4,))`, the quaternion taking the
    principal frame to the frame of `mat`.
  """
  dtype = mat.dtype
  scale = jnp.maximum(jnp.max(jnp.abs(jnp.diagonal(mat))), 1e-30)
  tol = 1e-7 * scale

  def body(_, carry):
    quat, done = carry
    r = _quat_to_mat(quat)
    d = r.T @ mat @ r
    a01, a02, a12 = jnp.abs(d[0, 1]), jnp.abs(d[0, 2]), jnp.abs(d[1, 2])
    case0 = (a01 > a02) & (a01 > a12)
    case1 = jnp.logical_not(case0) & (a02 > a12)
    rk = jnp.where(case0 | case1, 0, 1)
    ck = jnp.where(case0, 1, 2)
    rotk = jnp.where(case0, 2, jnp.where(case1, 1, 0))
    off = d[rk, ck]
    stop = jnp.abs(off) < tol
    safe_off = jnp.where(stop, 1.0, off)
    tau = (d[ck, ck] - d[rk, rk]) / (2 * safe_off)
    root = jnp.sqrt(1 + tau * tau)
    t = jnp.where(tau >= 0, 1.0 / (tau + root), -1.0 / (-tau + root))
    c = 1.0 / jnp.sqrt(1 + t * t)
    # MuJoCo's half-angle sine, sign(tau) * -sqrt(0.5 - 0.5 c), written as
    # -sin(theta) / sqrt(2 (1 + c)): float32 rounds c to 1 below ~3e-4 rad,
    # which would stop the iteration that early.
    comp = -(t * c) / jnp.sqrt(2 * (1 + c))
    comp = jnp.where(rotk == 1, -comp, comp)
    vec = jnp.zeros(3, dtype).at[rotk].set(comp)
    rot = jnp.concatenate([jnp.sqrt(1.0 - comp * comp)[None], vec])
    rot = rot / jnp.linalg.norm(rot)
    new = _quat_mul(quat, rot)
    new = new / jnp.linalg.norm(new)
    done = done | stop
    return jnp.where(done, quat, new), done

  quat0 = jnp.array([1.0, 0.0, 0.0, 0.0], dtype)
  quat, _ = jax.lax.fori_loop(0, iterations, body, (quat0, jnp.zeros((), bool)))
  r = _quat_to_mat(quat)
  eigval = jnp.diagonal(r.T @ mat @ r)
  # Sort decreasing (bubble sort 0, 1, 0), rotating the frame by quarter
  # turns; like MuJoCo, only swap values that differ (here: relatively).
  half = math.sqrt(0.5)
  swap_tol = 1e-6 * scale
  for j in range(3):
    j1 = j % 2
    swap = eigval[j1] + swap_tol < eigval[j1 + 1]
    swapped = eigval.at[j1].set(eigval[j1 + 1]).at[j1 + 1].set(eigval[j1])
    turn = jnp.zeros(4, dtype).at[0].set(half).at[(j1 + 2) % 3 + 1].set(half)
    turned = _quat_mul(quat, turn)
    turned = turned / jnp.linalg.norm(turned)
    eigval = jnp.where(swap, swapped, eigval)
    quat = jnp.where(swap, turned, quat)
  return eigval, quat


# -------------------------------------------------------------------------
# Geom volume, mass and inertia (mjCGeom::GetVolume, SetInertia).


def _geom_volume(gtype, shell, size):
  r, h = size[0], size[1]
  if gtype == _Geom.mjGEOM_SPHERE:
    return 4 * math.pi * r**2 if shell else 4 * math.pi * r**3 / 3
  if gtype == _Geom.mjGEOM_CAPSULE:
    height = 2 * h
    if shell:
      return 4 * math.pi * r * r + 2 * math.pi * r * height
    return math.pi * (r * r * height + 4 * r**3 / 3)
  if gtype == _Geom.mjGEOM_CYLINDER:
    height = 2 * h
    if shell:
      return 2 * math.pi * r * r + 2 * math.pi * r * height
    return math.pi * r * r * height
  if gtype == _Geom.mjGEOM_ELLIPSOID:
    if shell:
      p = 1.6075
      tmp = (
          (size[0] * size[1]) ** p
          + (size[1] * size[2]) ** p
          + (size[2] * size[0]) ** p
      )
      return 4 * math.pi * (tmp / 3) ** (1 / p)
    return 4 * math.pi * size[0] * size[1] * size[2] / 3
  if gtype == _Geom.mjGEOM_BOX:
    if shell:
      return 8 * (size[0] * size[1] + size[1] * size[2] + size[2] * size[0])
    return size[0] * size[1] * size[2] * 8
  return jnp.zeros((), size.dtype)


def _geom_inertia(gtype, shell, size, mass):
  """Principal inertia (geom frame) of a primitive geom of `mass`."""
  zeros = jnp.zeros((), size.dtype)
  if gtype == _Geom.mjGEOM_SPHERE:
    i = (2 / 3 if shell else 2 / 5) * mass * size[0] ** 2
    return jnp.stack([i, i, i])
  if gtype == _Geom.mjGEOM_CAPSULE:
    r, half = size[0], size[1]
    height = 2 * half
    if not shell:
      sphere_mass = mass * 4 * r / (4 * r + 3 * height)
      cyl_mass = mass - sphere_mass
      ixy = cyl_mass * (3 * r * r + height * height) / 12
      iz = cyl_mass * r * r / 2
      sphere_i = 2 * sphere_mass * r * r / 5
      ixy = ixy + sphere_i + sphere_mass * height * (3 * r + 2 * height) / 8
      return jnp.stack([ixy, ixy, iz + sphere_i])
    a_sphere = 4 * math.pi * r * r
    a_cyl = 2 * math.pi * r * height
    sphere_mass = mass * a_sphere / (a_sphere + a_cyl)
    cyl_mass = mass - sphere_mass
    ixy = cyl_mass * (6 * r * r + height * height) / 12
    iz = cyl_mass * r * r
    sphere_i = 2 * sphere_mass * r * r / 3
    hs_com = r / 2
    hs_pos = half + hs_com
    ixy = ixy + sphere_i + sphere_mass * (hs_pos * hs_pos - hs_com * hs_com)
    return jnp.stack([ixy, ixy, iz + sphere_i])
  if gtype == _Geom.mjGEOM_CYLINDER:
    r, half = size[0], size[1]
    height = 2 * half
    if not shell:
      ixy = mass * (3 * r * r + height * height) / 12
      return jnp.stack([ixy, ixy, mass * r * r / 2])
    a_disk = math.pi * r * r
    a_cyl = 2 * math.pi * r * height
    mass_disk = mass * a_disk / (2 * a_disk + a_cyl)
    mass_cyl = mass - 2 * mass_disk
    ixy = mass_cyl * (6 * r * r + height * height) / 12
    iz = mass_cyl * r * r
    disk_x = mass_disk * r * r / 4 + mass_disk * half * half
    disk_z = mass_disk * r * r / 2
    return jnp.stack([ixy + 2 * disk_x, ixy + 2 * disk_x, iz + 2 * disk_z])
  if gtype == _Geom.mjGEOM_ELLIPSOID:
    s00, s11, s22 = size[0] ** 2, size[1] ** 2, size[2] ** 2
    if not shell:
      return jnp.stack(
          [
              mass * (s11 + s22) / 5,
              mass * (s00 + s22) / 5,
              mass * (s00 + s11) / 5,
          ]
      )
    eps = 1e-6
    va = 4 * math.pi * size[0] * size[1] * size[2] / 3
    ae, be, ce = size[0] + eps, size[1] + eps, size[2] + eps
    vb = 4 * math.pi * ae * be * ce / 3
    density = mass / (vb - va)
    ma, mb = va * density, vb * density
    ia = jnp.stack([ma * (s11 + s22), ma * (s00 + s22), ma * (s00 + s11)]) / 5
    ib = (
        jnp.stack(
            [
                mb * (be * be + ce * ce),
                mb * (ae * ae + ce * ce),
                mb * (ae * ae + be * be),
            ]
        )
        / 5
    )
    return ib - ia
  if gtype == _Geom.mjGEOM_BOX:
    s00, s11, s22 = size[0] ** 2, size[1] ** 2, size[2] ** 2
    if not shell:
      return jnp.stack(
          [
              mass * (s11 + s22) / 3,
              mass * (s00 + s22) / 3,
              mass * (s00 + s11) / 3,
          ]
      )
    lx, ly, lz = 2 * size[0], 2 * size[1], 2 * size[2]
    a0, a1, a2 = lx * ly, ly * lz, lz * lx
    total = 2 * (a0 + a1 + a2)
    m0, m1, m2 = mass * a0 / total, mass * a1 / total, mass * a2 / total
    ix = 2 * (
        m0 * s22
        + m2 * s11
        + m0 * ly * ly / 12
        + m1 * (ly * ly + lz * lz) / 12
        + m2 * lz * lz / 12
    )
    iy = 2 * (
        m0 * s22
        + m1 * s00
        + m0 * lx * lx / 12
        + m1 * lz * lz / 12
        + m2 * (lx * lx + lz * lz) / 12
    )
    iz = 2 * (
        m1 * s00
        + m2 * s11
        + m0 * (lx * lx + ly * ly) / 12
        + m1 * ly * ly / 12
        + m2 * lx * lx / 12
    )
    return jnp.stack([ix, iy, iz])
  return jnp.stack([zeros, zeros, zeros])


def _geom_mass_inertia(gtype, shell, size, mass, density):
  """`(mass_, inertia)` as mjCGeom::Compile infers them.

  `mass` is None when the spec leaves it undefined (density decides).
  """
  volume = _geom_volume(gtype, shell, size)
  if mass is not None:
    ok = (mass != 0) & (volume > _EPS)
    mass_ = jnp.where(ok, mass, 0.0)
  else:
    ok = density != 0
    mass_ = jnp.where(ok, density * volume, 0.0)
  inertia = jnp.where(ok, _geom_inertia(gtype, shell, size, mass_), 0.0)
  return mass_, inertia


def _geom_rbound(gtype, size):
  if gtype == _Geom.mjGEOM_SPHERE:
    return size[0]
  if gtype == _Geom.mjGEOM_CAPSULE:
    return size[0] + size[1]
  if gtype == _Geom.mjGEOM_CYLINDER:
    return jnp.sqrt(size[0] ** 2 + size[1] ** 2)
  if gtype == _Geom.mjGEOM_ELLIPSOID:
    return jnp.max(size)
  if gtype == _Geom.mjGEOM_BOX:
    return jnp.sqrt(jnp.sum(size * size))
  return jnp.zeros((), size.dtype)


def _geom_aabb(gtype, size):
  """(center, half-size) as mjCGeom::ComputeAABB, for primitive geoms."""
  zero = jnp.zeros((), size.dtype)
  if gtype == _Geom.mjGEOM_SPHERE:
    half = jnp.stack([size[0]] * 3)
  elif gtype == _Geom.mjGEOM_CAPSULE:
    half = jnp.stack([size[0], size[0], size[0] + size[1]])
  elif gtype == _Geom.mjGEOM_CYLINDER:
    half = jnp.stack([size[0], size[0], size[1]])
  elif gtype == _Geom.mjGEOM_PLANE:
    return jnp.asarray(
        [0, 0, -_MAXVAL / 2, _MAXVAL, _MAXVAL, _MAXVAL / 2], size.dtype
    )
  else:
    half = size
  return jnp.concatenate([jnp.stack([zero, zero, zero]), half])


# -------------------------------------------------------------------------
# The compiler.


@dataclasses.dataclass
class _Bound:
  """One binding resolved against the compiled model."""

  element: Any
  kind: str
  attr: str
  obj_id: int  # compiled id (-1 for the option)
  describe: str


class ModelCompiler:
  """Derives the compiled fields of a model from varied MJCF attributes.

  Built once per compiled model (at trace time) from the bound attributes;
  calling it with one value per binding returns the model fields to replace.

  Args:
    index: the environment's `ElementIndex` (compiled host model and the
      element handles of every entity).
    bindings: `(element, attr, description)` per binding.
    owner: the variator's name, for messages.
  """

  def __init__(
      self,
      index,
      bindings: Sequence[tuple[Any, str, str]],
      owner: str = 'MJCFVariator',
  ):
    self._owner = owner
    self._m = index.mj_model
    self._handles = index.handles_by_id()
    self._bound = []
    for element, attr, describe in bindings:
      kind = kind_of(element)
      obj_id = -1
      if kind != 'option':
        try:
          obj_id = index.element_id(element_index.KINDS_BY_NAME[kind], element)
        except (ValueError, KeyError) as e:
          raise ValueError(
              f'{owner}: cannot apply the variation bound to '
              f'{describe}: {e}'
          ) from e
      self._bound.append(_Bound(element, kind, attr, obj_id, describe))
    self.initial_values = [
        spec_value(b.element, b.kind, b.attr).astype(np.float32)
        for b in self._bound
    ]
    self._auto = None  # which statistics the compiler computed (lazy)
    self._analyse()

  # -- static analysis ------------------------------------------------------

  def _error(self, bound: _Bound, why: str):
    return ValueError(f'{self._owner}: cannot vary {bound.describe}: {why}')

  def _analyse(self):
    m = self._m
    by = lambda kind, attrs: [
        b for b in self._bound if b.kind == kind and b.attr in attrs
    ]
    self._geom_size = {b.obj_id for b in by('geom', ('size',))}
    self._geom_mass = {
        b.obj_id for b in by('geom', ('mass', 'density', 'size'))
    }
    self._geom_pose = {b.obj_id for b in by('geom', ('pos', 'quat'))}
    self._body_pose = {b.obj_id for b in by('body', ('pos', 'quat'))}
    self._inertial_bound = {b.obj_id for b in by('body', _INERTIA_ATTRS)}
    self._site_pose = {b.obj_id for b in by('site', ('pos', 'quat'))}
    self._armature = bool(by('joint', ('armature',)))
    self._gear = bool(by('actuator', ('gear',)))
    self._gains = {
        b.obj_id for b in by('actuator', ('kp', 'kv', 'gainprm', 'biasprm'))
    }

    body_geoms = {}
    for g in range(m.ngeom):
      body_geoms.setdefault(int(m.geom_bodyid[g]), []).append(g)
    self._body_geoms = body_geoms

    # Bodies whose inertial frame is recomputed.
    inertia_bodies = set(self._inertial_bound)
    for g in self._geom_mass | self._geom_pose:
      b = int(m.geom_bodyid[g])
      body = self._handles['body'].get(b)
      if b > 0 and body is not None and _body_infers_inertia(body):
        inertia_bodies.add(b)
    # Bodies whose inertial copies the body pose (no geoms to infer from).
    for b in self._body_pose:
      if self._copies_body_frame(b):
        inertia_bodies.add(b)
    self._inertia_bodies = sorted(inertia_bodies)
    for b in self._inertia_bodies:
      body = self._handles['body'][b]
      if 'ipos' in self._bound_attrs('body', b) or not _body_infers_inertia(
          body
      ):
        continue
      for g in self._body_geoms.get(b, ()):
        geom = self._handles['geom'][g]
        if geom.type in _MESHLIKE and _geom_in_inertia_group(
            geom, body.compiler
        ):
          raise ValueError(
              f'{self._owner}: body {body.name!r} infers its inertia from a '
              f'mesh geom ({geom.name!r}) too; re-deriving it needs the '
              "mesh's inertia, which the compiled model does not keep. Give "
              'the body an explicit inertial, or vary geoms of another body.'
          )

    self._inertia_changed = bool(self._inertia_bodies)
    self._pose_changed = bool(self._body_pose)
    self._m_changed = (
        self._inertia_changed or self._armature or self._pose_changed
    )
    self._kinematics_changed = (
        self._pose_changed
        or self._inertia_changed
        or bool(self._geom_pose)
        or bool(self._site_pose)
        or bool(self._geom_size)
    )
    self._check_structure()

  def _bound_attrs(self, kind: str, obj_id: int) -> set[str]:
    return {
        b.attr for b in self._bound if b.kind == kind and b.obj_id == obj_id
    }

  def _copies_body_frame(self, b: int) -> bool:
    """Whether the body's inertial frame is its (local) body frame."""
    body = self._handles['body'].get(b)
    if body is None or not np.isnan(body.ipos[0]):
      return False
    if not _body_infers_inertia(body):
      return True
    return not any(
        _geom_in_inertia_group(self._handles['geom'][g], body.compiler)
        for g in self._body_geoms.get(b, ())
    )

  def _check_structure(self):
    """Trace-time refusals that depend on the composed model."""
    m = self._m
    root = self._handles['body'].get(0)
    mass_affecting = self._m_changed
    for bound in self._bound:
      b = None
      if bound.kind == 'body':
        b = bound.obj_id
      elif bound.kind == 'geom' and bound.attr in (
          'pos',
          'quat',
          'size',
          'mass',
          'density',
      ):
        b = int(m.geom_bodyid[bound.obj_id])
      elif bound.kind == 'site':
        b = int(m.site_bodyid[bound.obj_id])
      if b is not None and b > 0:
        self._check_body(bound, b)
      if bound.kind == 'option':
        self._check_option(bound)
      if bound.kind == 'joint' and bound.attr == 'range':
        for a in range(m.nu):
          act = self._handles['actuator'].get(a)
          if (
              act is not None
              and act.inheritrange > 0
              and m.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT
              and m.actuator_trnid[a, 0] == bound.obj_id
          ):
            raise self._error(
                bound,
                'an actuator inherits its ctrlrange '
                "from this joint's range (inheritrange).",
            )
    if mass_affecting and root is not None and root.compiler.settotalmass > 0:
      raise ValueError(
          f'{self._owner}: the root spec sets compiler settotalmass, which '
          'rescales every body when any mass changes; varying masses, '
          'inertias, sizes or poses under settotalmass is not supported.'
      )
    if mass_affecting:
      for j in range(m.njnt):
        joint = self._handles['joint'].get(j)
        if joint is not None and (
            joint.springdamper[0] or joint.springdamper[1]
        ):
          raise ValueError(
              f'{self._owner}: joint {joint.name!r} sets springdamper, whose '
              'stiffness and damping the compiler derives from the mass '
              'matrix; varying masses, inertias or poses in this model is '
              'not supported.'
          )
    geometric = (
        self._kinematics_changed
        or self._gear
        or bool(
            [b for b in self._bound if b.kind == 'joint' and b.attr == 'range']
        )
    )
    if geometric:
      for a in range(m.nu):
        act = self._handles['actuator'].get(a)
        if act is not None and _is_muscle(act):
          raise ValueError(
              f'{self._owner}: the model has muscle actuators, whose length '
              'ranges the compiler computes by simulation; varying poses, '
              'sizes, gears or ranges in this model is not supported.'
          )

  def _check_body(self, bound: _Bound, b: int):
    m = self._m
    body = self._handles['body'].get(b)
    # Judge from the compiled model: an attachment frame's handle does not
    # hold the attached entity's geoms and bodies.
    has_children = bool(np.any(np.asarray(m.body_parentid)[b + 1 :] == b))
    if (
        bound.kind == 'body'
        and bound.attr in _INERTIA_ATTRS
        and body is not None
        and _body_infers_inertia(body)
        and any(
            _geom_in_inertia_group(self._handles['geom'][g], body.compiler)
            for g in self._body_geoms.get(b, ())
        )
    ):
      raise self._error(
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
        raise self._error(
            bound,
            f'body {body.name!r} has an aligned free '
            'joint (compiler alignfree), which moves the body '
            'frame with its inertia.',
        )
    if int(m.body_simple[b]) == 0:
      return
    attr = bound.attr
    simple_why = (
        f'body {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b)!r} is '
        'compiled as a "simple" body (its inertial frame is its body frame), '
        "so MJX's mass matrix omits couplings that this variation would "
        'create. Set `simple = 0` on that MjsBody in the spec to vary it.'
    )
    if bound.kind == 'body' and attr in ('ipos', 'iquat'):
      raise self._error(bound, simple_why)
    if (
        bound.kind == 'body'
        and attr in ('pos', 'quat')
        and (self._copies_body_frame(b))
    ):
      raise self._error(bound, simple_why)
    if bound.kind == 'geom' and body is not None and _body_infers_inertia(body):
      selected = [
          g
          for g in self._body_geoms.get(b, ())
          if _geom_in_inertia_group(self._handles['geom'][g], body.compiler)
      ]
      if attr in ('pos', 'quat') or len(selected) > 1:
        raise self._error(bound, simple_why)

  def _check_option(self, bound: _Bound):
    compiled = np.asarray(getattr(self._m.opt, bound.attr), np.float64)
    value = spec_value(bound.element, 'option', bound.attr)
    if not np.allclose(
        compiled.reshape(value.shape), value, rtol=1e-9, atol=1e-12
    ):
      raise self._error(
          bound,
          'this MjOption does not hold the compiled '
          f"model's {bound.attr} ({value} vs {compiled}): bind "
          "the root entity's `mjcf_model.option` (options of "
          'attached entities are not compiled).',
      )

  # -- the device computation -----------------------------------------------

  def __call__(self, model: mjx.Model, values: Sequence[jax.Array]) -> dict:
    """The model fields to replace, for one world.

    Args:
      model: the world's current mjx.Model (fields that are not recomputed
        are read from it).
      values: one value per binding, in the attribute's spec units.

    Returns:
      `{field name: new value}`; `opt` and `stat` come as whole structs.
    """
    m = self._m
    fields = {}

    def get(name):
      return fields[name] if name in fields else getattr(model, name)

    def put(name, index, value):
      old = get(name)
      fields[name] = old.at[index].set(jnp.asarray(value, old.dtype))

    geom_vals = {}
    body_vals = {}
    act_vals = {}
    opt_updates = {}
    for bound, value in zip(self._bound, values):
      kind, attr, i = bound.kind, bound.attr, bound.obj_id
      value = jnp.asarray(value, jnp.float32)
      if kind == 'geom':
        geom_vals.setdefault(i, {})[attr] = value
        if attr in ('rgba', 'friction', 'solref', 'solimp'):
          put(f'geom_{attr}', i, value)
      elif kind == 'body':
        body_vals.setdefault(i, {})[attr] = value
      elif kind == 'site':
        site = self._handles['site'][i]
        frame = _frame_between(
            m.site_pos[i], m.site_quat[i], site.pos, site.quat
        )
        if attr == 'pos':
          put('site_pos', i, _apply_frame(frame, pos=value))
        else:
          put('site_quat', i, _apply_frame(frame, quat=value))
      elif kind == 'joint':
        dofs = _dof_slice(m, i)
        if attr in ('damping', 'armature', 'frictionloss'):
          put(f'dof_{attr}', dofs, value)
        elif attr == 'stiffness':
          put('jnt_stiffness', i, value)
        elif attr == 'range':
          joint = self._handles['joint'][i]
          if joint.compiler.degree and joint.type in (
              _Joint.mjJNT_HINGE,
              _Joint.mjJNT_BALL,
          ):
            value = value * (math.pi / 180)
          put('jnt_range', i, value)
      elif kind == 'actuator':
        act_vals.setdefault(i, {})[attr] = value
        if attr in ('gear', 'ctrlrange', 'forcerange', 'gainprm', 'biasprm'):
          put(f'actuator_{attr}', i, value)
        elif attr == 'kp':
          put('actuator_gainprm', (i, 0), value)
          put('actuator_biasprm', (i, 1), -value)
        elif attr == 'kv':
          put('actuator_biasprm', (i, 2), -value)
      elif kind == 'option':
        opt_updates[attr] = value

    self._geoms(geom_vals, put)
    self._bodies(body_vals, geom_vals, get, put)
    if self._inertia_changed:
      fields['body_subtreemass'] = self._subtreemass(get('body_mass'))
    if (
        self._m_changed
        or self._kinematics_changed
        or self._gear
        or (self._gains and self._dampratio_actuators())
    ):
      self._set_const(model, fields, get, act_vals)
    if opt_updates:
      fields['opt'] = model.opt.replace(**opt_updates)
    return fields

  # -- geoms ------------------------------------------------------------------

  def _geoms(self, geom_vals, put):
    m = self._m
    for g, vals in geom_vals.items():
      geom = self._handles['geom'][g]
      gtype = int(m.geom_type[g])
      if 'size' in vals:
        size = self._compiled_size(g, geom, vals['size'])
        put('geom_size', g, size)
        put('geom_rbound', g, _geom_rbound(gtype, size))
        put('geom_aabb', g, _geom_aabb(gtype, size))
      if 'pos' in vals or 'quat' in vals:
        frame = _frame_between(
            m.geom_pos[g], m.geom_quat[g], geom.pos, geom.quat
        )
        if 'pos' in vals:
          put('geom_pos', g, _apply_frame(frame, pos=vals['pos']))
        if 'quat' in vals:
          put('geom_quat', g, _apply_frame(frame, quat=vals['quat']))

  def _compiled_size(self, g, geom, size):
    """The compiled size: `fromto` fixes the length (and box/ellipsoid y)."""
    if np.isnan(geom.fromto[0]):
      return size
    length = float(
        self._m.geom_size[
            g,
            2 if geom.type in (_Geom.mjGEOM_BOX, _Geom.mjGEOM_ELLIPSOID) else 1,
        ]
    )
    if geom.type in (_Geom.mjGEOM_BOX, _Geom.mjGEOM_ELLIPSOID):
      return jnp.stack([size[0], size[0], jnp.asarray(length, size.dtype)])
    return size.at[1].set(length)

  def _geom_inertial(self, g, geom_vals, get):
    """(mass_, principal inertia, compiled pos, compiled quat) of a geom."""
    m = self._m
    geom = self._handles['geom'][g]
    vals = geom_vals.get(g, {})
    gtype = int(m.geom_type[g])
    shell = geom.typeinertia == mujoco.mjtGeomInertia.mjINERTIA_SHELL
    dtype = jnp.float32
    # Unbound geoms: the world's current size (another variator's, or the
    # compiled one); their mass and density can only come from the spec.
    size = (
        self._compiled_size(g, geom, vals['size'])
        if 'size' in vals
        else get('geom_size')[g]
    )
    if 'mass' in vals:
      mass = vals['mass']
    elif not np.isnan(geom.mass):
      mass = jnp.asarray(geom.mass, dtype)
    else:
      mass = None
    density = vals.get('density', jnp.asarray(geom.density, dtype))
    if gtype in _MESHLIKE:
      # A guard: `_analyse` refuses this already. The compiler derives mesh
      # inertia from the asset, which the compiled model does not keep.
      body = mujoco.mj_id2name(
          m, mujoco.mjtObj.mjOBJ_BODY, int(m.geom_bodyid[g])
      )
      raise ValueError(
          f'{self._owner}: body {body!r} infers its inertia from a mesh geom '
          'as well; varying its other geoms would need the mesh inertia, '
          'which the compiled model does not keep.'
      )
    mass_, inertia = _geom_mass_inertia(gtype, shell, size, mass, density)
    pos = get('geom_pos')[g]
    quat = get('geom_quat')[g]
    return mass_, inertia, pos, quat

  # -- bodies -----------------------------------------------------------------

  def _bodies(self, body_vals, geom_vals, get, put):
    m = self._m
    dtype = jnp.float32
    for b in sorted(set(body_vals) | set(self._inertia_bodies)):
      body = self._handles['body'][b]
      vals = body_vals.get(b, {})
      local_pos = vals.get('pos', jnp.asarray(body.pos, dtype))
      local_quat = _normalize_quat(
          vals.get('quat', jnp.asarray(body.quat, dtype))
      )
      if b in self._inertia_bodies:
        mass, inertia, ipos, iquat = self._body_inertial(
            b, body, vals, geom_vals, get, local_pos, local_quat
        )
        put('body_mass', b, mass)
        put('body_inertia', b, inertia)
        put('body_ipos', b, ipos)
        put('body_iquat', b, iquat)
      if 'pos' in vals or 'quat' in vals:
        frame = _frame_between(
            m.body_pos[b], m.body_quat[b], body.pos, body.quat
        )
        pos, quat = _apply_frame(
            frame,
            pos=local_pos,
            quat=vals.get('quat', jnp.asarray(body.quat, dtype)),
        )
        put('body_pos', b, pos)
        put('body_quat', b, quat)
        # A free joint's qpos0 (and qpos_spring) is the body's pose.
        for j in range(m.body_jntadr[b], m.body_jntadr[b] + m.body_jntnum[b]):
          if m.jnt_type[j] == _Joint.mjJNT_FREE:
            adr = int(m.jnt_qposadr[j])
            pose = jnp.concatenate([pos, quat])
            put('qpos0', slice(adr, adr + 7), pose)
            put('qpos_spring', slice(adr, adr + 7), pose)

  def _body_inertial(
      self, b, body, vals, geom_vals, get, local_pos, local_quat
  ):
    """(mass, inertia, ipos, iquat) as mjCBody::Compile sets them."""
    m = self._m
    dtype = jnp.float32
    compiler = body.compiler
    mass = vals.get('mass', jnp.asarray(body.mass, dtype))
    inertia = vals.get('inertia', jnp.asarray(body.inertia, dtype))
    explicit_ipos = 'ipos' in vals or not np.isnan(body.ipos[0])
    ipos = vals.get('ipos', jnp.asarray(np.nan_to_num(body.ipos), dtype))
    if 'iquat' in vals:
      iquat = _normalize_quat(vals['iquat'])
    elif not np.isnan(body.fullinertia[0]):
      # fullinertia: the compiler's principal axes, which do not vary.
      iquat = jnp.asarray(m.body_iquat[b], dtype)
      inertia = jnp.asarray(m.body_inertia[b], dtype)
    else:
      iquat = _normalize_quat(jnp.asarray(body.iquat, dtype))
    mode = compiler.inertiafromgeom
    infers = mode == mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_TRUE or (
        mode == mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_AUTO
        and not explicit_ipos
    )
    defined = jnp.asarray(explicit_ipos)
    if infers:
      selected = [
          g
          for g in self._body_geoms.get(b, ())
          if _geom_in_inertia_group(self._handles['geom'][g], compiler)
      ]
      if selected:
        parts = [self._geom_inertial(g, geom_vals, get) for g in selected]
        gm = jnp.stack([p[0] for p in parts])
        gi = jnp.stack([p[1] for p in parts])
        gp = jnp.stack([p[2] for p in parts])
        gq = jnp.stack([p[3] for p in parts])
        use = gm > _EPS
        count = jnp.sum(use)
        # One geom: its frame and principal inertia are copied.
        first = jnp.argmax(use)
        one = (gm[first], gi[first], gp[first], gq[first])
        # Several: total mass, centre of mass, principal axes of the sum.
        w = jnp.where(use, gm, 0.0)
        total = jnp.sum(w)
        com = jnp.sum(w[:, None] * gp, axis=0) / jnp.maximum(total, _MINVAL)
        rots = jax.vmap(_quat_to_mat)(gq)
        local = jnp.einsum('nij,nj,nkj->nik', rots, gi, rots)
        d = gp - com
        off = w[:, None, None] * (
            jnp.sum(d * d, -1)[:, None, None] * jnp.eye(3)
            - d[:, :, None] * d[:, None, :]
        )
        full = jnp.sum(jnp.where(use[:, None, None], local + off, 0.0), 0)
        eigval, eigquat = eig3(full)
        many = (total, eigval, com, eigquat)
        pick = lambda a, b_, c: jnp.where(
            count == 1, a, jnp.where(count > 1, b_, c)
        )
        mass = pick(one[0], many[0], mass)
        inertia = pick(one[1], many[1], inertia)
        ipos = pick(one[2], many[2], ipos)
        iquat = pick(one[3], many[3], iquat)
        defined = defined | (count > 0)
    # Undefined inertial frame: the compiler copies the (local) body frame.
    ipos = jnp.where(defined, ipos, local_pos)
    iquat = jnp.where(defined, iquat, local_quat)
    mass = jnp.maximum(mass, compiler.boundmass)
    inertia = jnp.maximum(inertia, compiler.boundinertia)
    if compiler.balanceinertia:
      bad = (
          (inertia[0] + inertia[1] < inertia[2])
          | (inertia[0] + inertia[2] < inertia[1])
          | (inertia[1] + inertia[2] < inertia[0])
      )
      inertia = jnp.where(bad, jnp.mean(inertia), inertia)
    return mass, inertia, ipos, iquat

  def _subtreemass(self, body_mass):
    m = self._m
    ancestors = _ancestor_matrix(m)
    return jnp.asarray(ancestors, body_mass.dtype) @ body_mass

  # -- mj_setConst at qpos0 ---------------------------------------------------

  def _dampratio_actuators(self) -> list[int]:
    """Actuators whose spec biasprm[2] > 0 may be a dampratio."""
    out = []
    for a in range(self._m.nu):
      act = self._handles['actuator'].get(a)
      if act is not None and act.biasprm[2] > 0:
        out.append(a)
    return out

  def _set_const(self, model, fields, get, act_vals):
    """The `mj_setConst` quantities that the bound attributes can change."""
    m = self._m
    nv = m.nv
    mx = model.replace(**{k: v for k, v in fields.items() if k != 'opt'})
    d = mjx.make_data(mx).replace(qpos=mx.qpos0)
    d = mjx.kinematics(mx, d)
    d = mjx.com_pos(mx, d)
    diag_m = minv = None
    if nv:
      d = mjx.crb(mx, d)
      full = mjx.full_m(mx, d)
      chol = jax.scipy.linalg.cho_factor(full)
      minv = jax.scipy.linalg.cho_solve(chol, jnp.eye(nv, dtype=full.dtype))
      diag_m = jnp.diagonal(full)
    if m.ntendon:
      d = mjx.tendon(mx, d)
    if m.nu:
      d = mjx.transmission(mx, d)

    # Which groups of quantities can change (decided statically).
    geometry = self._kinematics_changed  # positions at qpos0
    moments = geometry or self._gear  # transmissions
    if self._m_changed and nv:
      fields['dof_M0'] = diag_m
      fields['body_invweight0'] = self._body_invweight0(mx, d, minv)
      fields['dof_invweight0'] = self._dof_invweight0(mx, minv)
    if m.ntendon and (self._m_changed or geometry):
      ten_j = d._impl.ten_J  # pylint: disable=protected-access
      if nv:
        fields['tendon_invweight0'] = jnp.einsum(
            'ti,ij,tj->t', ten_j, minv, ten_j
        )
      if geometry:
        fields['tendon_length0'] = d.ten_length
        self._tendon_spring(mx, fields)
    if m.nu and nv and (self._m_changed or moments):
      moment = d._impl.actuator_moment  # pylint: disable=protected-access
      fields['actuator_acc0'] = jnp.linalg.norm(moment @ minv, axis=1)
    dampratio = self._dampratio_actuators()
    if dampratio and nv and (self._m_changed or moments or self._gains):
      self._dampratio(d, minv, dampratio, fields, get, act_vals)
    if self._pose_changed or self._inertia_changed:
      self._camlight(mx, d, fields)
    if self._pose_changed:
      self._eq_data(d, fields, get)
    self._stat(mx, d, diag_m, fields, model)

  def _body_invweight0(self, mx, d, minv):
    m = self._m
    mask = jnp.asarray(_dof_ancestor_mask(m), d.cdof.dtype)  # (nbody, nv)
    root_com = d.subtree_com[np.asarray(m.body_rootid)]
    offset = d.xipos - root_com  # (nbody, 3)
    cdof = d.cdof  # (nv, 6)
    jacp = cdof[None, :, 3:] + jnp.cross(cdof[None, :, :3], offset[:, None, :])
    jacr = jnp.broadcast_to(cdof[None, :, :3], jacp.shape)
    jac = jnp.concatenate([jacp, jacr], -1) * mask[:, :, None]  # (nb, nv, 6)
    a = jnp.einsum('bik,ij,bjl->bkl', jac, minv, jac)
    tran = jnp.trace(a[:, :3, :3], axis1=1, axis2=2) / 3
    rot = jnp.trace(a[:, 3:, 3:], axis1=1, axis2=2) / 3
    out = jnp.stack([tran, rot], -1)
    weld = np.asarray(m.body_weldid)
    static = np.asarray(m.body_dofnum)[weld] == 0
    simple2 = np.asarray(m.body_simple) == 2
    inv_mass = 1 / jnp.maximum(mx.body_mass, _MINVAL)
    out = jnp.where(
        simple2[:, None],
        jnp.stack([inv_mass, jnp.zeros_like(inv_mass)], -1),
        out,
    )
    out = jnp.where(static[:, None], 0.0, out)
    return out.at[0].set(0.0)

  def _dof_invweight0(self, mx, minv):
    m = self._m
    diag = jnp.diagonal(minv)
    group = jnp.asarray(_dof_group_matrix(m), diag.dtype)
    out = group @ diag
    simple2 = np.asarray(m.body_simple)[np.asarray(m.dof_bodyid)] == 2
    inv_mass = 1 / jnp.maximum(mx.body_mass[np.asarray(m.dof_bodyid)], _MINVAL)
    return jnp.where(simple2, inv_mass, out)

  def _tendon_spring(self, mx, fields):
    """Tendons with automatic spring length take their length at qpos_spring."""
    m = self._m
    auto = []
    for t in range(m.ntendon):
      tendon = self._handles['tendon'].get(t)
      if (
          tendon is not None
          and tendon.springlength[0] == -1
          and (tendon.springlength[1] == -1)
      ):
        auto.append(t)
    if not auto:
      return
    d = mjx.make_data(mx).replace(qpos=mx.qpos_spring)
    d = mjx.kinematics(mx, d)
    d = mjx.com_pos(mx, d)
    d = mjx.tendon(mx, d)
    idx = np.asarray(auto)
    length = d.ten_length[idx]
    spring = mx.tendon_lengthspring
    fields['tendon_lengthspring'] = spring.at[idx].set(
        jnp.stack([length, length], -1)
    )

  def _dampratio(self, d, minv, actuators, fields, get, act_vals):
    """biasprm[2] of position actuators whose spec sets a dampratio.

    MuJoCo 3.17 uses the inertia reflected through the transmission,
    `1 / (moment . M^-1 . moment)` at qpos0 (checked against the compiler).
    """
    moment = d._impl.actuator_moment  # pylint: disable=protected-access
    gainprm, biasprm = get('actuator_gainprm'), get('actuator_biasprm')
    out = biasprm
    for a in actuators:
      act = self._handles['actuator'][a]
      spec_b2 = _spec_biasprm2(act, act_vals.get(a, {}))
      is_pid = act.gaintype == mujoco.mjtGain.mjGAIN_PID
      position_like = jnp.asarray(is_pid) | (gainprm[a, 0] == -biasprm[a, 1])
      inv_mass = moment[a] @ minv @ moment[a]
      mass = 1.0 / jnp.maximum(inv_mass, _MINVAL)
      kp = -biasprm[a, 1] if is_pid else gainprm[a, 0]
      damping = spec_b2 * 2 * jnp.sqrt(jnp.maximum(kp * mass, 0.0))
      use = position_like & (spec_b2 > 0)
      out = out.at[a, 2].set(jnp.where(use, -damping, spec_b2))
    fields['actuator_biasprm'] = out

  def _camlight(self, mx, d, fields):
    m = self._m
    if m.ncam:
      body = np.asarray(m.cam_bodyid)
      target = np.asarray(m.cam_targetbodyid)
      xmat = d.xmat[body]
      cam_xpos = d.xpos[body] + jnp.einsum('cij,cj->ci', xmat, mx.cam_pos)
      cam_xmat = xmat @ jax.vmap(_quat_to_mat)(mx.cam_quat)
      com_body = np.where(target >= 0, target, body)
      fields['cam_pos0'] = cam_xpos - d.xpos[body]
      fields['cam_poscom0'] = cam_xpos - d.subtree_com[com_body]
      fields['cam_mat0'] = cam_xmat.reshape(mx.cam_mat0.shape)
    if m.nlight:
      body = np.asarray(m.light_bodyid)
      target = np.asarray(m.light_targetbodyid)
      xmat = d.xmat[body]
      light_xpos = d.xpos[body] + jnp.einsum('lij,lj->li', xmat, mx.light_pos)
      light_xdir = jnp.einsum('lij,lj->li', xmat, mx.light_dir)
      com_body = np.where(target >= 0, target, body)
      fields['light_pos0'] = light_xpos - d.xpos[body]
      fields['light_poscom0'] = light_xpos - d.subtree_com[com_body]
      fields['light_dir0'] = light_xdir

  def _eq_data(self, d, fields, get):
    """Connect/weld data that the compiler computes from poses at qpos0."""
    m = self._m
    data = get('eq_data')
    changed = False
    for e in range(m.neq):
      if m.eq_objtype[e] != mujoco.mjtObj.mjOBJ_BODY:
        continue
      id1, id2 = int(m.eq_obj1id[e]), int(m.eq_obj2id[e])
      eq = self._handles['equality'].get(e)
      if m.eq_type[e] == mujoco.mjtEq.mjEQ_CONNECT:
        anchor = jnp.asarray(m.eq_data[e, 0:3], data.dtype)
        pos = d.xpos[id1] + d.xmat[id1] @ anchor
        data = data.at[e, 3:6].set(d.xmat[id2].T @ (pos - d.xpos[id2]))
        changed = True
      elif m.eq_type[e] == mujoco.mjtEq.mjEQ_WELD:
        if eq is None or np.any(np.asarray(eq.data)[6:10] != 0):
          continue  # the spec gives the relative pose
        anchor = jnp.asarray(m.eq_data[e, 0:3], data.dtype)
        pos = d.xpos[id2] + d.xmat[id2] @ anchor
        data = data.at[e, 3:6].set(d.xmat[id1].T @ (pos - d.xpos[id1]))
        neg = d.xquat[id1] * jnp.array([1, -1, -1, -1], data.dtype)
        data = data.at[e, 6:10].set(_quat_mul(neg, d.xquat[id2]))
        changed = True
    if changed:
      fields['eq_data'] = data

  def _stat(self, mx, d, diag_m, fields, model):
    """mjModel.stat, except values the spec sets (kept as compiled)."""
    m = self._m
    if self._auto is None:
      self._auto = _auto_stat(self)
    auto = self._auto
    stat = model.stat
    updates = {}
    if diag_m is not None and self._m_changed and auto['meaninertia']:
      updates['meaninertia'] = jnp.mean(diag_m)
    if self._inertia_changed and auto['meanmass'] and m.nbody > 1:
      updates['meanmass'] = jnp.mean(mx.body_mass[1:])
    if self._kinematics_changed:
      center, extent, meansize = self._geometry_stat(mx, d)
      if auto['meansize'] and m.nbody > 1:
        updates['meansize'] = meansize
      if auto['extent']:
        updates['extent'] = extent
      if auto['center']:
        updates['center'] = center
    if updates:
      fields['stat'] = stat.replace(
          **{
              k: jnp.asarray(v, getattr(stat, k).dtype)
              for k, v in updates.items()
          }
      )

  def _geometry_stat(self, mx, d):
    m = self._m
    dtype = jnp.result_type(d.xpos)
    rbound = mx.geom_rbound
    size = mx.geom_size
    gtype = np.asarray(m.geom_type)
    plane = gtype == _Geom.mjGEOM_PLANE
    plane_r = jnp.where(
        (size[:, 0] != 0) | (size[:, 1] != 0),
        jnp.maximum(size[:, 0], size[:, 1]) * 0.1,
        0.01,
    )
    hfield_r = np.zeros(m.ngeom)
    for g in np.nonzero(gtype == _Geom.mjGEOM_HFIELD)[0]:
      hfield_r[g] = np.max(m.hfield_size[m.geom_dataid[g]]) * 0.1
    radius = jnp.where(
        rbound > 0,
        rbound,
        jnp.where(plane, plane_r, jnp.asarray(hfield_r, dtype)),
    )
    points = [d.xpos[1:], d.xipos[1:], d.xanchor, d.site_xpos]
    lows = [p for p in points if p.shape[0]]
    highs = list(lows)
    if m.ngeom:
      lows.append(d.geom_xpos - radius[:, None])
      highs.append(d.geom_xpos + radius[:, None])
    xmin = jnp.min(jnp.concatenate(lows), axis=0)
    xmax = jnp.max(jnp.concatenate(highs), axis=0)
    center = 0.5 * (xmin + xmax)
    extent = jnp.where(
        xmax[0] > xmin[0],
        jnp.maximum(1e-5, jnp.max(xmax - xmin)),
        mx.stat.extent,
    )
    # Body sizes: farthest joint anchor (own and children's), then geoms.
    body = jnp.zeros(m.nbody, dtype)
    jb = np.asarray(m.jnt_bodyid)
    if m.njnt:
      dist = jnp.linalg.norm(d.xipos[jb] - d.xanchor, axis=1)
      body = body.at[jb].max(dist)
      parent = np.asarray(m.body_parentid)[jb]
      dist = jnp.linalg.norm(d.xipos[parent] - d.xanchor, axis=1)
      body = body.at[parent].max(dist)
    body = body.at[0].set(0.0)
    if m.ngeom:
      gb = np.asarray(m.geom_bodyid)
      reach = rbound + jnp.linalg.norm(d.xipos[gb] - d.geom_xpos, axis=1)
      reach = jnp.where((rbound > 0) & (gb > 0), reach, 0.0)
      body = body.at[gb].max(reach)
    meansize = jnp.mean(jnp.maximum(body[1:], 1e-5)) if m.nbody > 1 else 0.0
    extent = jnp.maximum(extent, 2 * meansize)
    return center, extent, meansize


def _spec_biasprm2(act, vals):
  """An actuator's biasprm[2] before the compiler turns a dampratio into a
  damping: the bound value if any, else the spec's."""
  if 'biasprm' in vals:
    return jnp.asarray(vals['biasprm'], jnp.float32)[2]
  if 'kv' in vals:
    return -jnp.asarray(vals['kv'], jnp.float32)
  return jnp.asarray(act.biasprm[2], jnp.float32)


def _dof_slice(m, j):
  adr = int(m.jnt_dofadr[j])
  width = {0: 6, 1: 3, 2: 1, 3: 1}[int(m.jnt_type[j])]
  return slice(adr, adr + width)


def _ancestor_matrix(m) -> np.ndarray:
  """A[p, i] = 1 if body p is body i or one of its ancestors."""
  a = np.zeros((m.nbody, m.nbody))
  for i in range(m.nbody):
    p = i
    while True:
      a[p, i] = 1
      if p == 0:
        break
      p = int(m.body_parentid[p])
  return a


def _dof_ancestor_mask(m) -> np.ndarray:
  """mask[b, v] = 1 if dof v moves body b (its body is an ancestor of b)."""
  anc = _ancestor_matrix(m)
  return anc[np.asarray(m.dof_bodyid)].T


def _dof_group_matrix(m) -> np.ndarray:
  """Averages inverse-inertia diagonals per joint as mj_setConst does."""
  g = np.zeros((m.nv, m.nv))
  for j in range(m.njnt):
    adr = int(m.jnt_dofadr[j])
    jtype = int(m.jnt_type[j])
    groups = {0: [(0, 3), (3, 6)], 1: [(0, 3)], 2: [(0, 1)], 3: [(0, 1)]}
    for lo, hi in groups[jtype]:
      for r in range(adr + lo, adr + hi):
        g[r, adr + lo : adr + hi] = 1.0 / (hi - lo)
  return g


class _HostView:
  """Attribute access to host arrays, for running `_geometry_stat` on them."""

  def __init__(self, **arrays):
    self.__dict__.update(arrays)


def _auto_stat(compiler) -> dict:
  """Which statistics the compiler computed (the spec did not set them).

  Recomputes them on the host, at qpos0, with the same functions the device
  uses; a compiled value that differs was set in the spec and must stay.
  """
  m = compiler._m  # pylint: disable=protected-access
  data = mujoco.MjData(m)
  data.qpos[:] = m.qpos0
  mujoco.mj_forward(m, data)
  full = np.zeros((m.nv, m.nv))
  if m.nv:
    mujoco.mj_fullM(m, data, full)
  model = _HostView(
      geom_rbound=m.geom_rbound,
      geom_size=m.geom_size,
      stat=_HostView(extent=m.stat.extent),
  )
  kin = _HostView(
      xpos=data.xpos,
      xipos=data.xipos,
      xanchor=data.xanchor,
      site_xpos=data.site_xpos,
      geom_xpos=data.geom_xpos,
  )
  with jax.ensure_compile_time_eval():
    center, extent, meansize = compiler._geometry_stat(model, kin)  # pylint: disable=protected-access
    center, extent, meansize = (
        np.asarray(center),
        float(extent),
        float(meansize),
    )
  auto = {
      'meaninertia': np.mean(np.diagonal(full)) if m.nv else m.stat.meaninertia,
      'meanmass': np.mean(m.body_mass[1:]) if m.nbody > 1 else m.stat.meanmass,
      'meansize': meansize if m.nbody > 1 else m.stat.meansize,
      'extent': extent,
      'center': center,
  }
  # `_geometry_stat` computes in float32: compare at that precision.
  return {
      name: bool(
          np.allclose(auto[name], getattr(m.stat, name), rtol=1e-5, atol=1e-7)
      )
      for name in auto
  }
