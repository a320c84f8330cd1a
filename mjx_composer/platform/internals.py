"""Every use of MJX's and MuJoCo Warp's private internals.

The package needs a few things that MJX and MuJoCo Warp do not export:
MJX's implementation data (`mjx.Data._impl`, `mjx.Option._impl`), MJX's
collision tables, ray-geom table and quaternion math, the explanations of
dm_control idioms MuJoCo's bindings lack, and MuJoCo Warp's default
constraint rows and batch dimensions. This module, with `internals_jax`
(JAX) and `internals_numpy` (NumPy's random module), is the only one that
imports a private module (`mujoco.mjx._src`,
`mujoco.mjx.third_party.mujoco_warp._src`) or reads an `_impl` field; every
other module calls the names below. When MuJoCo or MuJoCo Warp is
upgraded, this file is the one to revisit (`tests/package/test_layers.py` keeps
private imports out of the rest of the package).

Each name says what private thing it wraps and why the package needs it.
Written against mujoco (MJX) 3.17.
"""

from __future__ import annotations


import jax.numpy as jnp
from mujoco import mjx

# pylint: disable=protected-access
from mujoco.mjx._src import collision_driver as _collision_driver
from mujoco.mjx._src import math as _mjx_math
from mujoco.mjx._src import ray as _mjx_ray
from mujoco.mjx.warp import types as _warp_types

# -- MJX ------------------------------------------------------------------------


def data_impl(data):
  """`data._impl`: the implementation data of an `mjx.Data`.

  A `DataJAX` ('jax') or `DataWarp` ('warp'). MJX 3.17 keeps some fields
  only there and has no public accessor for them: the tendon Jacobian
  (`ten_J`), the actuator moments (`actuator_moment`), the constraint
  Jacobian (`efc_J`); on 'warp', the buffer sizes and overflow flags
  (`naconmax`, `njmax`, `nacon`, `overflow`). MJX's deprecation message for
  `Data.<field>` points there.
  """
  return data._impl


def replace_data_impl(data, **fields):
  """`data` with `fields` of its implementation data (`data._impl`) replaced."""
  return data.replace(_impl=data._impl.replace(**fields))


def option_impl(option):
  """`option._impl`: the implementation options of an `mjx.Option`.

  On 'warp', MuJoCo Warp's options, among them `warn_overflow` (which
  overflows its kernels print a warning for); MJX has no public accessor.
  """
  return option._impl


def replace_option_impl(option, **fields):
  """`option` with `fields` of its implementation options replaced."""
  return option.replace(_impl=option._impl.replace(**fields))


def collision_pair_groups(mj_model) -> dict:
  """`mujoco.mjx._src.collision_driver._geom_groups(mj_model)`.

  MJX's static collision pairs grouped by narrow-phase function: the pairs
  `mjx.collision` tests (contype/conaffinity, exclusions, `<pair>`s and
  parent filtering as MuJoCo's), keyed by the function's key. The contact
  queries of `initializers.contacts` test a subset of them with MJX's own
  functions; MJX exports neither the table nor the functions.
  """
  return _collision_driver._geom_groups(mj_model)


def colliding_geom_pairs(mj_model) -> list[tuple[int, int]]:
  """`mujoco.mjx._src.collision_driver.geom_pairs(mj_model)`'s geom ids.

  Every pair of geoms MJX's JAX implementation tests for contact, after
  contype/conaffinity, exclusions and parent filtering, `<pair>`s included.
  """
  return [
      (int(g1), int(g2)) for g1, g2, _ in _collision_driver.geom_pairs(mj_model)
  ]


def has_collision_function(type1: int, type2: int) -> bool:
  """Whether MJX's JAX implementation collides geoms of these two types."""
  return bool(_collision_driver.has_collision_fn(type1, type2))


def contact_dims(mj_model):
  """`mujoco.mjx._src.collision_driver.make_condim(mj_model)`.

  The dimension of every contact MJX's JAX implementation allocates (one
  entry per potential contact, static): its solver's elliptic cone runs
  only where there is at least one and none has dimension 1, and MJX names
  neither case when it fails (`environment` chooses the cone from this).
  """
  return _collision_driver.make_condim(mj_model)


