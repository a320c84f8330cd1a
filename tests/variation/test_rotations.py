"""Tests for mjx_composer.variation.rotations.

Quaternion conventions are checked against MuJoCo's own functions (w, x, y, z
order).
"""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from mjx_composer.variation import distributions
from mjx_composer.variation import noises
from mjx_composer.variation import rotations

KEY = jax.random.key(0)
Z = 5.0  # Tolerance in standard errors, as in test_distributions.py.


def _random_unit_quats(n, seed=0):
  q = np.random.default_rng(seed).normal(size=(n, 4))
  return q / np.linalg.norm(q, axis=1, keepdims=True)


def _mj_mul(a, b):
  out = np.zeros(4)
  mujoco.mju_mulQuat(out, np.asarray(a, np.float64), np.asarray(b, np.float64))
  return out


def _mj_rotate(quat, vec):
  out = np.zeros(3)
  mujoco.mju_rotVecQuat(
      out, np.asarray(vec, np.float64), np.asarray(quat, np.float64)
  )
  return out


def test_identity_quaternion():
  np.testing.assert_array_equal(
      rotations.IDENTITY_QUATERNION, [1.0, 0.0, 0.0, 0.0]
  )


def test_uniform_quaternion_is_uniform_over_rotations():
  n = 20_000
  quats = np.asarray(
      jax.jit(jax.vmap(lambda k: rotations.UniformQuaternion()(key=k)))(
          jax.random.split(KEY, n)
      ),
      np.float64,
  )
  assert quats.shape == (n, 4)
  np.testing.assert_allclose(np.linalg.norm(quats, axis=1), 1.0, rtol=1e-5)
  # Uniform on S^3: E[q_i] = 0, E[q_i^2] = 1/4 (Var[q_i^2] = 1/8 - 1/16),
  # E[q_i q_j] = 0 (Var = 1/24).
  for i in range(4):
    assert abs(quats[:, i].mean()) < Z * np.sqrt(1 / 4 / n)
    assert abs((quats[:, i] ** 2).mean() - 1 / 4) < Z * np.sqrt(1 / 16 / n)
    for j in range(i + 1, 4):
      assert abs((quats[:, i] * quats[:, j]).mean()) < Z * np.sqrt(1 / 24 / n)
  # Rotating a fixed vector by a uniform rotation gives a uniform direction.
  rotated = np.stack([_mj_rotate(q, [0.0, 0.0, 1.0]) for q in quats[:2000]])
  assert np.all(np.abs(rotated.mean(axis=0)) < Z * np.sqrt(1 / 3 / 2000))


def test_uniform_quaternion_ignores_the_initial_value_like_composer():
  assert rotations.UniformQuaternion()(jnp.zeros((5, 4)), key=KEY).shape == (4,)


def test_quaternion_from_axis_angle_matches_mujoco():
  rng = np.random.default_rng(1)
  for _ in range(10):
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = rng.uniform(-np.pi, np.pi)
    expected = np.zeros(4)
    mujoco.mju_axisAngle2Quat(expected, axis, angle)
    actual = rotations.QuaternionFromAxisAngle(axis, angle)()
    np.testing.assert_allclose(actual, expected, atol=1e-6)


def test_quaternion_from_axis_angle_edge_cases():
  # composer's quirk: the angle is |axis * angle|, so a non-unit axis scales it.
  np.testing.assert_allclose(
      rotations.QuaternionFromAxisAngle([0.0, 0.0, 2.0], np.pi / 2)(),
      [0, 0, 0, 1],
      atol=1e-6,
  )
  np.testing.assert_array_equal(
      rotations.QuaternionFromAxisAngle([0.0, 0.0, 1.0], 0.0)(),
      rotations.IDENTITY_QUATERNION,
  )


