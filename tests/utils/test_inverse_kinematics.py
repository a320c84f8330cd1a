"""Inverse kinematics and the rotation helpers it needs, against MuJoCo."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from mjx_composer import environment
from mjx_composer.suite.tasks import reach
from mjx_composer.utils import inverse_kinematics as ik
from mjx_composer.utils import transformations as tr

_TOL = 1e-5  # the default `tol`: float32 kinematics


def test_mat_to_quat_and_quat_to_vel_match_mujoco():
  rng = np.random.default_rng(0)
  quats = rng.normal(size=(500, 4))
  quats /= np.linalg.norm(quats, axis=1, keepdims=True)
  # Each of Shepperd's four cases, and rotations by about pi.
  quats[:4] = np.eye(4)
  quats[4] = [1e-4, 1.0, 0.0, 0.0]
  quats[4] /= np.linalg.norm(quats[4])
  mats = np.zeros((len(quats), 9))
  expected_quats = np.zeros_like(quats)
  expected_vels = np.zeros((len(quats), 3))
  for i, q in enumerate(quats):
    mujoco.mju_quat2Mat(mats[i], q)
    mujoco.mju_mat2Quat(expected_quats[i], mats[i])
    mujoco.mju_quat2Vel(expected_vels[i], q, 1.0)
  got = np.asarray(tr.mat_to_quat(mats.reshape(-1, 3, 3)))
  # The same rotation: q and -q are one (MuJoCo returns either sign).
  np.testing.assert_allclose(
      np.minimum(
          np.abs(got - expected_quats).max(1),
          np.abs(got + expected_quats).max(1),
      ),
      0.0,
      atol=1e-6,
  )
  assert np.all(got[:, 0] >= 0)
  np.testing.assert_allclose(tr.quat_to_vel(quats), expected_vels, atol=1e-5)


@pytest.fixture(scope='module')
def arm_world():
  task = reach.Reach(randomize=False)
  env = environment.Environment(task)
  state = jax.jit(env.reset)(jax.random.key(0))
  return env, task.arm, env.physics(state)


def _host_site_pose(mj_model, qpos, site_name):
  data = mujoco.MjData(mj_model)
  data.qpos[:] = qpos
  mujoco.mj_kinematics(mj_model, data)
  site = mj_model.site(site_name).id
  quat = np.zeros(4)
  mujoco.mju_mat2Quat(quat, data.site_xmat[site])
  return data.site_xpos[site].copy(), quat


def test_reaches_poses_of_the_arm_checked_by_mujoco(arm_world):
  """Targets are poses MuJoCo computes for random joint angles."""
  env, arm, physics = arm_world
  mj_model = env.mj_model
  rng = np.random.default_rng(1)
  joints = rng.uniform([-2.0, -1.2, -2.0], [2.0, 1.2, 2.0], (6, 3))
  poses = []
  for q in joints:
    qpos = mj_model.qpos0.copy()
    qpos[:3] = q
    poses.append(_host_site_pose(mj_model, qpos, 'arm/hand'))
  positions = jnp.asarray([p for p, _ in poses], jnp.float32)
  quats = jnp.asarray([q for _, q in poses], jnp.float32)

  @jax.jit
  @jax.vmap
  def solve(position, quat):
    by_position = ik.qpos_from_site_pose(
        physics, arm.hand, target_pos=position, joints=arm.joints
    )
    by_pose = ik.qpos_from_site_pose(
        physics, arm.hand, target_pos=position, target_quat=quat,
        joints=arm.joints, max_steps=200,
    )  # fmt: skip
    return by_position, by_pose

  by_position, by_pose = solve(positions, quats)
  # From the same start, position-only solves converge for these targets.
  assert np.all(by_position.success), by_position.err_norm
  assert np.all(by_position.err_norm < _TOL)
  assert np.all(by_position.steps < 100)
  for qpos, target in zip(np.asarray(by_position.qpos), np.asarray(positions)):
    position, _ = _host_site_pose(mj_model, qpos, 'arm/hand')
    np.testing.assert_allclose(position, target, atol=2 * _TOL)
    # Only the arm's joints moved.
    np.testing.assert_array_equal(qpos[3:], np.asarray(physics.data.qpos[3:]))
  # Pose targets: where the solve succeeds, MuJoCo agrees on position and
  # orientation.
  assert by_pose.success.sum() >= 3
  for qpos, ok, target_pos, target_quat in zip(
      np.asarray(by_pose.qpos), np.asarray(by_pose.success), positions, quats
  ):
    if ok:
      position, quat = _host_site_pose(mj_model, qpos, 'arm/hand')
      np.testing.assert_allclose(position, target_pos, atol=2 * _TOL)
      angle = 2 * np.arccos(min(1.0, abs(float(np.dot(quat, target_quat)))))
      assert angle < 1e-3


def test_an_unreachable_target_fails_without_moving_other_joints(arm_world):
  _, arm, physics = arm_world
  result = jax.jit(
      lambda: ik.qpos_from_site_pose(
          physics, arm.hand, target_pos=jnp.array([2.0, 0.0, 0.3])
      )
  )()
  assert not result.success
  assert result.err_norm > 1.0
  np.testing.assert_array_equal(
      np.asarray(result.qpos[3:]), np.asarray(physics.data.qpos[3:])
  )


def test_bad_arguments_are_refused_at_trace_time(arm_world):
  env, arm, physics = arm_world
  with pytest.raises(ValueError, match='At least one of'):
    ik.qpos_from_site_pose(physics, arm.hand)
  ball_joint = env.task.ball.freejoint
  with pytest.raises(ValueError, match='hinge and slide joints only'):
    ik.qpos_from_site_pose(
        physics, arm.hand, target_pos=np.zeros(3), joints=[ball_joint]
    )
