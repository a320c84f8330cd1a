"""The JAX twin of a MuJoCo Warp model: what only MJX's JAX code computes.

Some of what the package computes on the device has no MuJoCo Warp kernel:
the derived quantities of a randomized model (`compiler.set_const`: mass
matrix at `qpos0`, `invweight0`, `actuator_acc0`, through `mjx.crb`,
`mjx.full_m`, `mjx.transmission`) and `PropPlacer`'s collision tests (MJX's
JAX narrow phase, `initializers.contacts`). On a 'warp' model they run on
its JAX twin: the host model put on the device with `impl='jax'`
(`jax_base`), with the world's public field values (`jax_twin`,
`jax_view`). Their results are public model or data fields, which MuJoCo
Warp reads. `backend.WarpBackend` calls these; on 'jax' there is no twin.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx

# {id(host model): (host model, its 'jax' model, its 'jax' data)}
_JAX_BASES = {}


def jax_base(mj_model: mujoco.MjModel):
  """`mj_model` put with `impl='jax'`, and its data (cached per model).

  On this process's first device. The host model is kept alive with them,
  so that its id is not reused.
  """
  entry = _JAX_BASES.get(id(mj_model))
  if entry is None or entry[0] is not mj_model:
    device = jax.local_devices()[0]
    model = mjx.put_model(mj_model, device=device, impl='jax')
    entry = (mj_model, model, mjx.make_data(model, device=device, impl='jax'))
    _JAX_BASES[id(mj_model)] = entry
  return entry[1], entry[2]


def jax_twin(model: mjx.Model, base: mjx.Model) -> mjx.Model:
  """The 'jax' implementation's model with `model`'s values.

  For computing, on a 'warp' model, what only MJX's JAX implementation
  provides (`mjx.crb`, `mjx.full_m`, `mjx.transmission`, and `make_data` of
  a device model): `base`, the host model put with `impl='jax'`
  (`jax_base`), with every public field whose value the JAX
  implementation holds on the device replaced by `model`'s (the per-world
  ones among them). Fields the JAX implementation holds as host constants
  (structure: ids, types, addresses) cannot differ between worlds and are
  kept.
  """
  twin = base
  updates = {}
  for f in dataclasses.fields(mjx.Model):
    name = f.name
    if name in ('_impl', 'opt', 'stat'):
      continue
    mine, theirs = getattr(twin, name), getattr(model, name)
    if not isinstance(mine, jax.Array) and not isinstance(
        theirs, jax.core.Tracer
    ):
      continue  # host structure, the same in every world
    if name == 'geom_aabb':
      theirs = jnp.reshape(theirs, jnp.shape(mine))
    updates[name] = theirs
  opt = {
      f.name: getattr(model.opt, f.name)
      for f in dataclasses.fields(type(model.opt))
      if f.name != '_impl' and isinstance(getattr(twin.opt, f.name), jax.Array)
  }
  return twin.replace(opt=twin.opt.replace(**opt), stat=model.stat, **updates)


def jax_view(model: mjx.Model, data: mjx.Data, mj_model: mujoco.MjModel):
  """`(model, data)` of MuJoCo Warp on MJX's JAX implementation.

  For MJX functions that only the JAX implementation has, e.g. its
  narrow-phase colliders (`initializers.contacts`): the JAX twin of
  `model` (`jax_twin`), and the host model's 'jax' data with `data`'s
  public fields.
  """
  base_model, base_data = jax_base(mj_model)
  public = {}
  for f in dataclasses.fields(mjx.Data):
    if f.name == '_impl':
      continue
    value, like = getattr(data, f.name), getattr(base_data, f.name)
    if jnp.shape(value) == jnp.shape(like):
      public[f.name] = value
  return jax_twin(model, base_model), base_data.replace(**public)
