"""Body mass and inertia as MuJoCo compiles them.

Ports of `mjCBody::Compile`'s inertial (explicit, or inferred from the
body's geoms, `geoms.mass_and_inertia`: total mass, centre of mass,
principal axes by MuJoCo's own Jacobi iteration `mjuu_eig3`, with
`boundmass`, `boundinertia` and `balanceinertia`), and of
`body_subtreemass`.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjx_composer.compiler import frames
from mjx_composer.compiler import geoms
from mjx_composer.utils import transformations as tr


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
  condition back to the host at every iteration; an early exit makes the
  walk task's batched reset about 40% slower on a GPU
  (`docs/performance.md`).

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


def _rotated(mat, r):
  """`r.T @ mat @ r` of 3x3 matrices, elementwise (fusible, full float32)."""
  mr = jnp.sum(mat[:, :, None] * r[None, :, :], axis=1)
  return jnp.sum(r[:, :, None] * mr[:, None, :], axis=0)


def _with_bound(constants, bound: dict):
  """`constants` on the device, with the rows in `bound` replaced.

  Args:
    constants: `(n, ...)` host values, the spec's.
    bound: `{row: value}`, values bound to some rows (one scatter for all).
  """
  out = jnp.asarray(constants, jnp.float32)
  if bound:
    rows = np.asarray(list(bound))
    values = jnp.stack([jnp.asarray(v, jnp.float32) for v in bound.values()])
    out = out.at[rows].set(jnp.reshape(values, (len(rows),) + out.shape[1:]))
  return out


def _geoms_inertial(fields, geom_ids, owner: str):
  """(mass, principal inertia, compiled pos, compiled quat) of `geom_ids`.

  Batched: `(k,)`, `(k, 3)`, `(k, 3)`, `(k, 4)`, each geom type's formula
  applied once to all geoms of that type. Sizes and poses are the world's
  (as bound, by another variator, or compiled); masses and densities are
  bound or the spec's.
  """
  m = fields.host.m
  handles = fields.host.handles['geom']
  count = len(geom_ids)
  given = np.zeros(count, bool)
  mass, density = np.zeros(count), np.zeros(count)
  bound_mass, bound_density = {}, {}
  kinds = []
  for k, g in enumerate(geom_ids):
    geom, vals = handles[g], fields.bound('geom', g)
    gtype = int(m.geom_type[g])
    if gtype in geoms.MESHLIKE:
      # A guard: `structure` refuses this already. The compiler derives mesh
      # inertia from the asset, which the compiled model does not keep.
      body = fields.host.body_name(int(m.geom_bodyid[g]))
      raise ValueError(
          f'{owner}: body {body!r} infers its inertia from a mesh geom '
          'as well; varying its other geoms would need the mesh inertia, '
          'which the compiled model does not keep.'
      )
    kinds.append(
        (gtype, geom.typeinertia == mujoco.mjtGeomInertia.mjINERTIA_SHELL)
    )
    if 'mass' in vals:
      given[k], bound_mass[k] = True, vals['mass']
    elif not np.isnan(geom.mass):
      given[k], mass[k] = True, geom.mass
    if 'density' in vals:
      bound_density[k] = vals['density']
    else:
      density[k] = geom.density
  mass = _with_bound(mass, bound_mass)
  density = _with_bound(density, bound_density)
  ids = np.asarray(geom_ids)
  size = fields.get('geom_size')[ids]
  groups = {}
  for k, kind in enumerate(kinds):
    groups.setdefault(kind, []).append(k)
  masses, inertias = [], []
  for (gtype, shell), rows in groups.items():
    rows = np.asarray(rows)
    pick = (lambda x: x) if len(groups) == 1 else (lambda x: x[rows])
    gm, gi = geoms.mass_and_inertia(
        gtype, shell, pick(size), given[rows], pick(mass), pick(density)
    )
    masses.append(gm)
    inertias.append(gi)
  gm, gi = masses[0], inertias[0]
  if len(groups) > 1:
    # Back from type order to the order of `geom_ids`.
    order = np.argsort(np.concatenate([np.asarray(r) for r in groups.values()]))
    gm = jnp.concatenate(masses)[order]
    gi = jnp.concatenate(inertias)[order]
  return gm, gi, fields.get('geom_pos')[ids], fields.get('geom_quat')[ids]


def bodies_inertial(fields, bodies, owner: str):
  """(mass, inertia, ipos, iquat) of `bodies` as mjCBody::Compile sets them.

  Batched over the bodies: `(n,)`, `(n, 3)`, `(n, 3)` and `(n, 4)` arrays in
  the order of `bodies`. A body's inertial is the spec's (no geom has mass),
  one geom's (exactly one has) or the sum of several, whose principal axes
  come from one `eig3` over all bodies: the program holds one Jacobi loop,
  not one per body (on a GPU each loop iteration is a kernel launch per
  loop), and none when no body sums several geoms. The geoms of all bodies
  are laid out in padded rows, one per body, so that every step is one
  elementwise computation over all bodies rather than one per body (fewer
  equations to trace, fewer instructions to compile).
  """
  host = fields.host
  m = host.m
  n = len(bodies)
  local_pos, local_quat = np.zeros((n, 3)), np.zeros((n, 4))
  mass, inertia = np.zeros(n), np.zeros((n, 3))
  ipos, iquat = np.zeros((n, 3)), np.zeros((n, 4))
  explicit = np.zeros(n, bool)
  boundmass, boundinertia = np.zeros(n), np.zeros(n)
  balance = np.zeros(n, bool)
  bound = {k: {} for k in ('pos', 'quat', 'mass', 'inertia', 'ipos', 'iquat')}
  selected = []
  for i, b in enumerate(bodies):
    body, vals = host.handles['body'][b], fields.bound('body', b)
    compiler = body.compiler
    local_pos[i] = body.pos
    local_quat[i] = frames.normalize_quat(np.asarray(body.quat), xp=np)
    mass[i], inertia[i] = body.mass, body.inertia
    explicit[i] = 'ipos' in vals or not np.isnan(body.ipos[0])
    ipos[i] = np.nan_to_num(body.ipos)
    iquat[i] = frames.normalize_quat(np.asarray(body.iquat), xp=np)
    for name in bound:
      if name in vals:
        bound[name][i] = vals[name]
    if 'iquat' not in vals and not np.isnan(body.fullinertia[0]):
      # fullinertia: the compiler's principal axes, which do not vary.
      iquat[i], inertia[i] = m.body_iquat[b], m.body_inertia[b]
      bound['inertia'].pop(i, None)
    boundmass[i], boundinertia[i] = compiler.boundmass, compiler.boundinertia
    balance[i] = compiler.balanceinertia
    mode = compiler.inertiafromgeom
    infers = mode == mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_TRUE or (
        mode == mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_AUTO
        and not explicit[i]
    )
    selected.append(host.inertia_geoms(b, compiler) if infers else [])
  for name in ('quat', 'iquat'):
    bound[name] = {
        i: frames.normalize_quat(jnp.asarray(q, jnp.float32))
        for i, q in bound[name].items()
    }
  local_pos = _with_bound(local_pos, bound['pos'])
  local_quat = _with_bound(local_quat, bound['quat'])
  mass = _with_bound(mass, bound['mass'])
  inertia = _with_bound(inertia, bound['inertia'])
  ipos = _with_bound(ipos, bound['ipos'])
  iquat = _with_bound(iquat, bound['iquat'])
  defined = jnp.asarray(explicit)
  members = [g for rows in selected for g in rows]
  if members:
    gm, gi, gp, gq = _geoms_inertial(fields, members, owner)
    # Padded rows: slots[i, j] is body i's j-th geom in `members`, or the
    # padding entry (massless) appended after them.
    width = max(len(rows) for rows in selected)
    slots = np.full((n, width), len(members))
    start = 0
    for i, rows in enumerate(selected):
      slots[i, : len(rows)] = np.arange(start, start + len(rows))
      start += len(rows)
    pad = lambda x, v: jnp.concatenate([x, jnp.full((1,) + x.shape[1:], v)])
    gm, gi = pad(gm, 0.0)[slots], pad(gi, 0.0)[slots]
    gp, gq = pad(gp, 0.0)[slots], pad(gq, 1.0)[slots]
    use = gm > frames.EPS
    count = jnp.sum(use, axis=1)
    defined = defined | (count > 0)
    # One geom with mass: its frame and principal inertia are copied. The
    # masked sum over the row is exactly that geom's value.
    one = count == 1
    only = lambda x: jnp.sum(jnp.where(use[..., None], x, 0.0), axis=1)
    mass = jnp.where(one, jnp.sum(jnp.where(use, gm, 0.0), axis=1), mass)
    inertia = jnp.where(one[:, None], only(gi), inertia)
    ipos = jnp.where(one[:, None], only(gp), ipos)
    iquat = jnp.where(one[:, None], only(gq), iquat)
    if width > 1:
      # Several: total mass, centre of mass, principal axes of the sum.
      w = jnp.where(use, gm, 0.0)
      total = jnp.sum(w, axis=1)
      com = (
          jnp.sum(w[..., None] * gp, axis=1)
          / jnp.maximum(total, frames.MINVAL)[:, None]
      )
      rots = tr.quat_to_mat(gq)
      local = jnp.einsum('bnij,bnj,bnkj->bnik', rots, gi, rots)
      d = gp - com[:, None, :]
      off = w[..., None, None] * (
          jnp.sum(d * d, -1)[..., None, None] * jnp.eye(3)
          - d[..., :, None] * d[..., None, :]
      )
      full = jnp.sum(jnp.where(use[..., None, None], local + off, 0.0), 1)
      eigval, eigquat = jax.vmap(eig3)(full)
      several = count > 1
      mass = jnp.where(several, total, mass)
      inertia = jnp.where(several[:, None], eigval, inertia)
      ipos = jnp.where(several[:, None], com, ipos)
      iquat = jnp.where(several[:, None], eigquat, iquat)
  # Undefined inertial frame: the compiler copies the (local) body frame.
  ipos = jnp.where(defined[:, None], ipos, local_pos)
  iquat = jnp.where(defined[:, None], iquat, local_quat)
  mass = jnp.maximum(mass, jnp.asarray(boundmass, mass.dtype))
  inertia = jnp.maximum(inertia, jnp.asarray(boundinertia, mass.dtype)[:, None])
  if balance.any():
    bad = (
        (inertia[:, 0] + inertia[:, 1] < inertia[:, 2])
        | (inertia[:, 0] + inertia[:, 2] < inertia[:, 1])
        | (inertia[:, 1] + inertia[:, 2] < inertia[:, 0])
    ) & balance
    mean = jnp.mean(inertia, axis=1, keepdims=True)
    inertia = jnp.where(bad[:, None], mean, inertia)
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
