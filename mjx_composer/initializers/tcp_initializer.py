"""`ToolCenterPointInitializer`: puts a robot's tool at a sampled pose.

Batched counterpart of composer's `initializers.ToolCenterPointInitializer`.
For one world (`jax.vmap` runs every world at once, each until its own
success): up to `max_rejection_samples` times, a target position and
orientation are drawn from `position` and `quaternion`, and the arm's
`set_site_to_xpos` solves inverse kinematics for the tool centre point (the
hand's `tool_center_point`, or the arm's `wrist_site` without a hand). A
solution is kept unless it collides, as composer counts collisions: a
contact with `dist <= 0` between two of the robot's geoms (except two of the
hand's), or between a robot geom and a geom of anything that is not a free
body (the floor, fixed props, the world). Contacts with free bodies, and
contacts not involving the robot, do not count. After a rejected sample the
arm's joints are restored, as composer restores them.

When no sample succeeds, the episode is marked with
`physics.fail_initialization()` (composer raises `EpisodeInitializationError`)
and the arm keeps its pose from before the call; the `Environment` then
reruns the `initialize_episode` hooks with a fresh key, up to
`max_reset_attempts` times.

Differences from composer's: `quaternion=None` matches the position only
(an arm with fewer than six joints cannot reach most orientations), and the
position and quaternion must be stateless variations (distributions,
constants, callables): a stateful one (e.g. `deterministic.Sequence`) is
refused when the initializer is called.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjx_composer import initializer
from mjx_composer import robot
from mjx_composer.initializers import contacts
from mjx_composer.variation import structures


def _free_body_geoms(mj_model):
  """Geoms of bodies whose root body hangs from the world by a freejoint."""
  free_roots = {
      int(mj_model.jnt_bodyid[j])
      for j in range(mj_model.njnt)
      if mj_model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE
  }
  roots = mj_model.body_rootid[mj_model.geom_bodyid]
  return np.flatnonzero(np.isin(roots, list(free_roots))).astype(np.int32)


def relevant_pair_groups(mj_model, index, arm, hand=None):
  """The geom pairs whose contacts reject a solution (see the module doc).

  Returns:
    `((MJX function key, (n, 2) geom ids), ...)`, as `contacts.pair_groups`.
  """
  arm_geoms = contacts.entity_geoms(index, arm)
  hand_geoms = (
      np.zeros(0, np.int32)
      if hand is None
      else contacts.entity_geoms(index, hand)
  )
  robot_geoms = np.union1d(arm_geoms, hand_geoms)
  # Free bodies' contacts never count; a hand or arm is not a free body.
  free = np.setdiff1d(_free_body_geoms(mj_model), robot_geoms)
  groups = []
  for key, pairs in contacts.pair_groups(mj_model, robot_geoms, free):
    hand_hand = np.isin(pairs, hand_geoms).all(axis=1)
    pairs = pairs[~hand_hand]
    if pairs.size:
      groups.append((key, pairs))
  return tuple(groups)


class ToolCenterPointInitializer(initializer.Initializer):
  """Puts a hand's tool centre point (or an arm's wrist) at a sampled pose.

  Args:
    hand: the `RobotHand` whose `tool_center_point` is placed, or None to
      place the arm's `wrist_site`.
    arm: the `RobotArm` whose joints move.
    position: (3,) target position: a constant, or a stateless variation.
    quaternion: (4,) target orientation likewise (composer's default points
      the tool down), or None for position only.
    ignore_collisions: keep the first solution whatever it touches.
    max_ik_attempts: inverse-kinematics solves per sample (the first from
      the current pose, the rest from random poses).
    max_rejection_samples: targets drawn before the episode fails.
  """

  def __init__(
      self,
      hand,
      arm,
      position,
      quaternion=robot.DOWN_QUATERNION,
      ignore_collisions=False,
      max_ik_attempts=10,
      max_rejection_samples=10,
  ):
    if max_ik_attempts < 1 or max_rejection_samples < 1:
      raise ValueError(
          'max_ik_attempts and max_rejection_samples must be at least 1, '
          f'got {max_ik_attempts} and {max_rejection_samples}.'
      )
    self._hand = hand
    self._arm = arm
    self._position = position
    self._quaternion = quaternion
    self._ignore_collisions = bool(ignore_collisions)
    self._max_ik_attempts = int(max_ik_attempts)
    self._max_rejection_samples = int(max_rejection_samples)
    for name, structure in (('position', position), ('quaternion', quaternion)):
      if structures.initial_state(structure) is not None:
        raise ValueError(
            f'ToolCenterPointInitializer: {name} is a stateful variation; '
            'pass a distribution, a constant or a callable (its state would '
            'have to persist across episodes per world).'
        )

  @property
  def tool_center_point(self):
    """The site that is placed."""
    if self._hand is None:
      return self._arm.wrist_site
    return self._hand.tool_center_point

  def pair_groups(self, physics):
    """The geom pairs whose contacts reject a solution."""
    return relevant_pair_groups(
        physics.mj_model, physics.index, self._arm, self._hand
    )

  def __call__(self, physics, key):
    """Places the tool of one world; returns the new `Physics`.

    The returned physics has its kinematics recomputed and is marked with
    `fail_initialization` where every sample failed.
    """
    groups = () if self._ignore_collisions else self.pair_groups(physics)
    initial_qpos = physics.data.qpos
    dtype = initial_qpos.dtype
    site = self.tool_center_point

    def collides(candidate):
      if not groups:
        return jnp.zeros((), bool)
      data = candidate.kinematics().data
      distance = contacts.min_distance(
          candidate.model, data, groups, mj_model=physics.mj_model
      )
      return distance <= 0

    def sample(loop):
      n, _, _ = loop
      pos_key, quat_key, ik_key = jax.random.split(
          jax.random.fold_in(key, n), 3
      )
      target_pos, _ = structures.sample(self._position, None, pos_key)
      target_pos = jnp.broadcast_to(jnp.asarray(target_pos, dtype), (3,))
      target_quat = None
      if self._quaternion is not None:
        target_quat, _ = structures.sample(self._quaternion, None, quat_key)
        target_quat = jnp.broadcast_to(jnp.asarray(target_quat, dtype), (4,))
      # Every sample starts from the pose before the call (`physics`).
      candidate, solved = self._arm.set_site_to_xpos(
          physics,
          ik_key,
          site,
          target_pos,
          target_quat,
          max_ik_attempts=self._max_ik_attempts,
      )
      # A drawn NaN or infinity (target or solution) is rejected as a
      # collision is, whatever the solver made of it.
      finite = jnp.all(jnp.isfinite(target_pos)) & jnp.all(
          jnp.isfinite(candidate.data.qpos)
      )
      if target_quat is not None:
        finite = finite & jnp.all(jnp.isfinite(target_quat))
      found = solved & finite & jnp.logical_not(collides(candidate))
      # A rejected sample leaves the joints as they were (composer restores).
      qpos = jnp.where(found, candidate.data.qpos, initial_qpos)
      return n + 1, qpos, found

    def searching(loop):
      n, _, found = loop
      return jnp.logical_and(
          jnp.logical_not(found), n < self._max_rejection_samples
      )

    init = (jnp.zeros((), jnp.int32), initial_qpos, jnp.zeros((), bool))
    _, qpos, found = jax.lax.while_loop(searching, sample, init)
    physics = physics.replace(data=physics.data.replace(qpos=qpos))
    return physics.fail_initialization(jnp.logical_not(found)).kinematics()
