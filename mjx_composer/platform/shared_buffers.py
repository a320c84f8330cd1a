"""Tree operations that keep MuJoCo Warp's batch-shared `Data` buffers whole.

MuJoCo Warp keeps the contacts of all the worlds of a batch in one buffer
of `naconmax` contacts, with its counters: those `Data` fields are one
copy per batch, not per world (`shared_leaves`), and must stay so. MJX's
`Data.where` merges per world and keeps them (`select`, which `episode`
and `control_flow` use), but a `lax.cond` or `lax.while_loop` whose
condition differs between worlds batches all of its operands: with a
`Data` among them, it would copy the buffer once per world (and MuJoCo
Warp's next call refuses the result). The reset's retry loop
(`max_reset_attempts > 1`) therefore carries the data without them
(`drop_shared`, `restore_shared`); hooks with such loops over the whole
`Physics` should do the same, or keep the `Data` out.

These work on any pytree and on either implementation: a 'jax' `Data`,
and anything else, has no shared leaves, so they reduce to plain per-world
tree operations there.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from mujoco import mjx
from mujoco.mjx.warp import types as warp_types


def _shared_names() -> frozenset:
  return frozenset(warp_types.DATA_NON_VMAP)


def shared_leaves(tree):
  """A tree of bools like `tree`: True at Warp `Data` fields the batch shares.

  MuJoCo Warp's contact buffer (`naconmax` contacts for all the worlds of
  a batch) and its counters are one copy per batch, not per world: under
  `jax.vmap` they stay unbatched, and must never be broadcast to the
  batch or selected per world (`Data.where` keeps them). Every leaf of a
  'jax' `Data`, and of anything else, is per world (False).
  """
  names = _shared_names()

  def mark(node):
    if isinstance(node, warp_types.DataWarp):
      return jax.tree_util.tree_map_with_path(
          lambda path, _: path[0].name in names, node
      )
    return jax.tree.map(lambda _: False, node)

  return jax.tree.map(
      mark, tree, is_leaf=lambda x: isinstance(x, warp_types.DataWarp)
  )


def drop_shared(tree):
  """`tree` with Warp's batch-shared `Data` buffers emptied (zero rows).

  For loops whose carry holds a `Data` and whose condition differs between
  worlds: under `jax.vmap` such a loop batches its whole carry, and would
  copy the shared contact buffer once per world. Emptied, the buffers cost
  nothing; `restore_shared` puts them back before the next Warp call.
  """
  return jax.tree.map(
      lambda x, shared: jnp.zeros((0,) + jnp.shape(x)[1:], x.dtype)
      if shared
      else x,
      tree,
      shared_leaves(tree),
  )


def restore_shared(tree, source):
  """`tree` with Warp's batch-shared `Data` buffers taken from `source`."""
  return jax.tree.map(
      lambda x, y, shared: y if shared else x,
      tree,
      source,
      shared_leaves(tree),
  )


def select(pred, on_true, on_false):
  """`on_true` where `pred`, else `on_false`, for one world's pytrees.

  `mjx.Data` is merged by `Data.where` (on 'warp' the shared fields come
  from `on_false`, unselected); every other leaf by `jnp.where`.
  """

  def one(a, b):
    if isinstance(a, mjx.Data):
      return b.where(pred, a)
    return jnp.where(pred, a, b)

  return jax.tree.map(
      one, on_true, on_false, is_leaf=lambda x: isinstance(x, mjx.Data)
  )
