"""Contacts between two sets of geoms, per world and inside jit.

composer code reads contacts in Python: it loops over `physics.data.contact`
and compares `contact.geom1`/`contact.geom2` with the ids of some geoms, or
collects the touching geom pairs. Here the same questions are answered by a
pure function of one world's `Physics`, usable in hooks, rewards and
observables:

    touch = contacts.between(physics, hand, prop)   # a `Contacts`
    touch.touching, touch.count, touch.normal_force, touch.force

A set of geoms is given as an entity (every geom of it and of the entities
attached below it), a body (its own geoms), a geom, their MjSpec handles, a
fully qualified name (a geom's, else a body's), or a list of these. Sets
are resolved to static geom ids while tracing (through `physics.index`, as
`physics.bind` resolves elements); nothing on the device looks a name up.
`None` as the second set means every geom outside the first.

What counts as a contact is what MuJoCo's constraint solver uses: a contact
whose distance is below its pair's `margin - gap` (MuJoCo's contacts with
`efc_address >= 0`; in `mjData.contact` those with `exclude == 0`).
Forces are the constraint forces of the last forward pass (`mj_contactForce`
for each contact, pyramidal or elliptic cones), so after a step they are the
forces of that step's last sub-step, as `physics.data.contact` after
`mj_step` in composer.

The contacts come from MJX's fixed-size contact list (`contact_list`):
every candidate contact of every colliding geom pair has a slot, and the
matching slots are selected by mask, so the
cost is one pass over the list whatever the sets. The contact positions come
padded to a static size (`max_contacts`, by default every slot the two sets
can fill) with a `valid` mask.

MJX's 'jax' implementation only: MuJoCo Warp keeps the batch's contacts in
one shared buffer, which a single world's hook cannot select from. A query
on a 'warp' environment is a trace-time error; there MuJoCo's contact
sensors (`mjSENS_CONTACT` with geom matching, declared in the entity's spec
and read from `sensordata`) are the way.
"""

from __future__ import annotations

from typing import Any

from flax import struct
import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjx_composer.model import element_index
from mjx_composer.model import pymjcf
from mjx_composer.observation import contact_list as contact_list_lib
from mjx_composer.platform import internals

# One world's candidate contacts and their forces (`contact_list` module).
ContactList = contact_list_lib.ContactList
contact_list = contact_list_lib.contact_list

_GEOM = element_index.KINDS_BY_NAME['geom']
_BODY = element_index.KINDS_BY_NAME['body']


# -- geom sets -------------------------------------------------------------------


def geom_ids(index: element_index.ElementIndex, elements) -> np.ndarray:
  """The sorted compiled ids of the geoms that `elements` stand for.

  Args:
    index: the environment's `ElementIndex` (`physics.index`).
    elements: an entity (its geoms and those of the entities attached below
      it), a body (its own geoms) or a geom, as an MjSpec handle, a PyMJCF
      element or a fully qualified name (a geom's, else a body's), or a
      list, tuple or set of these.

  Returns:
    An int32 array of unique geom ids (possibly empty: a body without geoms).

  Raises:
    TypeError: for anything else, naming the value.
    KeyError: for a name that is neither a geom's nor a body's.
  """
  ids: list[int] = []
  _collect(index, elements, ids)
  return np.unique(np.asarray(ids, np.int32))


def _collect(index, elements, ids):
  model = index.mj_model
  if isinstance(elements, (list, tuple, set, frozenset)):
    for element in elements:
      _collect(index, element, ids)
  elif hasattr(elements, 'iter_entities') and hasattr(elements, 'mjcf_model'):
    for entity in elements.iter_entities():
      spec = entity.mjcf_model
      geoms = spec.find_all('geom') if pymjcf.is_root(spec) else spec.geoms
      ids.extend(index.element_id(_GEOM, geom) for geom in geoms)
  elif isinstance(elements, str):
    geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, elements)
    if geom >= 0:
      ids.append(geom)
      return
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, elements)
    if body < 0:
      raise KeyError(
          f'No geom or body named {elements!r} in the compiled model: pass a '
          "fully qualified name ('<entity>/<element>'), an element handle or "
          'an entity.'
      )
    ids.extend(np.flatnonzero(model.geom_bodyid == body).tolist())
  else:
    try:
      kind = element_index.element_kind(elements)  # MjSpec or PyMJCF.
    except TypeError:
      kind = None
    if kind is _GEOM:
      ids.append(index.element_id(_GEOM, elements))
    elif kind is _BODY:
      body = index.element_id(_BODY, elements)
      ids.extend(np.flatnonzero(model.geom_bodyid == body).tolist())
    else:
      raise TypeError(
          'A set of geoms is an entity, a body, a geom (MjSpec handles or '
          'PyMJCF elements), a geom or body name, or a list of these: got '
          f'{type(elements).__name__} {elements!r}.'
      )


