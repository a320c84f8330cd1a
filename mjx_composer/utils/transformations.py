"""Quaternion helpers in MuJoCo's (w, x, y, z) convention.

Pure functions that act on the last axis and broadcast over leading axes.
They compute with `jax.numpy` by default; functions that take `xp` compute
with `numpy` given `xp=np` (e.g. float64 constants computed on the host).
"""

import jax.numpy as jnp


def quat_mul(a, b, xp=jnp):
  """Hamilton product `a ⊗ b` (apply `b`, then `a`), like `mju_mulQuat`."""
  aw, ax, ay, az = xp.moveaxis(xp.asarray(a), -1, 0)
  bw, bx, by, bz = xp.moveaxis(xp.asarray(b), -1, 0)
  return xp.stack(
      [
          aw * bw - ax * bx - ay * by - az * bz,
          aw * bx + ax * bw + ay * bz - az * by,
          aw * by - ax * bz + ay * bw + az * bx,
          aw * bz + ax * by - ay * bx + az * bw,
      ],
      axis=-1,
  )


def quat_conj(q, xp=jnp):
  q = xp.asarray(q)
  return q * xp.asarray([1.0, -1.0, -1.0, -1.0], dtype=q.dtype)


def rotate_vec(quat, vec):
  """Rotates `vec` by the unit quaternion `quat`, like `mju_rotVecQuat`."""
  vec = jnp.asarray(vec)
  vq = jnp.concatenate([jnp.zeros(vec.shape[:-1] + (1,), vec.dtype), vec], -1)
  return quat_mul(quat_mul(quat, vq), quat_conj(quat))[..., 1:]


def quat_to_mat(q, xp=jnp):
  """The (..., 3, 3) rotation matrix of unit quaternions, like `mju_quat2Mat`."""
  w, x, y, z = xp.moveaxis(xp.asarray(q), -1, 0)
  rows = (
      (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
      (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
      (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
  )
  return xp.stack([xp.stack(row, axis=-1) for row in rows], axis=-2)


def normalize(q, tolerance=None, xp=jnp):
  """`q / |q|` along the last axis.

  Args:
    q: the vectors (quaternions) to normalize.
    tolerance: if given, MuJoCo's compiler rule (`mjuu_normvec`): vectors
      whose norm is below `tolerance`, or within `tolerance` of 1, are left
      as they are.
    xp: `jax.numpy` (default) or `numpy`.
  """
  q = xp.asarray(q)
  norm = xp.linalg.norm(q, axis=-1, keepdims=True)
  if tolerance is None:
    return q / norm
  keep = (norm < tolerance) | (xp.abs(norm - 1) <= tolerance)
  return q * xp.where(keep, 1.0, 1.0 / xp.maximum(norm, tolerance))
