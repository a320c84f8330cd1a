"""MuJoCo's `mj_setConst` at qpos0, with MJX's kinematics, per world.

`dof_M0`, `body_invweight0`, `dof_invweight0`, `tendon_invweight0`,
`actuator_acc0`, `tendon_length0`, automatic tendon spring lengths, camera
and light `*_pos0/_poscom0/_mat0/_dir0`, body connect/weld `eq_data`,
`biasprm[2]` of position actuators given a `dampratio` (MuJoCo 3.17 uses
the reflected inertia `1 / (moment . M^-1 . moment)`), and the statistics
(`meaninertia`, `meanmass`, `meansize`, `extent`, `center`) unless the spec
sets them. Follows `engine_setconst.c`; only the quantities that the plan
says can change are computed. Runs on MJX's JAX implementation, also for a
'warp' model (on its JAX twin, `Backend.jax_model`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np

from mjx_composer.compiler import frames
from mjx_composer.compiler import inertia
from mjx_composer.platform import backend
from mjx_composer.platform import cpu_linalg
from mjx_composer.platform import internals
from mjx_composer.utils import transformations as tr

_Geom = mujoco.mjtGeom


def _spd_inverse(a):
  """The inverse of the symmetric positive definite matrix `a` (Cholesky)."""
  chol = jax.scipy.linalg.cho_factor(a)
  return jax.scipy.linalg.cho_solve(chol, jnp.eye(a.shape[-1], dtype=a.dtype))


def _spd_inverse_in_xla(a):
  """`_spd_inverse` without LAPACK: what the CPU runs.

  On the CPU, JAX lowers a batched Cholesky factorization to a LAPACK call
  that splits the batch into tasks on XLA's thread pool and blocks until
  those finish. When two such calls run at once and
  hold every thread of the pool, no thread is left for their tasks and the
  program deadlocks (jaxlib 0.10; see `platform.cpu_linalg`). A
  randomized reset factorizes `M(qpos0)` here while MJX's forward pass
  factorizes its own mass matrix beside it, which can take every thread
  of a 2-core machine's pool. These loops are plain XLA:
  `cpu_linalg.cholesky`, then the inverse of the factor row by row,
  `inv(a) = inv(L)^T inv(L)`.
  """
  n = a.shape[-1]
  index = jnp.arange(n)
  lower = cpu_linalg.cholesky(a)

  def invert_row(i, inverse):
    # Rows >= i of `inverse` are still zero: the product sums k < i.
    unit = (index == i).astype(a.dtype)
    return inverse.at[i].set((unit - lower[i] @ inverse) / lower[i, i])

  inverse = jax.lax.fori_loop(0, n, invert_row, jnp.zeros_like(a))
  return inverse.T @ inverse


@jax.named_scope('set_const')
def update(host, plan, fields, auto_stat):
  """Adds the `mj_setConst` quantities that the bound attributes can change.

  Args:
    host: the `context.Host`.
    plan: the `planner.Plan` (which groups of quantities can change).
    fields: the `context.Fields` of this call (read and extended).
    auto_stat: `() -> {statistic: bool}`, whether the compiler computed
      each statistic (see `auto_stat`).
  """
  m = host.m
  nv = m.nv
  model = fields.model
  # MJX implements crb, full_m and transmission on 'jax' only: on 'warp',
  # compute on the JAX twin of the world's model (public fields out).
  mx = model.replace(**fields.fields)
  mx = backend.of(mx).jax_model(mx, host.m)
  # Positions at qpos0 come from the host where the bound attributes
  # cannot move them (e.g. masses, sizes, colours): see `kinematics`.
  d = host.qpos0_kinematics.apply(
      mx, mjx.make_data(mx).replace(qpos=mx.qpos0), written=fields.fields
  )
  diag_m = minv = None
  if nv:
    d = mjx.crb(mx, d)
    full = mjx.full_m(mx, d)
    minv = jax.lax.platform_dependent(
        full, cpu=_spd_inverse_in_xla, default=_spd_inverse
    )
    diag_m = jnp.diagonal(full)
  if m.ntendon:
    d = mjx.tendon(mx, d)
  if m.nu:
    d = mjx.transmission(mx, d)

  out = fields.fields
  geometry = plan.kinematics  # positions at qpos0
  moments = plan.moments  # transmissions
  if plan.mass_matrix and nv:
    out['dof_M0'] = diag_m
    out['body_invweight0'] = _body_invweight0(m, mx, d, minv)
    out['dof_invweight0'] = _dof_invweight0(m, mx, minv)
  if m.ntendon and (plan.mass_matrix or geometry):
    ten_j = internals.data_impl(d).ten_J
    if nv:
      out['tendon_invweight0'] = jnp.einsum('ti,ij,tj->t', ten_j, minv, ten_j)
    if geometry:
      out['tendon_length0'] = d.ten_length
      _tendon_spring(host, mx, out)
  if m.nu and nv and (plan.mass_matrix or moments):
    moment = internals.data_impl(d).actuator_moment
    out['actuator_acc0'] = jnp.linalg.norm(moment @ minv, axis=1)
  if plan.dampratio_actuators and nv and plan.dampratios:
    _dampratio(host, plan.dampratio_actuators, d, minv, fields)
  if plan.body_frames or plan.inertia:
    _camlight(m, mx, d, out)
  if plan.body_frames:
    _eq_data(host, d, fields)
  _stat(m, plan, mx, d, diag_m, fields, auto_stat)


def _body_invweight0(m, mx, d, minv):
  """Each body's mean translational and rotational inverse inertia at qpos0:
  the means of the diagonals of the two 3x3 blocks of `J M^-1 J^T`, `J` the
  body's 6-row Jacobian at its centre of mass (mj_setConst).

  Only those diagonals are formed, never the 6x6 products: the
  translational ones as `J_k M^-1 J_k` over the three rows `k`, one body at
  a time (a loop: every body's Jacobian at once, and its product with
  `M^-1`, were the largest temporaries of a randomized restart on a GPU);
  the rotational rows are the dofs' axes `A` where the dof moves the body,
  so their sum is `mask^T (M^-1 * A A^T) mask` in the body's dof mask.
  """
  # mask[b, v] = 1 if dof v moves body b (its body is an ancestor of b).
  mask = inertia.ancestor_matrix(m)[np.asarray(m.dof_bodyid)].T
  mask = jnp.asarray(mask, d.cdof.dtype)  # (nbody, nv)
  root_com = d.subtree_com[np.asarray(m.body_rootid)]
  offset = d.xipos - root_com  # (nbody, 3)
  cdof = d.cdof  # (nv, 6): rotation axis, then linear velocity

  def translational(body):
    body_offset, body_mask = body
    jacp = cdof[:, 3:] + jnp.cross(cdof[:, :3], body_offset)
    jacp = jacp * body_mask[:, None]  # (nv, 3)
    return jnp.sum(jacp * (minv @ jacp)) / 3

  tran = jax.lax.map(translational, (offset, mask))
  axes = cdof[:, :3] @ cdof[:, :3].T  # (nv, nv)
  rot = jnp.einsum('bi,ij,bj->b', mask, minv * axes, mask) / 3
  out = jnp.stack([tran, rot], -1)
  weld = np.asarray(m.body_weldid)
  static = np.asarray(m.body_dofnum)[weld] == 0
  simple2 = np.asarray(m.body_simple) == 2
  inv_mass = 1 / jnp.maximum(mx.body_mass, frames.MINVAL)
  out = jnp.where(
      simple2[:, None],
      jnp.stack([inv_mass, jnp.zeros_like(inv_mass)], -1),
      out,
  )
  out = jnp.where(static[:, None], 0.0, out)
  return out.at[0].set(0.0)


def _dof_group_matrix(m) -> np.ndarray:
  """Averages inverse-inertia diagonals per joint as mj_setConst does.

  Over the translations and over the rotations of a free joint, the
  rotations of a ball joint, the one dof of a slide or hinge.
  """
  g = np.zeros((m.nv, m.nv))
  for j in range(m.njnt):
    adr = int(m.jnt_dofadr[j])
    jtype = int(m.jnt_type[j])
    groups = {0: [(0, 3), (3, 6)], 1: [(0, 3)], 2: [(0, 1)], 3: [(0, 1)]}
    for lo, hi in groups[jtype]:
      for r in range(adr + lo, adr + hi):
        g[r, adr + lo : adr + hi] = 1.0 / (hi - lo)
  return g


def _dof_invweight0(m, mx, minv):
  diag = jnp.diagonal(minv)
  group = jnp.asarray(_dof_group_matrix(m), diag.dtype)
  out = group @ diag
  simple2 = np.asarray(m.body_simple)[np.asarray(m.dof_bodyid)] == 2
  inv_mass = 1 / jnp.maximum(
      mx.body_mass[np.asarray(m.dof_bodyid)], frames.MINVAL
  )
  return jnp.where(simple2, inv_mass, out)


def _tendon_spring(host, mx, out):
  """Tendons with automatic spring length take their length at qpos_spring."""
  m = host.m
  auto = []
  for t in range(m.ntendon):
    tendon = host.handles['tendon'].get(t)
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
  out['tendon_lengthspring'] = spring.at[idx].set(
      jnp.stack([length, length], -1)
  )


def dampratio_actuators(host) -> list[int]:
  """Actuators whose spec biasprm[2] > 0 may be a dampratio."""
  out = []
  for a in range(host.m.nu):
    act = host.handles['actuator'].get(a)
    if act is not None and act.biasprm[2] > 0:
      out.append(a)
  return out


def _spec_biasprm2(act, vals):
  """An actuator's biasprm[2] as bound, else as the spec sets it.

  That is, before the compiler turns a dampratio into a damping.
  """
  if 'biasprm' in vals:
    return jnp.asarray(vals['biasprm'], jnp.float32)[2]
  if 'kv' in vals:
    return -jnp.asarray(vals['kv'], jnp.float32)
  return jnp.asarray(act.biasprm[2], jnp.float32)


def _dampratio(host, actuators, d, minv, fields):
  """biasprm[2] of position actuators whose spec sets a dampratio.

  MuJoCo 3.17 uses the inertia reflected through the transmission,
  `1 / (moment . M^-1 . moment)` at qpos0 (checked against the compiler).
  """
  moment = internals.data_impl(d).actuator_moment
  gainprm = fields.get('actuator_gainprm')
  biasprm = fields.get('actuator_biasprm')
  out = biasprm
  for a in actuators:
    act = host.handles['actuator'][a]
    spec_b2 = _spec_biasprm2(act, fields.bound('actuator', a))
    is_pid = act.gaintype == mujoco.mjtGain.mjGAIN_PID
    position_like = jnp.asarray(is_pid) | (gainprm[a, 0] == -biasprm[a, 1])
    inv_mass = moment[a] @ minv @ moment[a]
    mass = 1.0 / jnp.maximum(inv_mass, frames.MINVAL)
    kp = -biasprm[a, 1] if is_pid else gainprm[a, 0]
    damping = spec_b2 * 2 * jnp.sqrt(jnp.maximum(kp * mass, 0.0))
    use = position_like & (spec_b2 > 0)
    out = out.at[a, 2].set(jnp.where(use, -damping, spec_b2))
  fields.fields['actuator_biasprm'] = out


def _camlight(m, mx, d, out):
  if m.ncam:
    body = np.asarray(m.cam_bodyid)
    target = np.asarray(m.cam_targetbodyid)
    xmat = d.xmat[body]
    cam_xpos = d.xpos[body] + jnp.einsum('cij,cj->ci', xmat, mx.cam_pos)
    cam_xmat = xmat @ tr.quat_to_mat(mx.cam_quat)
    com_body = np.where(target >= 0, target, body)
    out['cam_pos0'] = cam_xpos - d.xpos[body]
    out['cam_poscom0'] = cam_xpos - d.subtree_com[com_body]
    out['cam_mat0'] = cam_xmat.reshape(mx.cam_mat0.shape)
  if m.nlight:
    body = np.asarray(m.light_bodyid)
    target = np.asarray(m.light_targetbodyid)
    xmat = d.xmat[body]
    light_xpos = d.xpos[body] + jnp.einsum('lij,lj->li', xmat, mx.light_pos)
    light_xdir = jnp.einsum('lij,lj->li', xmat, mx.light_dir)
    com_body = np.where(target >= 0, target, body)
    out['light_pos0'] = light_xpos - d.xpos[body]
    out['light_poscom0'] = light_xpos - d.subtree_com[com_body]
    out['light_dir0'] = light_xdir


def _eq_data(host, d, fields):
  """Connect/weld data that the compiler computes from poses at qpos0."""
  m = host.m
  data = fields.get('eq_data')
  changed = False
  for e in range(m.neq):
    if m.eq_objtype[e] != mujoco.mjtObj.mjOBJ_BODY:
      continue
    id1, id2 = int(m.eq_obj1id[e]), int(m.eq_obj2id[e])
    eq = host.handles['equality'].get(e)
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
      relative = tr.quat_mul(tr.quat_conj(d.xquat[id1]), d.xquat[id2])
      data = data.at[e, 6:10].set(relative)
      changed = True
  if changed:
    fields.fields['eq_data'] = data


def _stat(m, plan, mx, d, diag_m, fields, auto_stat):
  """mjModel.stat, except values the spec sets (kept as compiled)."""
  stat = fields.model.stat
  updates = {}
  if diag_m is not None and plan.mass_matrix and auto_stat()['meaninertia']:
    updates['meaninertia'] = jnp.mean(diag_m)
  if plan.inertia and auto_stat()['meanmass'] and m.nbody > 1:
    updates['meanmass'] = jnp.mean(mx.body_mass[1:])
  if plan.kinematics:
    center, extent, meansize = geometry_stat(m, mx, d)
    if auto_stat()['meansize'] and m.nbody > 1:
      updates['meansize'] = meansize
    if auto_stat()['extent']:
      updates['extent'] = extent
    if auto_stat()['center']:
      updates['center'] = center
  if updates:
    fields.fields['stat'] = stat.replace(
        **{
            k: jnp.asarray(v, getattr(stat, k).dtype)
            for k, v in updates.items()
        }
    )


def geometry_stat(m, mx, d, xp=jnp):
  """(center, extent, meansize) of the statistics, as mj_setConst.

  Args:
    m: the compiled host model (static structure).
    mx: the model (`geom_rbound`, `geom_size`, `stat.extent`).
    d: kinematics at qpos0 (`xpos`, `xipos`, `xanchor`, `site_xpos`,
      `geom_xpos`).
    xp: `jax.numpy` on the device, `numpy` for host values (`auto_stat`:
      eager JAX operations would each be compiled).
  """
  dtype = xp.result_type(d.xpos)
  rbound = mx.geom_rbound
  size = mx.geom_size
  gtype = np.asarray(m.geom_type)
  plane = gtype == _Geom.mjGEOM_PLANE
  plane_r = xp.where(
      (size[:, 0] != 0) | (size[:, 1] != 0),
      xp.maximum(size[:, 0], size[:, 1]) * 0.1,
      0.01,
  )
  hfield_r = np.zeros(m.ngeom)
  for g in np.nonzero(gtype == _Geom.mjGEOM_HFIELD)[0]:
    hfield_r[g] = np.max(m.hfield_size[m.geom_dataid[g]]) * 0.1
  radius = xp.where(
      rbound > 0,
      rbound,
      xp.where(plane, plane_r, xp.asarray(hfield_r, dtype)),
  )
  points = [d.xpos[1:], d.xipos[1:], d.xanchor, d.site_xpos]
  lows = [p for p in points if p.shape[0]]
  highs = list(lows)
  if m.ngeom:
    lows.append(d.geom_xpos - radius[:, None])
    highs.append(d.geom_xpos + radius[:, None])
  xmin = xp.min(xp.concatenate(lows), axis=0)
  xmax = xp.max(xp.concatenate(highs), axis=0)
  center = 0.5 * (xmin + xmax)
  extent = xp.where(
      xmax[0] > xmin[0],
      xp.maximum(1e-5, xp.max(xmax - xmin)),
      mx.stat.extent,
  )
  # Body sizes: farthest joint anchor (own and children's), then geoms.
  body = xp.zeros(m.nbody, dtype)
  jb = np.asarray(m.jnt_bodyid)
  if m.njnt:
    dist = xp.linalg.norm(d.xipos[jb] - d.xanchor, axis=1)
    body = _scatter_max(xp, body, jb, dist)
    parent = np.asarray(m.body_parentid)[jb]
    dist = xp.linalg.norm(d.xipos[parent] - d.xanchor, axis=1)
    body = _scatter_max(xp, body, parent, dist)
  body = xp.where(np.arange(m.nbody) == 0, 0.0, body)
  if m.ngeom:
    gb = np.asarray(m.geom_bodyid)
    reach = rbound + xp.linalg.norm(d.xipos[gb] - d.geom_xpos, axis=1)
    reach = xp.where((rbound > 0) & (gb > 0), reach, 0.0)
    body = _scatter_max(xp, body, gb, reach)
  meansize = xp.mean(xp.maximum(body[1:], 1e-5)) if m.nbody > 1 else 0.0
  extent = xp.maximum(extent, 2 * meansize)
  return center, extent, meansize


def _scatter_max(xp, values, index, updates):
  """`values.at[index].max(updates)`, also for numpy arrays."""
  if xp is np:
    out = np.array(values)
    np.maximum.at(out, index, updates)
    return out
  return values.at[index].max(updates)


class _HostView:
  """Attribute access to host arrays, for running `geometry_stat` on them."""

  def __init__(self, **arrays):
    self.__dict__.update(arrays)


def auto_stat(m) -> dict[str, bool]:
  """Which statistics the compiler computed (the spec did not set them).

  Recomputes them on the host, at qpos0, with the same functions the device
  uses; a compiled value that differs was set in the spec and must stay.
  """
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
  center, extent, meansize = geometry_stat(m, model, kin, xp=np)
  extent, meansize = float(extent), float(meansize)
  auto = {
      'meaninertia': np.mean(np.diagonal(full)) if m.nv else m.stat.meaninertia,
      'meanmass': np.mean(m.body_mass[1:]) if m.nbody > 1 else m.stat.meanmass,
      'meansize': meansize if m.nbody > 1 else m.stat.meansize,
      'extent': extent,
      'center': center,
  }
  # The device computes in float32: compare at that precision.
  return {
      name: bool(
          np.allclose(auto[name], getattr(m.stat, name), rtol=1e-5, atol=1e-7)
      )
      for name in auto
  }
