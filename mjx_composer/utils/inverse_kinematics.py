"""Inverse kinematics: joint positions that put a site at a target pose.

The jitted counterpart of dm_control's `utils.inverse_kinematics.
qpos_from_site_pose`, with its algorithm and defaults: damped least squares
(Levenberg-Marquardt) on the site's position and orientation error, the
damping switched on while the error is above `regularization_threshold`,
each update capped at `max_update_norm`, and a stop when an update no longer
makes progress (`err_norm / update_norm > progress_thresh`). Each iteration
runs MJX's kinematics and `mjx.jac` on one world; under `jax.vmap` every
world iterates until its own stop (a batched `lax.while_loop`).

Differences from dm_control's:

* `tol` defaults to 1e-5 instead of 1e-14: MJX computes in float32, whose
  site positions carry rounding errors of about 1e-7 per metre.
* Below `regularization_threshold` the system is damped by 1e-6 instead of
  solved by least squares (a singular Jacobian stays solvable).
* Only hinge and slide joints may move (a robot arm's): their qpos and dof
  coordinates coincide. Other joints are refused at trace time.
* The result is returned (`IKResult.qpos`, the whole qpos vector), not
  written in place: `physics.replace(data=physics.data.replace(qpos=...))`.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np

from mjx_composer.utils import transformations as tr

# dm_control solves the undamped system by least squares (its minimum-norm
# solution where the Jacobian is singular, e.g. a straight arm); a small
# damping floor gives nearly that solution with one linear solve.
_MIN_DAMPING = 1e-6
_MOVABLE = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))


class IKResult(NamedTuple):
  """What `qpos_from_site_pose` found (arrays; batched under vmap).

  Attributes:
    qpos: the whole qpos vector at the last iterate.
    err_norm: its position error norm plus `rot_weight` times its rotation
      error norm.
    steps: iterations run.
    success: `err_norm < tol`.
  """

  qpos: jax.Array
  err_norm: jax.Array
  steps: jax.Array
  success: jax.Array


def joint_addresses(mj_model: mujoco.MjModel, joint_ids) -> np.ndarray:
  """The qpos (= dof) addresses of hinge or slide joints; refuses others."""
  joint_ids = np.asarray(joint_ids, np.int32)
  for j in joint_ids:
    if int(mj_model.jnt_type[j]) not in _MOVABLE:
      name = mujoco.mj_id2name(mj_model, mujoco.mjtObj.mjOBJ_JOINT, int(j))
      raise ValueError(
          f'Inverse kinematics moves hinge and slide joints only; joint '
          f'{name!r} is a {mujoco.mjtJoint(mj_model.jnt_type[j]).name}. '
          "Pass the arm's hinge/slide joints as `joints`."
      )
  return mj_model.jnt_qposadr[joint_ids].astype(np.int32)


def qpos_from_site_pose(
    physics,
    site,
    target_pos=None,
    target_quat=None,
    joints=None,
    tol=1e-5,
    rot_weight=1.0,
    regularization_threshold=0.1,
    regularization_strength=3e-2,
    max_update_norm=2.0,
    progress_thresh=20.0,
    max_steps=100,
) -> IKResult:
  """Joint positions that put `site` at `target_pos` / `target_quat`.

  Args:
    physics: the world's `Physics`; its `data.qpos` is the first iterate.
    site: the `MjsSite` to move.
    target_pos: (3,) world position, or None to match orientation only.
    target_quat: (4,) world orientation (w, x, y, z), or None to match
      position only.
    joints: the hinge/slide `MjsJoint`s that may move (default: every hinge
      and slide joint of the model).
    tol: the error norm below which the target counts as reached.
    rot_weight: weight of the rotation error in `err_norm` (radians against
      metres).
    regularization_threshold: damping is on while `err_norm` is above it.
    regularization_strength: the damping (added to `J^T J`'s diagonal).
    max_update_norm: the largest joint update of one iteration.
    progress_thresh: stop (without success) once `err_norm / update_norm`
      exceeds it.
    max_steps: the most iterations.

  Returns:
    An `IKResult`.
  """
  if target_pos is None and target_quat is None:
    raise ValueError(
        'At least one of `target_pos` or `target_quat` must be specified.'
    )
  mj_model = physics.mj_model
  site_id = int(physics.bind(site).element_ids[0])
  if joints is None:
    joint_ids = [
        j for j in range(mj_model.njnt) if int(mj_model.jnt_type[j]) in _MOVABLE
    ]
  else:
    joint_ids = list(physics.bind(list(joints)).element_ids)
  addresses = joint_addresses(mj_model, joint_ids)
  body_id = int(mj_model.site_bodyid[site_id])
  model = physics.model
  dtype = physics.data.qpos.dtype
  if target_pos is not None:
    target_pos = jnp.asarray(target_pos, dtype)
  if target_quat is not None:
    target_quat = tr.normalize(jnp.asarray(target_quat, dtype))

  def error_and_jacobian(qpos):
    data = mjx.kinematics(model, physics.data.replace(qpos=qpos))
    data = mjx.com_pos(model, data)  # `mjx.jac` reads cdof and subtree_com
    xpos = data.site_xpos[site_id]
    errors, jacobians, norm = [], [], jnp.zeros((), dtype)
    jacp, jacr = mjx.jac(model, data, xpos, body_id)  # (nv, 3) each
    if target_pos is not None:
      err = target_pos - xpos
      errors.append(err)
      jacobians.append(jacp[addresses].T)
      norm = norm + jnp.linalg.norm(err)
    if target_quat is not None:
      site_quat = tr.mat_to_quat(data.site_xmat[site_id])
      err = tr.quat_to_vel(tr.quat_mul(target_quat, tr.quat_conj(site_quat)))
      errors.append(err)
      jacobians.append(jacr[addresses].T)
      norm = norm + rot_weight * jnp.linalg.norm(err)
    return jnp.concatenate(errors), jnp.concatenate(jacobians), norm

  eye = jnp.eye(len(addresses), dtype=dtype)

  def body(loop):
    qpos, steps, _ = loop
    err, jac, err_norm = error_and_jacobian(qpos)
    reached = err_norm < tol
    damping = jnp.where(
        err_norm > regularization_threshold,
        regularization_strength,
        _MIN_DAMPING,
    )
    # Damped least squares: (J^T J + damping I) dq = J^T err.
    update = jnp.linalg.solve(jac.T @ jac + damping * eye, jac.T @ err)
    update_norm = jnp.linalg.norm(update)
    stalled = err_norm / jnp.maximum(update_norm, 1e-30) > progress_thresh
    # A singular system the floor could not tame stops the solve; it never
    # writes a non-finite qpos.
    stalled = jnp.logical_or(
        stalled, jnp.logical_not(jnp.isfinite(update_norm))
    )
    update = update * jnp.minimum(
        1.0, max_update_norm / jnp.maximum(update_norm, 1e-30)
    )
    moved = qpos.at[addresses].add(update)
    done = jnp.logical_or(reached, stalled)
    qpos = jnp.where(done, qpos, moved)
    return qpos, steps + jnp.where(reached, 0, 1), done

  def running(loop):
    _, steps, done = loop
    return jnp.logical_and(jnp.logical_not(done), steps < max_steps)

  init = (physics.data.qpos, jnp.zeros((), jnp.int32), jnp.zeros((), bool))
  qpos, steps, _ = jax.lax.while_loop(running, body, init)
  # A loop stopped by `max_steps` ends on an update: measure where it ended.
  _, _, final_norm = error_and_jacobian(qpos)
  success = final_norm < tol
  return IKResult(qpos, final_norm, steps, success)