def collision_function(key):
  """`mujoco.mjx._src.collision_driver._COLLISION_FUNC[key.types]`.

  The narrow-phase function MJX runs on the pairs of `key`'s group
  (`collision_pair_groups`): `fn(model, data, key, pairs)` returns the
  signed distances, positions and frames of their contacts.
  """
  return _collision_driver._COLLISION_FUNC[key.types]


# `mujoco.mjx._src.math`: MJX's quaternion functions, so that poses composed
# outside `mjx.kinematics` (`initializers.contacts.rigid_geom_poses`) round
# as MJX's own kinematics do.
quat_normalize = _mjx_math.normalize
quat_rotate = _mjx_math.rotate
quat_mul = _mjx_math.quat_mul
quat_to_mat = _mjx_math.quat_to_mat


def _ray_cylinder(size, pnt, vec):
  """Distance along `vec` from `pnt` to a cylinder's surface (`inf`: none).

  The cylinder's frame: radius `size[0]`, half-height `size[1]` along z. As
  MuJoCo's `mju_rayGeom`: the nearest intersection at a distance >= 0 with
  the round side (between the flat sides) or a flat side (within the
  radius), so a ray from inside meets the surface on its way out.
  """
  radius, half_height = size[0], size[1]
  minval = _mjx_ray.mujoco.mjMINVAL
  # Round side: |pnt_xy + t vec_xy| = radius, i.e. a t^2 + 2 b t + c = 0.
  a = vec[0] * vec[0] + vec[1] * vec[1]
  b = vec[0] * pnt[0] + vec[1] * pnt[1]
  c = pnt[0] * pnt[0] + pnt[1] * pnt[1] - radius * radius
  det = b * b - a * c
  root = jnp.sqrt(jnp.maximum(det, 0.0))
  safe_a = jnp.where(a < minval, 1.0, a)
  side = jnp.stack([(-b - root) / safe_a, (-b + root) / safe_a])
  side_hit = (det >= minval) & (a >= minval) & (side >= 0)
  side_hit &= jnp.abs(pnt[2] + side * vec[2]) <= half_height
  # Flat sides: z = +-half_height, within the radius.
  safe_vz = jnp.where(jnp.abs(vec[2]) < minval, 1.0, vec[2])
  caps = (jnp.stack([half_height, -half_height]) - pnt[2]) / safe_vz
  xy = pnt[:2] + caps[:, None] * vec[:2]
  caps_hit = (jnp.abs(vec[2]) >= minval) & (caps >= 0)
  caps_hit &= jnp.sum(xy * xy, axis=-1) <= radius * radius
  return jnp.min(
      jnp.concatenate(
          [
              jnp.where(side_hit, side, jnp.inf),
              jnp.where(caps_hit, caps, jnp.inf),
          ]
      )
  )


def add_missing_ray_functions() -> None:
  """Fills `mujoco.mjx._src.ray._RAY_FUNC` where MJX lacks a geom type.

  MJX's table of ray-geom functions serves `mjx.ray` and the touch sensor,
  which counts the contacts whose force ray meets its site's volume. MJX
  3.17 has no cylinder entry, so a touch sensor on a cylinder site (as
  composer's tutorial builds its button) fails to trace with a `KeyError`;
  this adds `_ray_cylinder`, MuJoCo's semantics. An entry MJX has is never
  replaced.
  """
  _mjx_ray._RAY_FUNC.setdefault(_mjx_ray.GeomType.CYLINDER, _ray_cylinder)


