"""Geom and body mass and inertia, and geom bounds, as MuJoCo compiles them.

Ports of `mjCGeom::GetVolume`, `mjCGeom::SetInertia` and
`mjCGeom::ComputeAABB` for primitive geoms, of `mjCBody::Compile`'s
inertial (explicit, or inferred from the body's geoms: total mass, centre
of mass, principal axes by MuJoCo's own Jacobi iteration `mjuu_eig3`, with
`boundmass`, `boundinertia` and `balanceinertia`), and of
`body_subtreemass`. Geom shapes are static, so a geom's type picks its
formula on the host.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjx_composer.compiler import frames
from mjx_composer.utils import transformations as tr

_Geom = mujoco.mjtGeom
# Geoms whose size, inertia and frame come from an asset.
MESHLIKE = (_Geom.mjGEOM_MESH, _Geom.mjGEOM_SDF, _Geom.mjGEOM_HFIELD)


def infers_inertia(body) -> bool:
  """Whether the compiler infers this body's inertial from its geoms."""
  mode = body.compiler.inertiafromgeom
  return mode == mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_TRUE or (
      mode == mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_AUTO
      and np.isnan(body.ipos[0])
  )


def in_inertia_group(geom, compiler) -> bool:
  """Whether the compiler counts the geom in its body's inertial."""
  low, high = compiler.inertiagrouprange
  return low <= geom.group <= high


def eig3(mat, iterations=24):
  """Principal moments and axes of a symmetric 3x3 matrix, as MuJoCo does.

  A float32 port of `mjuu_eig3`: Jacobi rotations accumulated in a
  quaternion from the identity, then eigenvalues sorted in decreasing order
  by quarter turns. The termination threshold is relative here (float32
  cannot reach the compiler's absolute 1e-12; an off-diagonal below 1e-7 of
  the diagonal is float32 noise), and an iteration budget with a converged
  flag replaces the loop so it vmaps. The budget is fixed, not an early
  exit: a loop with a known trip count runs on a GPU without reading its
  condition back to the host at every iteration (with an early exit, the
  walk task's batched reset took 17 ms instead of 12 ms in one timed call
  on an H200, 8,192 worlds).

  Returns:
    `(eigenvalues (3,), quaternion (4,))`, the quaternion taking the
    principal frame to the frame of `mat`.
  """
  dtype = mat.dtype
  scale = jnp.maximum(jnp.max(jnp.abs(jnp.diagonal(mat))), 1e-30)
  tol = 1e-7 * scale

  def body(_, carry):
    quat, done = carry
    d = _rotated(mat, tr.quat_to_mat(quat))
    d01, d02, d12 = d[0, 1], d[0, 2], d[1, 2]
    a01, a02, a12 = jnp.abs(d01), jnp.abs(d02), jnp.abs(d12)
    case0 = (a01 > a02) & (a01 > a12)
    case1 = jnp.logical_not(case0) & (a02 > a12)
    # Selects, not indexing with traced indices: the loop body stays one
    # elementwise computation that XLA fuses. (rk, ck) is (0, 1), (0, 2)
    # or (1, 2); the rotation axis is the third one.
    off = jnp.where(case0, d01, jnp.where(case1, d02, d12))
    d_rr = jnp.where(case0 | case1, d[0, 0], d[1, 1])
    d_cc = jnp.where(case0, d[1, 1], d[2, 2])
    rotk = jnp.where(case0, 2, jnp.where(case1, 1, 0))
    stop = jnp.abs(off) < tol
    safe_off = jnp.where(stop, 1.0, off)
    tau = (d_cc - d_rr) / (2 * safe_off)
    root = jnp.sqrt(1 + tau * tau)
    t = jnp.where(tau >= 0, 1.0 / (tau + root), -1.0 / (-tau + root))
    c = 1.0 / jnp.sqrt(1 + t * t)
    # MuJoCo's half-angle sine, sign(tau) * -sqrt(0.5 - 0.5 c), written as
    # -sin(theta) / sqrt(2 (1 + c)): float32 rounds c to 1 below ~3e-4 rad,
    # which would stop the iteration that early.
    comp = -(t * c) / jnp.sqrt(2 * (1 + c))
    comp = jnp.where(rotk == 1, -comp, comp)
    vec = jnp.where(jnp.arange(3) == rotk, comp, jnp.zeros((), dtype))
    rot = jnp.concatenate([jnp.sqrt(1.0 - comp * comp)[None], vec])
    rot = tr.normalize(rot)
    new = tr.quat_mul(quat, rot)
    new = tr.normalize(new)
    done = done | stop
    return jnp.where(done, quat, new), done

  quat0 = jnp.array([1.0, 0.0, 0.0, 0.0], dtype)
  # Unrolled by 4: a quarter of the iterations, each a few fused kernels.
  quat, _ = jax.lax.fori_loop(
      0, iterations, body, (quat0, jnp.zeros((), bool)), unroll=4
  )
  eigval = jnp.diagonal(_rotated(mat, tr.quat_to_mat(quat)))
  # Sort decreasing (bubble sort 0, 1, 0), rotating the frame by quarter
  # turns; like MuJoCo, only swap values that differ (here: relatively).
  half = math.sqrt(0.5)
  swap_tol = 1e-6 * scale
  for j in range(3):
    j1 = j % 2
    swap = eigval[j1] + swap_tol < eigval[j1 + 1]
    swapped = eigval.at[j1].set(eigval[j1 + 1]).at[j1 + 1].set(eigval[j1])
    turn = jnp.zeros(4, dtype).at[0].set(half).at[(j1 + 2) % 3 + 1].set(half)
    turned = tr.quat_mul(quat, turn)
    turned = tr.normalize(turned)
    eigval = jnp.where(swap, swapped, eigval)
    quat = jnp.where(swap, turned, quat)
  return eigval, quat