def membership(index, sets, other=None) -> tuple[np.ndarray, np.ndarray]:
  """Static `(rows, ngeom)` tables: which geoms are in each row's two sets.

  Args:
    index: the environment's `ElementIndex`.
    sets: one geom set per row (`geom_ids`' `elements`).
    other: the geom set every row is matched against; None: every geom
      outside the row's own set.

  Returns:
    `(first, second)`, bool arrays of shape `(len(sets), ngeom)`.

  Raises:
    ValueError: where a row's set is empty or its two sets share a geom
      (a contact between them would count once for each side).
  """
  ngeom = index.mj_model.ngeom
  first = np.zeros((len(sets), ngeom), bool)
  second = np.zeros((len(sets), ngeom), bool)
  other_ids = None if other is None else geom_ids(index, other)
  if other_ids is not None and not other_ids.size:
    raise ValueError(f'The second set of geoms {other!r} has no geoms.')
  for row, elements in enumerate(sets):
    ids = geom_ids(index, elements)
    if not ids.size:
      raise ValueError(
          f'The set of geoms {elements!r} has no geoms: give an entity, a '
          'body with geoms, or geoms.'
      )
    first[row, ids] = True
    if other_ids is None:
      second[row] = ~first[row]
    else:
      second[row, other_ids] = True
      shared = np.flatnonzero(first[row] & second[row])
      if shared.size:
        names = [
            mujoco.mj_id2name(index.mj_model, mujoco.mjtObj.mjOBJ_GEOM, g)
            for g in shared
        ]
        raise ValueError(
            f'The two sets of geoms share geoms {names}: a contact between '
            'them would belong to both sides. Give disjoint sets.'
        )
  return first, second


def contact_slots(mj_model, first: np.ndarray, second: np.ndarray) -> int:
  """How many slots of MJX's contact list pairs of the two sets can fill.

  From MJX's static collision pairs (`platform.internals`), each counted
  with the number of contacts its narrow-phase function returns. An upper
  bound: MJX's `max_geom_pairs` and `max_contact_points` only lower it.

  Args:
    mj_model: the compiled host model.
    first, second: bool arrays of shape `(ngeom,)`: the two sets.
  """
  if mj_model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT:
    return 0
  total = 0
  for key, pairs in internals.collision_pair_groups(mj_model).items():
    pairs = np.asarray(pairs, np.int64)[:, :2]
    if not pairs.size:
      continue
    matched = (first[pairs[:, 0]] & second[pairs[:, 1]]) | (
        first[pairs[:, 1]] & second[pairs[:, 0]]
    )
    if not matched.any():
      continue
    if key.types[1] == mujoco.mjtGeom.mjGEOM_SDF:
      per_pair = int(mj_model.opt.sdf_initpoints)
    else:
      per_pair = int(internals.collision_function(key).ncon)
    total += per_pair * int(matched.sum())
  return total


# -- queries ---------------------------------------------------------------------


