"""Quaternion helpers in MuJoCo's (w, x, y, z) convention, as pure jnp functions."""

import jax.numpy as jnp


def quat_mul(a, b):
  """Hamilton product `a ⊗ b` (apply `b`, then `a`), like `mju_mulQuat`."""
  aw, ax, ay, az = jnp.moveaxis(jnp.asarray(a), -1, 0)
  bw, bx, by, bz = jnp.moveaxis(jnp.asarray(b), -1, 0)
  return jnp.stack(
      [
          aw * bw - ax * bx - ay * by - az * bz,
          aw * bx + ax * bw + ay * bz - az * by,
          aw * by - ax * bz + ay * bw + az * bx,
          aw * bz + ax * by - ay * bx + az * bw,
      ],
      axis=-1,
  )


def quat_conj(q):
  q = jnp.asarray(q)
  return q * jnp.array([1.0, -1.0, -1.0, -1.0], dtype=q.dtype)


def rotate_vec(quat, vec):
  """Rotates `vec` by the unit quaternion `quat`, like `mju_rotVecQuat`."""
  vec = jnp.asarray(vec)
  vq = jnp.concatenate([jnp.zeros(vec.shape[:-1] + (1,), vec.dtype), vec], -1)
  return quat_mul(quat_mul(quat, vq), quat_conj(quat))[..., 1:]


def normalize(q):
  q = jnp.asarray(q)
  return q / jnp.linalg.norm(q, axis=-1, keepdims=True)