# -- geoms ---


def _rotated(mat, r):
  """`r.T @ mat @ r` of 3x3 matrices, elementwise (fusible, full float32)."""
  mr = jnp.sum(mat[:, :, None] * r[None, :, :], axis=1)
  return jnp.sum(r[:, :, None] * mr[:, None, :], axis=0)


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
    ok = (mass != 0) & (volume > frames.EPS)
    mass_ = jnp.where(ok, mass, 0.0)
  else:
    ok = density != 0
    mass_ = jnp.where(ok, density * volume, 0.0)
  inertia = jnp.where(ok, _geom_inertia(gtype, shell, size, mass_), 0.0)
  return mass_, inertia


def geom_rbound(gtype, size):
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


def geom_aabb(gtype, size):
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
        [
            0,
            0,
            -frames.MAXVAL / 2,
            frames.MAXVAL,
            frames.MAXVAL,
            frames.MAXVAL / 2,
        ],
        size.dtype,
    )
  else:
    half = size
  return jnp.concatenate([jnp.stack([zero, zero, zero]), half])


def compiled_size(m, g: int, geom, size):
  """A geom's compiled size: `fromto` fixes the length (and box y)."""
  if np.isnan(geom.fromto[0]):
    return size
  boxlike = geom.type in (_Geom.mjGEOM_BOX, _Geom.mjGEOM_ELLIPSOID)
  length = float(m.geom_size[g, 2 if boxlike else 1])
  if boxlike:
    return jnp.stack([size[0], size[0], jnp.asarray(length, size.dtype)])
  return size.at[1].set(length)


# -- bodies ---