def test_quaternion_from_axis_angle_with_random_operands():
  variation = rotations.QuaternionFromAxisAngle(
      axis=distributions.UniformPointOnSphere(),
      angle=distributions.Uniform(0.0, np.pi),
  )
  # Operands are evaluated without the quaternion being varied, so the
  # distributions draw a (3,) axis and a scalar angle (composer would draw
  # them with the quaternion's shape).
  identity = jnp.asarray(rotations.IDENTITY_QUATERNION)
  sample = jax.jit(jax.vmap(lambda k: variation(identity, None, k)))
  quats = sample(jax.random.split(KEY, 16))
  assert quats.shape == (16, 4)
  np.testing.assert_allclose(np.linalg.norm(quats, axis=1), 1.0, rtol=1e-5)
  assert np.all(
      quats[:, 0] >= -1e-6
  )  # angle in [0, pi] => w = cos(angle/2) >= 0.
  assert len(np.unique(np.asarray(quats[:, 0]))) == 16


def test_quaternion_pre_multiply_matches_mujoco():
  a, b = _random_unit_quats(5, seed=2), _random_unit_quats(5, seed=3)
  for qa, qb in zip(a, b):
    actual = rotations.QuaternionPreMultiply(qa)(initial_value=qb)
    np.testing.assert_allclose(actual, _mj_mul(qa, qb), atol=1e-6)


def test_quaternion_pre_multiply_cumulative_and_not():
  quarter_turn = rotations.QuaternionFromAxisAngle([0.0, 0.0, 1.0], np.pi / 2)
  initial = jnp.asarray(rotations.IDENTITY_QUATERNION)
  for cumulative, expected_last in [
      (False, quarter_turn()),
      (True, [-1.0, 0.0, 0.0, 0.0]),
  ]:
    variation = rotations.QuaternionPreMultiply(
        quarter_turn, cumulative=cumulative
    )
    current = initial
    for _ in range(4):
      current = variation(initial, current)
    # Four quarter turns compose to a full turn: quaternion -1.
    np.testing.assert_allclose(current, expected_last, atol=1e-6)


def test_quaternion_rotate():
  quats, vecs = _random_unit_quats(5, seed=4), np.random.default_rng(5).normal(
      size=(5, 3)
  )
  for q, v in zip(quats, vecs):
    np.testing.assert_allclose(
        rotations.QuaternionRotate(q, vec=v)(), _mj_rotate(q, v), atol=1e-5
    )
  quarter_turn = rotations.QuaternionFromAxisAngle([0.0, 0.0, 1.0], np.pi / 2)
  x, y = jnp.asarray([1.0, 0.0, 0.0]), jnp.asarray([0.0, 1.0, 0.0])
  # Without vec: rotates the initial value, or the current one if cumulative.
  np.testing.assert_allclose(
      rotations.QuaternionRotate(quarter_turn)(x, y), [0, 1, 0], atol=1e-6
  )
  np.testing.assert_allclose(
      rotations.QuaternionRotate(quarter_turn, cumulative=True)(x, y),
      [-1, 0, 0],
      atol=1e-6,
  )
  # A vec operand sees the initial value (it is the value being varied).
  shifted = rotations.QuaternionRotate(
      quarter_turn, vec=noises.Additive([0.0, 1.0, 0.0])
  )
  np.testing.assert_allclose(shifted(x), [-1, 1, 0], atol=1e-6)


def test_rotation_errors_and_repr():
  with pytest.raises(
      ValueError, match="multiplies initial_value, but initial_value is None"
  ):
    rotations.QuaternionPreMultiply(rotations.IDENTITY_QUATERNION)()
  with pytest.raises(ValueError, match="rotates current_value"):
    rotations.QuaternionRotate([1.0, 0, 0, 0], cumulative=True)(jnp.ones(3))
  assert repr(
      rotations.QuaternionFromAxisAngle([0, 0, 1], distributions.Uniform())
  ) == (
      "QuaternionFromAxisAngle(axis=[0, 0, 1], angle=Uniform(low=0.0, high=1.0))"
  )
  assert rotations.UniformQuaternion() == rotations.UniformQuaternion()
