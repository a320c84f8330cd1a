"""Variations of 3D rotations, as unit quaternions in MuJoCo's (w, x, y, z) order.

Mirrors `dm_control.composer.variation.rotations`. All quaternion arithmetic
acts on the last axis and broadcasts over leading axes.

Deviation from composer: the operands that *define* a rotation (`axis` and
`angle` of `QuaternionFromAxisAngle`, `quat` of `QuaternionPreMultiply` and
`QuaternionRotate`) are evaluated without the initial and current value.
composer hands them the quaternion being varied, so a distribution used as an
angle was drawn with the quaternion's shape (4,) and the result was unusable
unless `single_sample=True`; with `single_sample=True`, or with constants,
both behave the same. `QuaternionRotate`'s `vec` operand does receive the
initial and current value, since it is the value being varied.
"""

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer.utils import transformations as tr
from mjx_composer.variation import arrays as arrays_lib
from mjx_composer.variation import base
from mjx_composer.variation import composite
from mjx_composer.variation import printing

IDENTITY_QUATERNION = np.array([1.0, 0.0, 0.0, 0.0])

_EPS = 1e-12


def _axisangle_to_quat(rotation_vector):
  """Quaternion of the rotation by `|r|` around `r / |r|` (identity at 0).

  Like dm_control's `transformations.axisangle_to_quat`, the axis is not
  assumed to be unit length: the angle is the norm of `axis * angle`.
  """
  r = jnp.asarray(rotation_vector, arrays_lib.float_dtype(rotation_vector))
  angle = jnp.linalg.norm(r, axis=-1, keepdims=True)
  small = angle < _EPS
  safe_angle = jnp.where(small, 1.0, angle)
  axis = jnp.where(small, 0.0, r / safe_angle)
  w = jnp.where(small, 1.0, jnp.cos(angle / 2))
  xyz = axis * jnp.where(small, 0.0, jnp.sin(angle / 2))
  return jnp.concatenate([w, xyz], axis=-1)


class UniformQuaternion(base.Variation):
  """Unit quaternions uniformly distributed over all rotations (shape (4,)).

  Uses composer's construction from three uniforms (Shoemake's method);
  like composer it ignores the initial value and returns one quaternion.
  """

  def _sample(self, state, key, initial_value, current_value):
    self._require_key(key)
    dtype = arrays_lib.float_dtype()
    u1, u2, u3 = jax.random.uniform(key, (3,), dtype) * jnp.asarray(
        [1.0, 2 * np.pi, 2 * np.pi], dtype
    )
    a, b = jnp.sqrt(1.0 - u1), jnp.sqrt(u1)
    quat = jnp.stack(
        [a * jnp.sin(u2), a * jnp.cos(u2), b * jnp.sin(u3), b * jnp.cos(u3)]
    )
    return quat, state

  def static_bounds(self):
    return np.asarray(-1.0), np.asarray(1.0)

  def _eq_fields(self):
    return ()


class QuaternionFromAxisAngle(composite.CompositeVariation):
  """The quaternion rotating by `angle` around `axis`.

  Computes `axisangle_to_quat(axis * angle)`, as composer: a non-unit axis
  scales the angle by its norm.
  """

  def __init__(self, axis, angle):
    """Initializes a `QuaternionFromAxisAngle`.

    Args:
      axis: (3,) rotation axis: constant or variation (e.g.
        `UniformPointOnSphere()`).
      angle: angle in radians: constant or variation.
    """
    self._axis, self._angle = axis, angle
    self._operands = (axis, angle)

  def _operand_inputs(self, initial_value, current_value):
    return [(None, None)] * 2  # See the module docstring.

  def _apply(self, values, key, initial_value, current_value):
    axis, angle = (arrays_lib.as_array(v) for v in values)
    return _axisangle_to_quat(axis * angle)

  def _eq_fields(self):
    return (self._axis, self._angle)

  def __repr__(self):
    return printing.format_call(
        type(self).__name__, axis=self._axis, angle=self._angle
    )


class QuaternionPreMultiply(composite.CompositeVariation):
  """`quat * (current if cumulative else initial)`: rotates an orientation.

  Pre-multiplication applies `quat` in the parent (world) frame after the
  existing rotation.
  """

  def __init__(self, quat, cumulative=False):
    """Initializes a `QuaternionPreMultiply`.

    Args:
      quat: (4,) quaternion: constant or variation.
      cumulative: multiply `current_value` instead of `initial_value`.
    """
    self._quat = quat
    self._cumulative = bool(cumulative)
    self._operands = (quat,)

  def _operand_inputs(self, initial_value, current_value):
    return [(None, None)]  # See the module docstring.

  def _apply(self, values, key, initial_value, current_value):
    base_quat = current_value if self._cumulative else initial_value
    if base_quat is None:
      which = "current_value" if self._cumulative else "initial_value"
      raise ValueError(f"{self!r} multiplies {which}, but {which} is None.")
    quat = arrays_lib.as_array(values[0])
    base_quat = jnp.asarray(base_quat)
    dtype = arrays_lib.float_dtype(quat, base_quat)
    return tr.quat_mul(quat.astype(dtype), base_quat.astype(dtype))

  def _eq_fields(self):
    return (self._quat, self._cumulative)

  def __repr__(self):
    extra = {"cumulative": True} if self._cumulative else {}
    return printing.format_call(type(self).__name__, self._quat, **extra)


class QuaternionRotate(composite.CompositeVariation):
  """Rotates a 3-vector by `quat`.

  The vector is `vec` if given (a constant or variation, evaluated with the
  initial and current value), otherwise the value being varied:
  `current_value` if `cumulative` else `initial_value`.
  """

  def __init__(self, quat, vec=None, cumulative=False):
    """Initializes a `QuaternionRotate`.

    Args:
      quat: (4,) quaternion: constant or variation.
      vec: (..., 3) vector to rotate, or `None` for the varied value.
      cumulative: when `vec` is None, rotate `current_value` instead of
        `initial_value`.
    """
    self._quat, self._vec = quat, vec
    self._cumulative = bool(cumulative)
    self._operands = (quat, vec)

  def _operand_inputs(self, initial_value, current_value):
    return [(None, None), (initial_value, current_value)]

  def _apply(self, values, key, initial_value, current_value):
    quat, vec = values
    if self._vec is None:
      vec = current_value if self._cumulative else initial_value
      if vec is None:
        which = "current_value" if self._cumulative else "initial_value"
        raise ValueError(
            f"{self!r} rotates {which} (no vec given), but {which} is None."
        )
    vec = jnp.asarray(vec)
    vec = vec.astype(arrays_lib.float_dtype(vec))
    return tr.rotate_vec(jnp.asarray(arrays_lib.as_array(quat), vec.dtype), vec)

  def _eq_fields(self):
    return (self._quat, self._vec, self._cumulative)

  def __repr__(self):
    kwargs = {}
    if self._vec is not None:
      kwargs["vec"] = self._vec
    if self._cumulative:
      kwargs["cumulative"] = True
    return printing.format_call(type(self).__name__, self._quat, **kwargs)
