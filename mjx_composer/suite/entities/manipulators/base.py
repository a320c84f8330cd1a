"""`RobotArm` and `RobotHand`: the robots that `ToolCenterPointInitializer` moves.

dm_control's `entities/manipulators/base.py`, as pure functions of a
`Physics` and a key: `randomize_arm_joints` draws a pose, and
`set_site_to_xpos` solves inverse kinematics (`utils.inverse_kinematics`)
with random restarts and returns the new `Physics` with a success flag,
where dm_control writes the physics in place and returns the flag.
"""

from __future__ import annotations

import abc

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjx_composer import robot
from mjx_composer.utils import inverse_kinematics

_HINGE = int(mujoco.mjtJoint.mjJNT_HINGE)
# dm_control's arms weigh the rotation error twice in their IK.
_ROT_WEIGHT = 2.0


class RobotArm(robot.Robot, metaclass=abc.ABCMeta):
  """A robot arm: joints, a wrist site, and inverse kinematics."""

  @property
  @abc.abstractmethod
  def joints(self):
    """The arm's `MjsJoint` handles (hinge or slide), base to tip."""

  @property
  @abc.abstractmethod
  def wrist_site(self):
    """The `MjsSite` at the wrist (where a hand attaches)."""

  @property
  def attachment_site(self):
    """Children (a hand) attach at the wrist."""
    return self.wrist_site

  def _joint_tables(self, physics):
    """(qpos addresses, hinge mask, low, high, limited mask) of the joints.

    `low`/`high` are the sampling bounds: the range of a limited joint,
    [0, 2 pi] for an unlimited hinge. An unlimited slide joint is refused.
    """
    mj_model = physics.mj_model
    ids = np.asarray(physics.bind(list(self.joints)).element_ids, np.int32)
    addresses = inverse_kinematics.joint_addresses(mj_model, ids)
    hinge = mj_model.jnt_type[ids] == _HINGE
    limited = mj_model.jnt_limited[ids].astype(bool)
    if np.any(~hinge & ~limited):
      names = [
          mujoco.mj_id2name(mj_model, mujoco.mjtObj.mjOBJ_JOINT, int(j))
          for j in ids[~hinge & ~limited]
      ]
      raise ValueError(
          f'{type(self).__name__}: every non-hinge joint needs limits to be '
          f'sampled; these have none: {names}. Give them a range.'
      )
    low, high = mj_model.jnt_range[ids].T
    low = np.where(limited, low, 0.0)
    high = np.where(limited, high, 2 * np.pi)
    return addresses, hinge, low, high, limited

  def randomize_arm_joints(self, physics, key):
    """Each joint uniform in its range ([0, 2 pi) for unlimited hinges)."""
    addresses, _, low, high, _ = self._joint_tables(physics)
    dtype = physics.data.qpos.dtype
    qpos = jax.random.uniform(
        key, (len(addresses),), dtype, jnp.asarray(low), jnp.asarray(high)
    )
    data = physics.data.replace(qpos=physics.data.qpos.at[addresses].set(qpos))
    return physics.replace(data=data).mark_written('qpos')

  def set_site_to_xpos(
      self,
      physics,
      key,
      site,
      target_pos,
      target_quat=None,
      max_ik_attempts=10,
  ):
    """Moves the arm's joints so that `site` reaches the target pose.

    Up to `max_ik_attempts` inverse-kinematics solves (rotation weight 2,
    as dm_control's): the first from the current pose, each later one from
    `randomize_arm_joints`. A solve succeeds when it reaches the target and
    its hinge angles can be brought, by whole turns, into their sampling
    bounds (an angle at or above the upper bound is turned down below it,
    then one below the lower bound up; past the upper bound it fails).

    Args:
      physics: the world's `Physics`.
      key: a JAX PRNG key (the restarts' poses).
      site: the `MjsSite` to move (e.g. a hand's tool centre point).
      target_pos: (3,) world position.
      target_quat: (4,) world orientation, or None for position only
        (dm_control's points the site down instead: pass
        `robot.DOWN_QUATERNION` for that).
      max_ik_attempts: the most solves.

    Returns:
      `(physics, success)`: the joints as the last solve left them (the
      successful one's, where one succeeded); only `qpos` is written.
    """
    addresses, hinge, low, high, _ = self._joint_tables(physics)
    low = jnp.asarray(low, physics.data.qpos.dtype)
    high = jnp.asarray(high, physics.data.qpos.dtype)
    turn = 2 * np.pi

    def solve(start):
      result = inverse_kinematics.qpos_from_site_pose(
          start,
          site,
          target_pos=target_pos,
          target_quat=target_quat,
          joints=self.joints,
          rot_weight=_ROT_WEIGHT,
      )
      q = result.qpos[addresses]
      down = jnp.where(q >= high, jnp.floor((q - high) / turn) + 1, 0.0)
      q_down = q - turn * down
      up = jnp.where(q_down < low, jnp.ceil((low - q_down) / turn), 0.0)
      q_turned = q_down + turn * up
      q = jnp.where(hinge, q_turned, q)
      in_bounds = jnp.all((q >= low) & (q <= high))
      qpos = result.qpos.at[addresses].set(q)
      return qpos, jnp.logical_and(result.success, in_bounds)

    def attempt(loop):
      n, qpos, _ = loop
      start = physics.replace(data=physics.data.replace(qpos=qpos))
      restart = self.randomize_arm_joints(start, jax.random.fold_in(key, n))
      start_qpos = jnp.where(n == 0, qpos, restart.data.qpos)
      qpos, success = solve(
          physics.replace(data=physics.data.replace(qpos=start_qpos))
      )
      return n + 1, qpos, success

    def trying(loop):
      n, _, success = loop
      return jnp.logical_and(jnp.logical_not(success), n < max_ik_attempts)

    init = (jnp.zeros((), jnp.int32), physics.data.qpos, jnp.zeros((), bool))
    _, qpos, success = jax.lax.while_loop(trying, attempt, init)
    physics = physics.replace(data=physics.data.replace(qpos=qpos))
    return physics.mark_written('qpos'), success


class RobotHand(robot.Robot, metaclass=abc.ABCMeta):
  """A robot hand: a tool centre point and a grasp."""

  @property
  @abc.abstractmethod
  def tool_center_point(self):
    """The `MjsSite` that `ToolCenterPointInitializer` places."""

  @abc.abstractmethod
  def set_grasp(self, physics, close_factors):
    """Returns `physics` with the hand closed by `close_factors` in [0, 1]."""