def _geom_inertial(fields, g: int, owner: str):
  """(mass, principal inertia, compiled pos, compiled quat) of a geom.

  Sizes and poses are the world's (as bound, by another variator, or
  compiled); mass and density are bound or the spec's.
  """
  m = fields.host.m
  geom = fields.host.handles['geom'][g]
  vals = fields.bound('geom', g)
  gtype = int(m.geom_type[g])
  shell = geom.typeinertia == mujoco.mjtGeomInertia.mjINERTIA_SHELL
  dtype = jnp.float32
  if 'mass' in vals:
    mass = vals['mass']
  elif not np.isnan(geom.mass):
    mass = jnp.asarray(geom.mass, dtype)
  else:
    mass = None
  density = vals.get('density', jnp.asarray(geom.density, dtype))
  if gtype in MESHLIKE:
    # A guard: `structure` refuses this already. The compiler derives mesh
    # inertia from the asset, which the compiled model does not keep.
    body = fields.host.body_name(int(m.geom_bodyid[g]))
    raise ValueError(
        f'{owner}: body {body!r} infers its inertia from a mesh geom '
        'as well; varying its other geoms would need the mesh inertia, '
        'which the compiled model does not keep.'
    )
  size = fields.get('geom_size')[g]
  mass_, inertia = _geom_mass_inertia(gtype, shell, size, mass, density)
  return mass_, inertia, fields.get('geom_pos')[g], fields.get('geom_quat')[g]


def bodies_inertial(fields, bodies, owner: str):
  """(mass, inertia, ipos, iquat) of `bodies` as mjCBody::Compile sets them.

  Batched over the bodies: `(n,)`, `(n, 3)`, `(n, 3)` and `(n, 4)` arrays in
  the order of `bodies`. The principal axes of every body that sums several
  geoms come from one `eig3` over all of them, so the program holds one
  Jacobi loop, not one per body (on a GPU each loop iteration is a kernel
  launch per body).
  """
  parts = [_body_parts(fields, b, owner) for b in bodies]
  summed = [i for i, p in enumerate(parts) if p.full is not None]
  if summed:
    eigval, eigquat = jax.vmap(eig3)(jnp.stack([parts[i].full for i in summed]))
    for j, i in enumerate(summed):
      parts[i] = parts[i].with_principal(eigval[j], eigquat[j])
  out = [_finish_body(fields, b, p) for b, p in zip(bodies, parts)]
  return tuple(jnp.stack([o[k] for o in out]) for k in range(4))


@dataclasses.dataclass(frozen=True)
class _BodyParts:
  """A body's inertial before its principal axes (see `_body_parts`).

  `mass`..`iquat` are, per world, the spec's inertial (no geom has mass)
  or one geom's (exactly one has). `full` is the inertia matrix about the
  centre of mass of its geoms where several may count (None otherwise);
  `with_principal` then takes the summed inertial where several have mass.
  """

  mass: jax.Array
  inertia: jax.Array
  ipos: jax.Array
  iquat: jax.Array
  defined: jax.Array
  local_pos: jax.Array
  local_quat: jax.Array
  full: jax.Array | None = None
  count: jax.Array | None = None
  total: jax.Array | None = None
  com: jax.Array | None = None

  def with_principal(self, eigval, eigquat):
    pick = lambda several, old: jnp.where(self.count > 1, several, old)
    return dataclasses.replace(
        self,
        mass=pick(self.total, self.mass),
        inertia=pick(eigval, self.inertia),
        ipos=pick(self.com, self.ipos),
        iquat=pick(eigquat, self.iquat),
    )