# What a port of dm_control code meets on MJX's classes, and what to use.
CONTACT_INDEXING_MESSAGE = (
    "MJX's contact list (`physics.data.contact`) cannot be indexed or "
    "iterated as dm_control's `physics.data.contact[:physics.data.ncon]`: "
    'it holds a fixed number of candidate slots per world, most of them not '
    'touching, and a Python loop or `if` cannot branch on traced values. Ask '
    'the question as one function of the physics: '
    '`mjx_composer.observation.contacts.between(physics, geoms_a, geoms_b)` '
    '(`.touching`, `.count`, `.normal_force`, `.force`; `geoms_b=None`: '
    'anything else) or, per row of geoms, '
    '`mjx_composer.observation.contact_sensor`.'
)
MUJOCO_POINTER_MESSAGE = (
    "{kind} is MJX's `mjx.{kind}`, not dm_control's wrapper of MuJoCo's "
    "Mj{kind}: it has no `ptr`, and MuJoCo's C functions (`mujoco.mj_*`, "
    "dm_control's `mjlib`) cannot run on a traced world. Use MJX's function "
    '(`mujoco.mjx`), a binding (`physics.bind(...)`), or, for what the '
    'compiled model knows (names, ids, sizes, defaults), `physics.mj_model`: '
    'the host MjModel shared by every world, read while tracing.'
)


def explain_dm_control_idioms() -> None:
  """Clear errors for dm_control idioms on MJX's `Contact`, `Model` and
  `Data`, where Python's own errors say nothing of what to use.

  * `mjx.Contact` (`physics.data.contact`, through MJX's deprecated
    forwarding to `data._impl.contact`) gets a `__getitem__` that raises
    a `TypeError` (`CONTACT_INDEXING_MESSAGE`). Python's iteration falls
    back to it, so `for c in physics.data.contact` and `contact[:ncon]`
    raise it too; MJX defines neither, and `Contact` stays a plain pytree
    (not an `Iterable` to `isinstance`).
  * `mjx.Model.ptr` and `mjx.Data.ptr` (dm_control's way to hand MuJoCo's
    C functions the model and data) raise an `AttributeError` that says
    what to use (`MUJOCO_POINTER_MESSAGE`); `hasattr` stays False. MJX's
    own `__getattr__` answers every other missing name as before.

  A name MJX defines itself is never replaced; calling this again does
  nothing.
  """
  if '__getitem__' not in vars(mjx.Contact):

    def refuse_indexing(self, key):
      del self, key
      raise TypeError(CONTACT_INDEXING_MESSAGE)

    mjx.Contact.__getitem__ = refuse_indexing
  for cls in (mjx.Model, mjx.Data):
    original = vars(cls).get('__getattr__')
    if 'ptr' in vars(cls) or getattr(original, '_explains_ptr', False):
      continue
    cls.__getattr__ = _explaining_ptr(cls.__name__, original)


def _explaining_ptr(kind: str, original):
  """`original` (a class's `__getattr__`, or None), answering `ptr` with
  `MUJOCO_POINTER_MESSAGE`."""

  def __getattr__(self, name):  # pylint: disable=invalid-name
    if name == 'ptr':
      raise AttributeError(MUJOCO_POINTER_MESSAGE.format(kind=kind))
    if original is None:
      raise AttributeError(
          f"'{type(self).__name__}' object has no attribute '{name}'"
      )
    return original(self, name)

  __getattr__._explains_ptr = True  # pylint: disable=protected-access
  return __getattr__


# -- MuJoCo Warp ----------------------------------------------------------------


def warp_default_njmax(mj_model) -> int:
  """MuJoCo Warp's own estimate of the constraint rows per world.

  `mujoco.mjx.third_party.mujoco_warp._src.io._default_njmax(mj_model)`:
  what `make_data` allocates unless told; `backend.default_njmax` takes the
  larger of it and MJX's JAX count. Imported here, not at the top: MuJoCo
  Warp imports only where `warp-lang` is installed.
  """
  from mujoco.mjx.third_party.mujoco_warp._src import io as warp_io  # pylint: disable=g-import-not-at-top

  return int(warp_io._default_njmax(mj_model))


def warp_model_batch_dims() -> dict[str, bool]:
  """`mujoco.mjx.warp.types._BATCH_DIM['Model']`: which fields vary per world.

  `{model field: whether it has a batch dimension}` for the fields MuJoCo
  Warp reads: `backend.check_per_world_fields` refuses per-world values of
  the others. MJX keeps the table private.
  """
  return _warp_types._BATCH_DIM['Model']
