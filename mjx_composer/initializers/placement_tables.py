"""The static tables `PropPlacer` resolves once against a compiled model.

A placement runs prop by prop: a prop with joints of its own, or a fixed
prop, on its own (`Single`); consecutive free rigid props together, in one
`lax.scan` over tables stacked along the props (`RigidRun`). Building them
is host work, done once per compiled model.
"""

from typing import Any, NamedTuple

import numpy as np

from mjx_composer.model import element_index
from mjx_composer.model import pymjcf


class Single(NamedTuple):
  """A prop placed on its own, through `set_pose` and a kinematics pass.

  Used for fixed props (their pose is a model field) and for props with
  joints of their own, whose geoms do not move rigidly with the frame.
  """

  prop_index: int
  pair_groups: tuple  # ((FunctionKey, (n, 2) geom ids), ...)


class RigidRun(NamedTuple):
  """Consecutive free, rigid props placed by one `lax.scan`.

  Tables are stacked along the props and padded where sizes differ.
  """

  prop_indices: np.ndarray  # (n,) indices into `PropPlacer.props`
  qpos_adr: np.ndarray  # (n,) the freejoints' qpos addresses
  geom_ids: np.ndarray  # (n, G) geom ids; `ngeom` pads (dropped)
  chains: np.ndarray  # (n, G, D) welded bodies below the frame
  # down to each geom's body; -1 pads
  keys: tuple  # MJX function keys of the pair tables
  pairs: tuple  # per key: (n, P, 2) geom pairs
  valid: tuple  # per key: (n, P) which pairs are real


class Tables(NamedTuple):
  """Static facts resolved once against a compiled model."""

  index: Any  # the ElementIndex these were resolved with
  steps: tuple  # `Single`s and `RigidRun`s, in prop order
  held_qpos: np.ndarray  # qpos addresses of every non-prop joint
  held_dofs: np.ndarray  # dof addresses of every non-prop joint
  prop_dofs: np.ndarray  # dof addresses of every prop joint
  fixed_fields: tuple  # model fields placement writes


def entity_elements(entity, attr):
  """Element handles of `attr` ('geoms', 'joints') in an entity's subtree."""
  return [
      el
      for e in entity.iter_entities()
      for el in pymjcf.elements(e.mjcf_model, attr)
  ]


def joint_addresses(model, joint_ids):
  """(qpos addresses, dof addresses) of compiled joints, as int arrays."""
  qpos, dofs = [], []
  for j in joint_ids:
    kind = int(model.jnt_type[j])
    start = int(model.jnt_qposadr[j])
    qpos.extend(range(start, start + element_index.QPOS_WIDTH[kind]))
    start = int(model.jnt_dofadr[j])
    dofs.extend(range(start, start + element_index.DOF_WIDTH[kind]))
  return np.asarray(qpos, np.int32), np.asarray(dofs, np.int32)


def rigid_run(model, members):
  """Stacks the tables of consecutive rigid props into one `RigidRun`.

  Args:
    model: the compiled host model.
    members: `(prop index, qpos address, geom ids, chains, pair groups)`.
  """
  n = len(members)
  max_geoms = max(len(m[2]) for m in members)
  depth = max([len(c) for m in members for c in m[3]] + [0])
  geom_ids = np.full((n, max_geoms), model.ngeom, np.int32)
  chains = np.full((n, max_geoms, max(depth, 1)), -1, np.int32)
  for i, (_, _, geoms, prop_chains, _) in enumerate(members):
    geom_ids[i, : len(geoms)] = geoms
    for j, chain in enumerate(prop_chains):
      chains[i, j, : len(chain)] = chain
  # One table per narrow-phase function, padded with a real pair of that
  # function (masked out) so every prop runs the same code.
  keys, pairs, valid = [], [], []
  for _, _, _, _, groups in members:
    for key, _ in groups:
      if key not in keys:
        keys.append(key)
  for key in keys:
    per_prop = [
        dict(groups).get(key, np.zeros((0, 2), np.int32))
        for *_, groups in members
    ]
    width = max(len(p) for p in per_prop)
    filler = next(p[0] for p in per_prop if len(p))
    table = np.tile(filler, (n, width, 1)).astype(np.int32)
    mask = np.zeros((n, width), bool)
    for i, p in enumerate(per_prop):
      table[i, : len(p)] = p
      mask[i, : len(p)] = True
    pairs.append(table)
    valid.append(mask)
  return RigidRun(
      np.asarray([m[0] for m in members], np.int32),
      np.asarray([m[1] for m in members], np.int32),
      geom_ids,
      chains,
      tuple(keys),
      tuple(pairs),
      tuple(valid),
  )