def _body_parts(fields, b: int, owner: str) -> _BodyParts:
  """Body `b`'s inertial from the spec and its geoms, but the eigen-axes."""
  m = fields.host.m
  body = fields.host.handles['body'][b]
  vals = fields.bound('body', b)
  dtype = jnp.float32
  compiler = body.compiler
  local_pos = vals.get('pos', jnp.asarray(body.pos, dtype))
  local_quat = frames.normalize_quat(
      vals.get('quat', jnp.asarray(body.quat, dtype))
  )
  mass = vals.get('mass', jnp.asarray(body.mass, dtype))
  inertia = vals.get('inertia', jnp.asarray(body.inertia, dtype))
  explicit_ipos = 'ipos' in vals or not np.isnan(body.ipos[0])
  ipos = vals.get('ipos', jnp.asarray(np.nan_to_num(body.ipos), dtype))
  if 'iquat' in vals:
    iquat = frames.normalize_quat(vals['iquat'])
  elif not np.isnan(body.fullinertia[0]):
    # fullinertia: the compiler's principal axes, which do not vary.
    iquat = jnp.asarray(m.body_iquat[b], dtype)
    inertia = jnp.asarray(m.body_inertia[b], dtype)
  else:
    iquat = frames.normalize_quat(jnp.asarray(body.iquat, dtype))
  mode = compiler.inertiafromgeom
  infers = mode == mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_TRUE or (
      mode == mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_AUTO
      and not explicit_ipos
  )
  parts = _BodyParts(
      mass=mass,
      inertia=inertia,
      ipos=ipos,
      iquat=iquat,
      defined=jnp.asarray(explicit_ipos),
      local_pos=local_pos,
      local_quat=local_quat,
  )
  selected = fields.host.inertia_geoms(b, compiler) if infers else []
  if not selected:
    return parts
  geoms = [_geom_inertial(fields, g, owner) for g in selected]
  gm, gi, gp, gq = (jnp.stack([p[k] for p in geoms]) for k in range(4))
  use = gm > frames.EPS
  count = jnp.sum(use)
  # One geom: its frame and principal inertia are copied.
  first = jnp.argmax(use)
  one = count == 1
  parts = dataclasses.replace(
      parts,
      mass=jnp.where(one, gm[first], mass),
      inertia=jnp.where(one, gi[first], inertia),
      ipos=jnp.where(one, gp[first], ipos),
      iquat=jnp.where(one, gq[first], iquat),
      defined=parts.defined | (count > 0),
  )
  if len(selected) == 1:
    return parts  # never several
  # Several: total mass, centre of mass, principal axes of the sum.
  w = jnp.where(use, gm, 0.0)
  total = jnp.sum(w)
  com = jnp.sum(w[:, None] * gp, axis=0) / jnp.maximum(total, frames.MINVAL)
  rots = tr.quat_to_mat(gq)
  local = jnp.einsum('nij,nj,nkj->nik', rots, gi, rots)
  d = gp - com
  off = w[:, None, None] * (
      jnp.sum(d * d, -1)[:, None, None] * jnp.eye(3)
      - d[:, :, None] * d[:, None, :]
  )
  full = jnp.sum(jnp.where(use[:, None, None], local + off, 0.0), 0)
  return dataclasses.replace(
      parts, full=full, count=count, total=total, com=com
  )


def _finish_body(fields, b: int, parts: _BodyParts):
  """The compiler's bounds and balancing, and the undefined-frame rule."""
  compiler = fields.host.handles['body'][b].compiler
  # Undefined inertial frame: the compiler copies the (local) body frame.
  ipos = jnp.where(parts.defined, parts.ipos, parts.local_pos)
  iquat = jnp.where(parts.defined, parts.iquat, parts.local_quat)
  mass = jnp.maximum(parts.mass, compiler.boundmass)
  inertia = jnp.maximum(parts.inertia, compiler.boundinertia)
  if compiler.balanceinertia:
    bad = (
        (inertia[0] + inertia[1] < inertia[2])
        | (inertia[0] + inertia[2] < inertia[1])
        | (inertia[1] + inertia[2] < inertia[0])
    )
    inertia = jnp.where(bad, jnp.mean(inertia), inertia)
  return mass, inertia, ipos, iquat


def ancestor_matrix(m) -> np.ndarray:
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


def subtreemass(m, body_mass):
  """`body_subtreemass`: each body's mass plus its descendants'."""
  return jnp.asarray(ancestor_matrix(m), body_mass.dtype) @ body_mass