@struct.dataclass
class Contacts:
  """The contacts between two sets of geoms in one world (`between`).

  Attributes:
    touching: bool scalar: at least one contact.
    count: int32 scalar: how many contacts.
    normal_force: the sum of the contacts' normal forces (>= 0).
    force: `(3,)` the net contact force the second set exerts on the first,
      world frame (normal and friction parts): e.g. `+m g` up for a body
      resting on the floor, queried as `between(physics, body, floor)`.
    penetration: the deepest penetration, `max(-dist, 0)` (0 if none).
    position: `(max_contacts, 3)` the contacts' positions, world frame,
      zero where not `valid`.
    distance: `(max_contacts,)` their signed distances (negative:
      penetration), zero where not `valid`.
    normal: `(max_contacts, 3)` unit normals pointing from the first set to
      the second, zero where not `valid`.
    geoms: `(max_contacts, 2)` int32 geom ids, the first set's first;
      -1 where not `valid`.
    valid: `(max_contacts,)` bool: which rows hold a contact. Contacts
      beyond `max_contacts` are counted and summed but not listed.
  """

  touching: jax.Array
  count: jax.Array
  normal_force: jax.Array
  force: jax.Array
  penetration: jax.Array
  position: jax.Array
  distance: jax.Array
  normal: jax.Array
  geoms: jax.Array
  valid: jax.Array


def _oriented(contacts: ContactList, first, second):
  """Masks `(rows, n)` of the matching contacts and the side of geom1.

  `flip` is true where `geom1` belongs to the row's first set: there the
  contact's force acts on the second set, and the first set feels minus it.
  """
  first = jnp.asarray(first)
  second = jnp.asarray(second)
  g1, g2 = contacts.geom[:, 0], contacts.geom[:, 1]
  flip = first[:, g1] & second[:, g2]
  straight = first[:, g2] & second[:, g1]
  matched = (flip | straight) & contacts.active[None]
  return matched, flip


def between(physics, first, second=None, max_contacts=None) -> Contacts:
  """The contacts between two sets of geoms in one world (module docstring).

  Args:
    physics: one world's `Physics`, after a forward pass or a step (in a
      hook, a reward, an observable).
    first: a set of geoms (`geom_ids`' `elements`).
    second: another set, disjoint from `first`; None: any geom outside
      `first`.
    max_contacts: how many contacts `Contacts.position` and friends list
      (static); None: every slot the two sets can fill
      (`contact_slots`).

  Returns:
    A `Contacts`.
  """
  index = physics.index
  table1, table2 = membership(index, [first], second)
  if max_contacts is None:
    max_contacts = contact_slots(index.mj_model, table1[0], table2[0])
  max_contacts = _check_max_contacts(max_contacts)
  contacts = contact_list(physics)
  matched, flip = _oriented(contacts, table1, table2)
  matched, flip = matched[0], flip[0]
  sign = jnp.where(flip, -1.0, 1.0).astype(contacts.force.dtype)
  weights = matched.astype(contacts.force.dtype)
  count = jnp.sum(matched, dtype=jnp.int32)
  depth = jnp.where(matched, -contacts.dist, 0.0)
  n = matched.shape[0]
  if n:
    (rows,) = jnp.nonzero(matched, size=max_contacts, fill_value=0)
  else:
    rows = jnp.zeros((max_contacts,), jnp.int32)
  valid = jnp.arange(max_contacts) < count
  listed = lambda x: (
      jnp.where(_expand(valid, x), x[rows], 0)
      if n
      else jnp.zeros((max_contacts,) + x.shape[1:], x.dtype)
  )
  pair = jnp.where(flip[:, None], contacts.geom, contacts.geom[:, ::-1])
  geoms = jnp.where(valid[:, None], pair[rows], -1) if n else None
  if geoms is None:
    geoms = -jnp.ones((max_contacts, 2), jnp.int32)
  return Contacts(
      touching=count > 0,
      count=count,
      normal_force=jnp.sum(contacts.normal_force * weights),
      force=jnp.sum(contacts.force * (weights * sign)[:, None], axis=0),
      penetration=jnp.maximum(jnp.max(depth, initial=0.0), 0.0),
      position=listed(contacts.pos),
      distance=listed(contacts.dist),
      normal=listed(contacts.normal * -sign[:, None]),
      geoms=geoms,
      valid=valid,
  )


def _expand(mask, x):
  return jnp.reshape(mask, mask.shape + (1,) * (x.ndim - 1))


