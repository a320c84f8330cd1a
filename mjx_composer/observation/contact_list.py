"""One world's contact list: MJX's contacts and their constraint forces.

MJX keeps a fixed-size list of candidate contacts (`data._impl.contact`,
through `platform.internals`): every contact that each colliding geom pair
can produce has a slot, and a slot is in use when its distance is below its
pair's `margin - gap`, the contacts MuJoCo's solver uses (`efc_address >= 0`
in `mjData.contact`). `contact_list` returns that list with each contact's
force decoded from the constraint forces of the last forward pass, as
`mj_contactForce` decodes them (pyramidal or elliptic cones), in the world
frame. `contacts` answers questions about sets of geoms from it.

MJX's 'jax' implementation only: MuJoCo Warp keeps the batch's contacts in
one buffer shared by every world, which a single world's hook cannot select
from; `contact_list` refuses 'warp' data at trace time.
"""

from __future__ import annotations

from flax import struct
import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjx_composer.platform import backend
from mjx_composer.platform import internals


@struct.dataclass
class ContactList:
  """One world's candidate contacts, one row per slot of MJX's contact list.

  Attributes:
    geom: `(n, 2)` int32 geom ids (MuJoCo's `geom1`, `geom2`).
    active: `(n,)` bool: the contact is in the constraint solver.
    dist: `(n,)` signed distance (negative: penetration).
    pos: `(n, 3)` contact position, world frame.
    normal: `(n, 3)` unit normal, pointing from `geom1` to `geom2`.
    force: `(n, 3)` the force `geom1` exerts on `geom2`, world frame
      (`mj_contactForce`'s normal and tangential parts, rotated out of the
      contact frame); zero for inactive contacts.
    normal_force: `(n,)` its normal component (non-negative).
  """

  geom: jax.Array
  active: jax.Array
  dist: jax.Array
  pos: jax.Array
  normal: jax.Array
  force: jax.Array
  normal_force: jax.Array


def contact_list(physics) -> ContactList:
  """The `ContactList` of one world's last forward pass.

  Raises:
    ValueError: at trace time, for data of MJX's 'warp' implementation
      (module docstring).
  """
  data = physics.data
  if not backend.of(data).jax_data_fields:
    raise ValueError(
        "Contact queries read MJX's per-world contact list, which the "
        "'warp' implementation does not keep (its contacts live in one "
        "buffer shared by the batch). Build the environment with "
        "options=ExecutionOptions(impl='jax'), or declare MuJoCo contact "
        "sensors (mjSENS_CONTACT, geom matching) and read their sensordata."
    )
  impl = internals.data_impl(data)
  contact = impl.contact
  dim = np.asarray(contact.dim, np.int64)
  adr = np.asarray(contact.efc_address, np.int64)
  n = dim.size
  dtype = data.qpos.dtype
  if n == 0:
    zeros = lambda *shape: jnp.zeros(shape, dtype)
    return ContactList(
        geom=jnp.zeros((0, 2), jnp.int32),
        active=jnp.zeros((0,), bool),
        dist=zeros(0),
        pos=zeros(0, 3),
        normal=zeros(0, 3),
        force=zeros(0, 3),
        normal_force=zeros(0),
    )
  frame = jnp.reshape(contact.frame, (n, 3, 3))
  local = _local_forces(physics.mj_model, dim, adr, impl.efc_force, contact)
  included = jnp.asarray(adr >= 0)
  active = jnp.logical_and(included, contact.dist < contact.includemargin)
  local = local * active[:, None]
  # Rows of `frame` are the contact axes: normal, then two tangents.
  force = jnp.einsum("ni,nij->nj", local, frame)
  return ContactList(
      geom=jnp.asarray(contact.geom, jnp.int32).reshape(n, 2),
      active=active,
      dist=contact.dist,
      pos=contact.pos,
      normal=frame[:, 0],
      force=force,
      normal_force=local[:, 0],
  )


def _local_forces(mj_model, dim, adr, efc_force, contact):
  """`(n, 3)` normal and tangential forces in each contact's frame.

  MuJoCo's decoding of the constraint forces (`mj_contactForce`): an
  elliptic cone's rows are the force's components; a pyramidal cone's
  2 (dim - 1) edge forces sum to the normal force, and each pair's
  difference times the friction coefficient is a tangential component.
  """
  n = dim.size
  start = np.maximum(adr, 0)
  friction = contact.friction
  if mj_model.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC:
    normal = efc_force[start]
    has_tangents = dim >= 3
    t1 = efc_force[np.where(has_tangents, start + 1, start)]
    t2 = efc_force[np.where(has_tangents, start + 2, start)]
    mask = jnp.asarray(has_tangents, efc_force.dtype)
    return jnp.stack([normal, t1 * mask, t2 * mask], axis=-1)
  edges = np.where(dim == 1, 1, 2 * (dim - 1))
  width = int(edges.max())
  rows = start[:, None] + np.arange(width)[None]
  in_contact = np.arange(width)[None] < edges[:, None]
  rows = np.where(in_contact, rows, start[:, None])
  pyramid = efc_force[rows] * jnp.asarray(in_contact, efc_force.dtype)
  normal = jnp.sum(pyramid, axis=-1)
  if width < 4:  # Only frictionless contacts: no tangential force.
    zeros = jnp.zeros((n,), efc_force.dtype)
    return jnp.stack([normal, zeros, zeros], axis=-1)
  has_tangents = jnp.asarray(dim >= 3, efc_force.dtype)
  t1 = (pyramid[:, 0] - pyramid[:, 1]) * friction[:, 0] * has_tangents
  t2 = (pyramid[:, 2] - pyramid[:, 3]) * friction[:, 1] * has_tangents
  return jnp.stack([normal, t1, t2], axis=-1)
