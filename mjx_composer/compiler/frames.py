"""Compiled poses of varied local poses, and MuJoCo's numeric tolerances.

A compiled pose is `frame * local pose`, where the frame (that of an
attached entity, of `MjsFrame`s, ...) is constant: we recover it once from
the compiled and the spec pose, in float64 on the host.
"""

import jax.numpy as jnp
import numpy as np

from mjx_composer.utils import transformations as tr

EPS = 1e-14  # mjEPS (user_util.h)
MINVAL = 1e-15  # mjMINVAL
MAXVAL = 1e10  # mjMAXVAL


def normalize_quat(q, xp=jnp):
  """MuJoCo's `mjuu_normvec`: leave (near-)unit and (near-)zero alone."""
  return tr.normalize(q, tolerance=EPS, xp=xp)


def frame_between(compiled_pos, compiled_quat, local_pos, local_quat):
  """(pos, quat) of F with compiled = F * local (MuJoCo's frameaccum)."""
  local_quat = normalize_quat(np.asarray(local_quat, np.float64), xp=np)
  fq = tr.quat_mul(
      np.asarray(compiled_quat, np.float64),
      tr.quat_conj(local_quat, xp=np),
      xp=np,
  )
  rot = tr.quat_to_mat(fq, xp=np)
  fp = np.asarray(compiled_pos, np.float64) - rot @ np.asarray(
      local_pos, np.float64
  )
  return fp, fq


def apply_frame(frame, pos=None, quat=None):
  """Compiled pose of a local pose under a constant frame (pos, quat)."""
  fp, fq = frame
  out = []
  if pos is not None:
    rot = jnp.asarray(tr.quat_to_mat(fq, xp=np), pos.dtype)
    out.append(jnp.asarray(fp, pos.dtype) + rot @ pos)
  if quat is not None:
    out.append(tr.quat_mul(jnp.asarray(fq, quat.dtype), normalize_quat(quat)))
  return out[0] if len(out) == 1 else tuple(out)