def _check_max_contacts(max_contacts) -> int:
  if (
      isinstance(max_contacts, bool)
      or not isinstance(max_contacts, (int, np.integer))
      or max_contacts < 0
  ):
    raise ValueError(
        'max_contacts must be a non-negative int (how many contacts to '
        f'list), got {max_contacts!r}.'
    )
  return int(max_contacts)


@struct.dataclass
class ContactRows:
  """Per-row contact summaries (`summarize`): one row per geom set.

  Attributes:
    touching: `(rows,)` bool.
    count: `(rows,)` int32.
    normal_force: `(rows,)` summed normal force.
    force: `(rows, 3)` net force the other set exerts on the row's set,
      world frame.
  """

  touching: jax.Array
  count: jax.Array
  normal_force: jax.Array
  force: jax.Array


def summarize(physics, sets, other=None) -> ContactRows:
  """`between(physics, s, other)`'s summaries for each `s` in `sets` at once.

  One pass over the contact list for every row: what a foot-contact sensor
  needs (`sets` the feet, `other` the ground or None for anything).

  Args:
    physics: one world's `Physics`.
    sets: a list of geom sets, one per row.
    other: the set each row is matched against; None: anything outside the
      row's set.
  """
  first, second = membership(physics.index, list(sets), other)
  return summarize_tables(physics, first, second)


def summarize_tables(physics, first, second) -> ContactRows:
  """`summarize` with the sets already resolved (`membership`)."""
  contacts = contact_list(physics)
  matched, flip = _oriented(contacts, first, second)
  dtype = contacts.force.dtype
  weights = matched.astype(dtype)
  signed = weights * jnp.where(flip, -1.0, 1.0).astype(dtype)
  count = jnp.sum(matched, axis=-1, dtype=jnp.int32)
  return ContactRows(
      touching=count > 0,
      count=count,
      normal_force=weights @ contacts.normal_force,
      force=signed @ contacts.force,
  )


def touching_pairs(physics, first, second=None, max_pairs=None) -> Any:
  """The distinct touching geom pairs between two sets, padded.

  composer's "collect the touching geom pairs" (`{(c.geom1, c.geom2) for c
  in physics.data.contact}`), with the first set's geom first.

  Args:
    physics, first, second: as in `between`.
    max_pairs: how many pairs to list (static); None: every pair of MJX's
      collision pairs between the two sets.

  Returns:
    `(pairs, valid)`: `(max_pairs, 2)` int32 geom ids (-1 where not valid)
    and a `(max_pairs,)` bool mask; the touching pairs first, ordered by
    geom ids.
  """
  index = physics.index
  table1, table2 = membership(index, [first], second)
  candidates = _candidate_pairs(index.mj_model, table1[0], table2[0])
  if max_pairs is None:
    max_pairs = len(candidates)
  max_pairs = _check_max_contacts(max_pairs)
  contacts = contact_list(physics)
  matched, flip = _oriented(contacts, table1, table2)
  if not len(candidates) or not matched.shape[1]:
    return -jnp.ones((max_pairs, 2), jnp.int32), jnp.zeros(max_pairs, bool)
  pair = jnp.where(flip[0][:, None], contacts.geom, contacts.geom[:, ::-1])
  cand = jnp.asarray(candidates)
  # (pairs, slots): slot j is a contact of candidate pair i.
  hit = jnp.all(pair[None] == cand[:, None], axis=-1) & matched[0][None]
  touched = jnp.any(hit, axis=-1)
  (rows,) = jnp.nonzero(touched, size=max_pairs, fill_value=0)
  valid = jnp.arange(max_pairs) < jnp.sum(touched)
  return jnp.where(valid[:, None], cand[rows], -1), valid


def _candidate_pairs(mj_model, first, second) -> np.ndarray:
  """MJX's static collision pairs between the sets, the first set's first."""
  if mj_model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT:
    return np.zeros((0, 2), np.int32)
  out = []
  for pairs in internals.collision_pair_groups(mj_model).values():
    for g1, g2 in np.asarray(pairs, np.int64)[:, :2]:
      if first[g1] and second[g2]:
        out.append((g1, g2))
      elif first[g2] and second[g1]:
        out.append((g2, g1))
  return np.unique(np.asarray(out, np.int32).reshape(-1, 2), axis=0)
