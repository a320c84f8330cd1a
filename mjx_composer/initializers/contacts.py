"""Batched contact queries for initializers: "does this pose collide?".

composer's initializers call `mj_forward` and scan `physics.data.contact` in
Python. Here the question is answered inside jit with MJX's own collision
code, restricted to the geom pairs that matter:

* `pair_groups` picks, from MJX's static pair list (`mjx.collision`'s, so
  contype/conaffinity, exclusions, `<pair>`s and parent filtering are
  MuJoCo's), the pairs that involve some geoms and none of an excluded set,
  grouped by MJX's narrow-phase function.
* `min_distance` runs just those functions and returns the smallest signed
  distance. MuJoCo reports a contact when that distance is below the pair's
  margin; composer counts the ones with `dist <= 0` as collisions.
* `rigid_geom_poses` gives the world poses of geoms that move rigidly with a
  body whose pose is known, so a candidate pose can be checked without a
  kinematics pass over the whole tree.

These build on MJX's private collision tables (the pair table and the
function table of `mjx.collision`, through `platform.internals`), pinned
with mujoco 3.17.

A pose is judged by MJX's narrow phase, the one the batched simulation runs.
Where MJX and MuJoCo's own collision code disagree, placement follows MJX:
e.g. MJX's capsule-box test misses some deep contacts of a capsule beside a
box that MuJoCo reports (prefer box or sphere stand-ins for such obstacles).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np

from mjx_composer.model import element_index
from mjx_composer.model import pymjcf
from mjx_composer.platform import backend
from mjx_composer.platform import internals


def entity_geoms(index, entity) -> np.ndarray:
  """Compiled ids of the geoms in `entity`'s subtree (an `ElementIndex`)."""
  kind = element_index.KINDS_BY_NAME["geom"]
  return np.asarray(
      [
          index.element_id(kind, geom)
          for e in entity.iter_entities()
          for geom in pymjcf.elements(e.mjcf_model, "geoms")
      ],
      np.int32,
  )


def pair_groups(model: mujoco.MjModel, geoms, excluded=()):
  """MJX's collision pairs that involve `geoms` and none of `excluded`.

  Args:
    model: the compiled host model.
    geoms: geom ids; a pair qualifies if either of its geoms is one of them.
    excluded: geom ids; a pair with either geom among them is left out.

  Returns:
    `((function key, (n, 2) int32 geom ids), ...)` in MJX's grouping, each
    group for the narrow-phase function `mjx.collision` would run on it.
    Empty when the model disables contacts.
  """
  if model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT:
    return ()  # MuJoCo reports no contacts at all: nothing can collide.
  geoms = np.asarray(geoms, np.int32)
  excluded = np.asarray(excluded, np.int32)
  groups = []
  all_groups = internals.collision_pair_groups(model)
  for key, pairs in all_groups.items():
    pairs = np.asarray(pairs, np.int32)[:, :2]
    involved = np.isin(pairs, geoms).any(axis=1)
    clean = ~np.isin(pairs, excluded).any(axis=1)
    selected = pairs[involved & clean]
    if selected.size:
      groups.append((key, selected))
  return tuple(groups)


def group_distances(model: mjx.Model, data: mjx.Data, key, pairs):
  """Signed distances `(n, ncon)` of the `(n, 2)` geom pairs of one group.

  Functions that return several contact points per pair pad the unused
  ones with positive distances.
  """
  fn = internals.collision_function(key)
  dist, _, _ = fn(model, data, key, jnp.asarray(pairs))
  return jnp.reshape(dist, (pairs.shape[0], -1))


def min_distance(
    model: mjx.Model, data: mjx.Data, groups, valid=None, mj_model=None
):
  """Smallest signed distance over the pairs of `groups` (+inf if none).

  Args:
    model: the (possibly per-world) `mjx.Model`.
    data: `mjx.Data` whose `geom_xpos`/`geom_xmat` hold the poses to test.
    groups: as returned by `pair_groups` (pairs may be traced arrays).
    valid: optional per-group `(n,)` bool masks; masked pairs do not count.
    mj_model: the compiled host model; needed for a 'warp' model, whose
      distances come from MJX's JAX colliders on its JAX twin
      (`Backend.jax_view`).

  Returns:
    A scalar: `<= 0` exactly when one of the pairs touches or penetrates.
  """
  # On 'warp': MJX's JAX colliders, on the JAX twin.
  model, data = backend.of(model).jax_view(model, data, mj_model)
  distances = []
  for i, (key, pairs) in enumerate(groups):
    dist = group_distances(model, data, key, pairs)
    if valid is not None:
      dist = jnp.where(valid[i][:, None], dist, jnp.inf)
    distances.append(jnp.ravel(dist))
  if not distances:
    return jnp.asarray(jnp.inf, data.qpos.dtype)
  return jnp.min(jnp.concatenate(distances))


def welded_chains(model: mujoco.MjModel, frame_body: int, geom_ids):
  """Bodies between a frame body and each geom's body, or None if jointed.

  Args:
    model: the compiled host model.
    frame_body: the body whose pose moves the geoms.
    geom_ids: geoms in `frame_body`'s subtree.

  Returns:
    A list with, per geom, the body ids from just below `frame_body` down to
    the geom's body (empty when the geom is in `frame_body` itself); None if
    a body on the way has a joint (the geom does not move rigidly).
  """
  chains = []
  for geom in geom_ids:
    chain = []
    body = int(model.geom_bodyid[geom])
    while body != frame_body:
      if body == 0:
        raise ValueError(f"Geom {geom} is not below body {frame_body}.")
      if model.body_jntnum[body]:
        return None
      chain.append(body)
      body = int(model.body_parentid[body])
    chains.append(chain[::-1])
  return chains


def rigid_geom_poses(model: mjx.Model, position, quaternion, geom_ids, chains):
  """World poses of geoms that move rigidly with a body at a given pose.

  Composes the body's pose with the model's `body_pos`/`body_quat` down each
  chain and the geoms' `geom_pos`/`geom_quat`, as `mjx.kinematics` would.

  Args:
    model: the (possibly per-world) `mjx.Model`.
    position: (3,) world position of the frame body.
    quaternion: (4,) its orientation (normalised here, like a freejoint's).
    geom_ids: (G,) int geom ids; out-of-range ids are padding.
    chains: (G, D) int body ids from `welded_chains`, padded with -1.

  Returns:
    `(geom_xpos (G, 3), geom_xmat (G, 3, 3))`.
  """
  quaternion = internals.quat_normalize(quaternion)

  def one_geom(geom, chain):
    pos, quat = position, quaternion
    for body in chain:  # D is static and small
      valid = body >= 0
      body = jnp.maximum(body, 0)
      child_pos = pos + internals.quat_rotate(model.body_pos[body], quat)
      child_quat = internals.quat_mul(quat, model.body_quat[body])
      pos = jnp.where(valid, child_pos, pos)
      quat = jnp.where(valid, child_quat, quat)
    geom = jnp.minimum(geom, model.ngeom - 1)
    xpos = pos + internals.quat_rotate(model.geom_pos[geom], quat)
    xmat = internals.quat_to_mat(
        internals.quat_mul(quat, model.geom_quat[geom])
    )
    return xpos, xmat

  geom_ids = jnp.asarray(geom_ids)
  chains = jnp.asarray(chains).reshape(geom_ids.shape[0], -1)
  return jax.vmap(lambda g, c: one_geom(g, [c[d] for d in range(c.shape[0])]))(
      geom_ids, chains
  )
