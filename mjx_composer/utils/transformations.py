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


def mat_to_quat(mat):
  """The unit quaternion of (..., 3, 3) rotation matrices, like `mju_mat2Quat`.

  Shepperd's method, branch-free: each of the four candidate formulas is
  computed and the one with the largest pivot (the most accurate) kept, so
  the result is finite for every rotation. Of the two quaternions of a
  rotation it returns the one with `w >= 0` (MuJoCo's may return either).
  """
  mat = jnp.asarray(mat)
  m00, m11, m22 = mat[..., 0, 0], mat[..., 1, 1], mat[..., 2, 2]
  pivots = jnp.stack(
      [1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22,
       1 - m00 - m11 + m22],
      axis=-1,
  )  # fmt: skip
  d = lambda i, j: mat[..., i, j]
  candidates = jnp.stack(
      [
          jnp.stack([pivots[..., 0], d(2, 1) - d(1, 2), d(0, 2) - d(2, 0),
                     d(1, 0) - d(0, 1)], -1),
          jnp.stack([d(2, 1) - d(1, 2), pivots[..., 1], d(0, 1) + d(1, 0),
                     d(0, 2) + d(2, 0)], -1),
          jnp.stack([d(0, 2) - d(2, 0), d(0, 1) + d(1, 0), pivots[..., 2],
                     d(1, 2) + d(2, 1)], -1),
          jnp.stack([d(1, 0) - d(0, 1), d(0, 2) + d(2, 0), d(1, 2) + d(2, 1),
                     pivots[..., 3]], -1),
      ],
      axis=-2,
  )  # fmt: skip
  best = jnp.argmax(pivots, axis=-1)
  q = jnp.take_along_axis(candidates, best[..., None, None], axis=-2)[..., 0, :]
  q = q / jnp.linalg.norm(q, axis=-1, keepdims=True)
  return q * jnp.where(q[..., :1] < 0, -1.0, 1.0)


def quat_to_vel(q):
  """The rotation vector (axis x angle, angle in [-pi, pi]) of unit `q`.

  Like `mju_quat2Vel(res, q, 1)`: the angular velocity that rotates by `q`
  in unit time.
  """
  q = jnp.asarray(q)
  xyz = q[..., 1:]
  sin_half = jnp.linalg.norm(xyz, axis=-1, keepdims=True)
  angle = 2 * jnp.arctan2(sin_half, q[..., :1])
  angle = jnp.where(angle > jnp.pi, angle - 2 * jnp.pi, angle)
  safe = jnp.where(sin_half > 0, sin_half, 1.0)
  return jnp.where(sin_half > 0, xyz * (angle / safe), 0.0)


def yaw_quaternion(yaw):
  """The quaternion (4,) of a rotation by `yaw` about the world's z axis."""
  return jnp.stack(
      [jnp.cos(yaw / 2), 0.0 * yaw, 0.0 * yaw, jnp.sin(yaw / 2)]
  ).astype(jnp.float32)
