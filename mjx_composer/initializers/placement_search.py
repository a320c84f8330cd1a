"""The search of `PropPlacer`'s placement: collision-free poses, prop by prop.

Rejection sampling, batched: for each prop in order, up to
`max_attempts_per_prop` candidate poses are drawn from `position` and
`quaternion` (composer's two `variation.evaluate` calls, with the prop's
pose at call time as initial value and the previous candidate as current
value) inside a `lax.while_loop`, and the first finite, collision-free one
is kept. A prop with joints of its own, or a fixed one, is tried through
`set_pose` and a kinematics pass (`placement_tables.Single`); a run of
consecutive free rigid props is placed by one `lax.scan` whose candidates
move the props' geoms directly (`placement_tables.RigidRun`). Collisions are
MJX's narrow phase on the pair tables that `contacts` resolves.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from mujoco import mjx
import numpy as np

from mjx_composer.initializers import contacts
from mjx_composer.initializers import placement_tables
from mjx_composer.variation import base as variation_base
from mjx_composer.variation import structures

_POSE_SIZES = {'position': 3, 'quaternion': 4}


class PoseSearch:
  """What a placement draws and how long it searches (`PropPlacer`'s).

  Args:
    props: the attached entities placed, in order.
    position: a fixed position (3,), a variation or a callable drawing one.
    quaternion: a fixed quaternion (4,), a variation or a callable.
    ignore_collisions: take the first finite candidate, unchecked.
    max_attempts_per_prop: candidate poses per prop before it fails.
  """

  def __init__(
      self,
      props,
      position,
      quaternion,
      ignore_collisions: bool,
      max_attempts_per_prop: int,
  ):
    self.props = tuple(props)
    self.position = position
    self.quaternion = quaternion
    self.ignore_collisions = ignore_collisions
    self.max_attempts_per_prop = max_attempts_per_prop

  def sample_pose(self, states, key, initial, current):
    """One candidate pose (composer's two `variation.evaluate` calls)."""
    position_key, quaternion_key = jax.random.split(key)
    position_state, quaternion_state = states
    position, position_state = _draw(
        'position',
        self.position,
        position_state,
        position_key,
        initial[0],
        current[0],
    )
    quaternion, quaternion_state = _draw(
        'quaternion',
        self.quaternion,
        quaternion_state,
        quaternion_key,
        initial[1],
        current[1],
    )
    check_pose_shape('position', position, self.position)
    check_pose_shape('quaternion', quaternion, self.quaternion)
    pose = (
        jnp.broadcast_to(jnp.asarray(position, initial[0].dtype), (3,)),
        jnp.broadcast_to(jnp.asarray(quaternion, initial[1].dtype), (4,)),
    )
    return pose, (position_state, quaternion_state)

  def search(self, key, initial, states, collides):
    """Rejection sampling: the first finite candidate for which `collides`
    is False.

    A candidate with a NaN or an infinity (a variation that drew one) is
    rejected as a colliding one is: its contact distances are NaN, which no
    comparison rejects. Only the candidate pose and the variation states
    are carried, so the loop stays light under vmap. Returns `(pose,
    states, found)`.
    """
    if self.ignore_collisions:
      pose, states = self.sample_pose(states, key, initial, initial)
      return pose, states, _finite(pose)

    def attempt(carry):
      n, _, current, states = carry
      pose, states = self.sample_pose(
          states, jax.random.fold_in(key, n), initial, current
      )
      valid = jnp.logical_and(_finite(pose), jnp.logical_not(collides(pose)))
      return n + 1, valid, pose, states

    def searching(carry):
      n, found, _, _ = carry
      return jnp.logical_and(
          jnp.logical_not(found), n < self.max_attempts_per_prop
      )

    carry = (jnp.zeros((), jnp.int32), jnp.zeros((), bool), initial, states)
    _, found, pose, states = jax.lax.while_loop(searching, attempt, carry)
    return pose, states, found

  def place_props(self, physics, key, tables, states):
    """Places every prop in order; returns (physics, states, failed)."""
    failed = jnp.zeros((), bool)
    # Geom poses of everything already in the scene (the robot may have
    # moved since the last forward pass).
    physics = physics.replace(data=mjx.kinematics(physics.model, physics.data))
    for step in tables.steps:
      if isinstance(step, placement_tables.RigidRun):
        physics, states, step_failed = self._place_run(
            physics, key, step, states
        )
      else:
        physics, states, step_failed = self._place_single(
            physics, key, step, states
        )
      failed = jnp.logical_or(failed, step_failed)
    return physics, states, failed

  def _place_single(self, physics, key, step, states):
    prop = self.props[step.prop_index]
    initial = tuple(jnp.asarray(x) for x in prop.get_pose(physics))

    def collides(pose):
      candidate = prop.set_pose(physics, *pose)
      data = mjx.kinematics(candidate.model, candidate.data)
      return (
          contacts.min_distance(
              candidate.model,
              data,
              step.pair_groups,
              mj_model=physics.mj_model,
          )
          <= 0
      )

    pose, states, found = self.search(
        jax.random.fold_in(key, step.prop_index), initial, states, collides
    )
    physics = prop.set_pose(physics, *pose)
    physics = physics.replace(data=mjx.kinematics(physics.model, physics.data))
    return physics, states, jnp.logical_not(found)

  def _place_run(self, physics, key, run, states):
    """Places a run of rigid free props with one scan over the props."""
    model, data = physics.model, physics.data

    def place(carry, row):
      qpos, geom_xpos, geom_xmat, states, failed = carry
      prop_index, adr, geom_ids, chains, pairs, valid = row

      def geom_poses(pose):
        return contacts.rigid_geom_poses(
            model, pose[0], pose[1], geom_ids, chains
        )

      def collides(pose):
        xpos, xmat = geom_poses(pose)
        candidate = data.replace(
            geom_xpos=geom_xpos.at[geom_ids].set(xpos, mode='drop'),
            geom_xmat=geom_xmat.at[geom_ids].set(xmat, mode='drop'),
        )
        groups = tuple(zip(run.keys, pairs))
        return (
            contacts.min_distance(
                model, candidate, groups, valid, mj_model=physics.mj_model
            )
            <= 0
        )

      initial = (
          jax.lax.dynamic_slice(qpos, (adr,), (3,)),
          jax.lax.dynamic_slice(qpos, (adr + 3,), (4,)),
      )
      pose, states, found = self.search(
          jax.random.fold_in(key, prop_index), initial, states, collides
      )
      # What `set_pose` writes for a free entity.
      qpos = jax.lax.dynamic_update_slice(
          qpos,
          jnp.concatenate([pose[0], pose[1] / jnp.linalg.norm(pose[1])]),
          (adr,),
      )
      xpos, xmat = geom_poses(pose)
      geom_xpos = geom_xpos.at[geom_ids].set(xpos, mode='drop')
      geom_xmat = geom_xmat.at[geom_ids].set(xmat, mode='drop')
      failed = jnp.logical_or(failed, jnp.logical_not(found))
      return (qpos, geom_xpos, geom_xmat, states, failed), None

    carry = (
        data.qpos,
        data.geom_xpos,
        data.geom_xmat,
        states,
        jnp.zeros((), bool),
    )
    rows = (
        run.prop_indices,
        run.qpos_adr,
        run.geom_ids,
        run.chains,
        run.pairs,
        run.valid,
    )
    (qpos, geom_xpos, geom_xmat, states, failed), _ = jax.lax.scan(
        place, carry, rows
    )
    # Body poses are stale until the next kinematics pass; geom poses are
    # current, which is all that the following placements read.
    data = data.replace(qpos=qpos, geom_xpos=geom_xpos, geom_xmat=geom_xmat)
    return physics.replace(data=data), states, failed


def _finite(pose) -> jax.Array:
  """Whether a candidate `(position, quaternion)` is finite."""
  return jnp.logical_and(
      jnp.all(jnp.isfinite(pose[0])), jnp.all(jnp.isfinite(pose[1]))
  )


def _draw(name, structure, state, key, initial, current):
  """`structures.sample`, its shape errors naming the argument."""
  try:
    return structures.sample(structure, state, key, initial, current)
  except ValueError as error:
    raise ValueError(
        f'PropPlacer: `{name}` {structure!r} could not be drawn for a '
        f'{name} of shape {np.shape(initial)}: {error}'
    ) from error


def check_pose_shape(name, value, drawn_by):
  """Raises unless `value` broadcasts to a position (3,) or quaternion (4,).

  Args:
    name: 'position' or 'quaternion'.
    value: a fixed value (at construction; variations and callables are left
      to the draw) or a drawn one (while the reset is traced).
    drawn_by: the variation that drew `value`, or None for a fixed value.
  """
  if drawn_by is None and (
      callable(value) or variation_base.contains_variation(value)
  ):
    return
  size = _POSE_SIZES[name]
  shape = np.shape(value)
  try:
    ok = np.broadcast_shapes(shape, (size,)) == (size,)
  except ValueError:
    ok = False
  if ok:
    return
  if drawn_by is None:
    got = f'{value!r}, of shape {shape}'
  else:
    got = f'{drawn_by!r}, which drew a value of shape {shape}'
  example = '(0, 0, 0.1)' if size == 3 else '(1, 0, 0, 0)'
  raise ValueError(
      f'PropPlacer: `{name}` must be {size} numbers (or a variation drawing '
      f'{size}), got {got}. Pass {size} numbers, e.g. {name}={example}, or a '
      f'variation of {size}.'
  )
