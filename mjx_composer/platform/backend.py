"""Which MJX implementation runs the physics: 'jax' or 'warp'.

MJX 3.17 runs the same `mjx.Model`/`mjx.Data` API on two implementations:
'jax' (XLA, every device) and 'warp' (MuJoCo Warp kernels called through
JAX's FFI, on a CUDA GPU or, compiled through LLVM, on the CPU). An
`ExecutionOptions(impl=...)` picks one when it is built (`resolve_impl`); this
module holds what differs between them and refuses, when the environment
is built, what MuJoCo Warp cannot run:

* the model itself: MuJoCo Warp's `put_model` refuses some geom, sensor and
  actuator types, plugins and options; `put` re-raises that with what to do.
* per-world model fields: MuJoCo Warp runs one kernel over every world of
  a batch, and only some model fields may differ between worlds (those
  with a batch dimension in `mujoco.mjx.warp.types._BATCH_DIM['Model']`:
  masses, inertias, frames, sizes, frictions, gains, option vectors, ...).
  A hook that writes any other field per world, e.g. a per-world height
  field profile (`hfield_data`), is refused (`check_per_world_fields`).
  Fields that MuJoCo Warp does not read at all (`dof_M0`, `stat`) may vary:
  they only matter to the 'jax' implementation.
* the fused same-step restart (`ExecutionOptions(share_reset_forward=True)`):
  it runs the integrator (`mjx.euler`, `mjx.implicit`) apart from
  `mjx.forward`, which MJX provides on 'jax' only; on 'warp' the sub-steps
  run `mjx.step` and the restart is separate.

What runs where on 'warp':

* `mjx.step`, `mjx.forward`, `mjx.kinematics`, `mjx.com_pos`,
  `mjx.tendon`: MuJoCo Warp, batched over the worlds of a `jax.vmap`.
* the derived quantities of a randomized model (`compiler.set_const`: mass
  matrix at `qpos0`, `invweight0`, `actuator_acc0`, ...): MJX's JAX
  implementation, on a JAX twin of the world's model (`jax_twin`): the
  world's public fields over the host model put on the device with
  `impl='jax'`. Their results are public model fields, which MuJoCo Warp
  reads.
* kinematics the host already knows (`kinematics.ReferenceKinematics`):
  public `Data` fields, the same on both.
* `PropPlacer`'s collision tests: MJX's JAX narrow phase on the JAX twin
  (`jax_view`). Its `settle_physics=True` is refused on 'warp' (below).

Contacts and constraints (`naconmax`, `njmax`): MuJoCo Warp keeps the
contacts of all the worlds of a batch in one buffer of `naconmax` contacts
(shared by the batch: those `Data` fields are not per world, see
`shared_leaves`), and `njmax` constraint rows per world (`default_njmax`).
Both are fixed when the environment is built. A world that needs more
loses contacts or constraints; MuJoCo Warp flags it in its per-world
overflow bitmask, which `overflow` reads and `metrics['overflow']`
reports: check it (the benchmarks and tests do) when choosing the sizes.

The shared buffers must stay one copy per batch. MJX's `Data.where`
merges per world and keeps them (`select`, which `episode` uses), but a
`lax.cond` or `lax.while_loop` whose condition differs between worlds
batches all of its operands: with a `Data` among them, it would copy the
buffer once per world (and MuJoCo Warp's next call refuses the result).
The reset's retry loop (`max_reset_attempts > 1`) therefore carries the
data without them (`drop_shared`, `restore_shared`); hooks with such loops
over the whole `Physics` should do the same, or keep the `Data` out.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import mujoco.mjx.warp as mjx_warp
from mujoco.mjx.warp import types as warp_types

from mjx_composer.platform import internals

IMPLS = ('jax', 'warp')
INSTALL_HINT = "pip install 'mjx-composer[warp]'"

# The contacts per world that the default contact buffer holds, and the
# worlds it holds them for: `naconmax` defaults to their product.
DEFAULT_CONTACTS_PER_WORLD = 64
DEFAULT_WORLDS = 8192


def warp_installed() -> bool:
  """Whether MJX can use MuJoCo Warp (`warp-lang` imports)."""
  return bool(mjx_warp.WARP_INSTALLED)


class WarpUnsupportedError(NotImplementedError):
  """MuJoCo Warp cannot run this environment (its model or per-world fields).

  With `ExecutionOptions(impl='warp')` it reaches the caller; with `impl=None`
  the environment is built on 'jax' instead, with a logged warning.
  """


def _is_cuda(device) -> bool:
  """Whether `device` is an NVIDIA GPU (MuJoCo Warp's GPU target)."""
  if device.platform != 'gpu':
    return False
  version = getattr(device.client, 'platform_version', '') or ''
  return 'rocm' not in version.lower()


def default_impls(device, share_reset_forward=None) -> tuple[str, ...]:
  """What `impl=None` tries on `device`, in order.

  'warp' first on a CUDA GPU where MuJoCo Warp is installed and the fused
  restart was not asked for (`share_reset_forward=True` is 'jax' only): on
  a GPU at 8,192 worlds, MuJoCo Warp steps the composed tasks faster than
  MJX's JAX implementation (walk: about 2.3x; `benchmarks/backends.py`
  measures it). 'jax' everywhere else, and after 'warp' when Warp refuses
  the environment (`WarpUnsupportedError`).
  """
  if _is_cuda(device) and not share_reset_forward and warp_installed():
    return ('warp', 'jax')
  return ('jax',)


def resolve_impl(impl, device, share_reset_forward=None) -> tuple[str, ...]:
  """The implementations an environment on `device` tries, in order.

  Args:
    impl: 'jax', 'warp', or None for the default (`default_impls`).
    device: the JAX device the environment runs on.
    share_reset_forward: the `Environment` argument (True rules out 'warp'
      for the default).

  Returns:
    `(impl,)` for an explicit choice; `default_impls(...)` for None.

  Raises:
    ValueError: for an unknown `impl`, or 'warp' on a device that is
      neither a CUDA GPU nor a CPU.
    ImportError: for 'warp' when `warp-lang` is not installed.
  """
  if impl is None:
    return default_impls(device, share_reset_forward)
  if impl not in IMPLS:
    raise ValueError(f"impl must be 'jax', 'warp' or None, got {impl!r}.")
  if impl == 'warp':
    if device.platform not in ('cpu', 'gpu'):
      raise ValueError(
          "impl='warp' runs on a CUDA GPU or on the CPU; this environment's "
          f"device is {device} ({device.platform}). Use impl='jax'."
      )
    if not warp_installed():
      raise ImportError(
          "impl='warp' needs MuJoCo Warp's runtime, warp-lang, which is not "
          f'installed (or failed to import). Install it with: {INSTALL_HINT}'
          " (or use impl='jax')."
      )
  return (impl,)


def default_share_reset_forward(impl: str, device) -> bool:
  """`ExecutionOptions(share_reset_forward=None)`: True on a CPU with 'jax'."""
  return impl == 'jax' and device.platform == 'cpu'


def check_share_reset_forward(impl: str, share_reset_forward) -> None:
  if impl == 'warp' and share_reset_forward:
    raise ValueError(
        "share_reset_forward=True cannot run on impl='warp': the fused "
        'restart runs the integrator (mjx.euler / mjx.implicit) apart from '
        "mjx.forward, and MJX implements those on impl='jax' only. Leave "
        "share_reset_forward unset (on 'warp' the sub-steps run mjx.step "
        'and the restart of ended episodes is separate; results are the '
        "same), or use impl='jax'."
    )


def check_buffer_arguments(
    impl: str, naconmax, njmax, requested: str | None = None
) -> None:
  """`naconmax` and `njmax` size MuJoCo Warp's buffers.

  Args:
    impl: the implementation the environment is built on.
    naconmax: the `Environment` argument.
    njmax: the `Environment` argument.
    requested: the `Environment`'s `impl` argument. With None (the default
      choice, Warp only where it runs), sizes given for Warp are ignored on
      'jax', so that one call builds on either; an explicit 'jax' refuses
      them.

  Raises:
    ValueError: sizes with an explicit impl='jax', or sizes that are not
      positive integers.
  """
  if (
      requested is not None
      and impl != 'warp'
      and (naconmax is not None or njmax is not None)
  ):
    raise ValueError(
        "naconmax and njmax size MuJoCo Warp's contact and constraint "
        f"buffers: pass them with impl='warp' or impl=None only (impl is "
        f'{impl!r}).'
    )
  for name, value in (('naconmax', naconmax), ('njmax', njmax)):
    if value is not None and (int(value) != value or value < 1):
      raise ValueError(f'{name} must be a positive integer, got {value!r}.')


def put(mj_model, impl: str, device, naconmax=None, njmax=None):
  """`(mjx.Model, mjx.Data)` of `mj_model` on `device` with `impl`.

  Args:
    mj_model: the compiled host model.
    impl: 'jax' or 'warp' (`resolve_impl`).
    device: the JAX device.
    naconmax: 'warp': contacts held for all the worlds of a batch (default
      `DEFAULT_CONTACTS_PER_WORLD * DEFAULT_WORLDS`).
    njmax: 'warp': constraint rows per world (default `default_njmax`).

  Raises:
    WarpUnsupportedError: the model uses something MuJoCo Warp does not
      implement (its own message, with what to do).
  """
  if impl == 'jax':
    model = mjx.put_model(mj_model, device=device, impl='jax')
    return model, mjx.make_data(model, device=device, impl='jax')
  if naconmax is None:
    naconmax = DEFAULT_CONTACTS_PER_WORLD * DEFAULT_WORLDS
  if njmax is None:
    njmax = default_njmax(mj_model)
  try:
    model = mjx.put_model(mj_model, device=device, impl='warp')
    data = mjx.make_data(
        mj_model,
        device=device,
        impl='warp',
        naconmax=int(naconmax),
        njmax=int(njmax),
    )
  except (NotImplementedError, ValueError) as e:
    raise WarpUnsupportedError(
        f"MuJoCo Warp (impl='warp') cannot run the composed model: {e} "
        "Change the entity that adds it, or use impl='jax'."
    ) from e
  # MuJoCo Warp prints a warning from its kernels whenever a flag in
  # `warn_overflow` is raised. Keep the buffer overflows (lost contacts or
  # constraints); drop the solver's iteration limits, which models reach
  # by design (e.g. Playground's iterations=1) and 'jax' reaches silently.
  warn_overflow = int(internals.option_impl(model.opt).warn_overflow)
  model = model.replace(
      opt=internals.replace_option_impl(
          model.opt, warn_overflow=warn_overflow & ~_solver_limits()
      )
  )
  return model, data


def default_njmax(mj_model) -> int:
  """Constraint rows per world that `put` gives MuJoCo Warp unless told.

  The larger of MuJoCo Warp's own estimate and the rows MJX's JAX
  implementation allocates for the model. Warp's estimate depends only on
  the model's degrees of freedom, height fields, flexes and SDFs, and is 64
  rows for each bundled model; the JAX implementation allocates a world's
  worst case under its per-pair contact limits (every contact pair touching
  at once, every limit active). On push, Warp's 64 rows let 194 of 8,192
  worlds drop constraints; the JAX implementation's count is 122. Where
  the estimate is larger (reach: 64 against 32), it stays, so nothing that
  ran within Warp's default gets less room.
  """
  jax_data = jax.eval_shape(lambda: mjx.make_data(mj_model, impl='jax'))
  jax_rows = internals.data_impl(jax_data).efc_J.shape[0]
  return max(internals.warp_default_njmax(mj_model), int(jax_rows))


def _overflow_type():
  # Here, not at the top: MuJoCo Warp imports only where warp-lang does.
  from mujoco.mjx.third_party import mujoco_warp  # pylint: disable=g-import-not-at-top

  return mujoco_warp.OverflowType


def _solver_limits() -> int:
  """The overflow bits that say the solver stopped at its iteration limit."""
  kind = _overflow_type()
  return int(kind.ITERATIONS | kind.LS_ITERATIONS)


# -- per-world model fields ---------------------------------------------------


def unbatchable_fields(names) -> list[str]:
  """The model fields of `names` that cannot differ between Warp's worlds.

  A field MuJoCo Warp reads (it has an entry in `_BATCH_DIM['Model']`)
  without a batch dimension. 'opt' and 'stat' are judged by their leaves:
  every option MJX's `Option` carries is batchable or unread by Warp, and
  Warp never reads the statistics.
  """
  batch = internals.warp_model_batch_dims()
  return sorted(n for n in names if batch.get(n) is False)


def check_per_world_fields(impl: str, writers: dict) -> None:
  """Refuses, on 'warp', per-world fields that Warp cannot batch.

  Args:
    impl: 'jax' or 'warp'.
    writers: `{model field: the hooks that made it per-world}`
      (`Environment.per_world_model_fields`).

  Raises:
    WarpUnsupportedError: naming each field, who writes it, and what to do.
  """
  if impl != 'warp':
    return
  bad = unbatchable_fields(writers)
  if not bad:
    return
  lines = '; '.join(f'{n} (written by {", ".join(writers[n])})' for n in bad)
  raise WarpUnsupportedError(
      "impl='warp' cannot vary these model fields per world: "
      f'{lines}. MuJoCo Warp runs one kernel over all the worlds of a batch '
      'and reads these fields from one copy shared by every world (they '
      "have no batch dimension in mujoco.mjx.warp.types._BATCH_DIM['Model']"
      '). Keep them the same in every world (switch off the variation or '
      "hook that writes them), or use impl='jax', which varies any field."
  )


# -- the JAX twin of a Warp model -----------------------------------------------


def is_warp(model_or_data) -> bool:
  return model_or_data.impl == mjx.Impl.WARP


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
  """`(model, data)` on MJX's JAX implementation, with their values.

  For MJX functions that only the JAX implementation has, e.g. its
  narrow-phase colliders (`initializers.contacts`): the JAX twin of
  `model` (`jax_twin`), and the host model's 'jax' data with `data`'s
  public fields. A 'jax' pair is returned as it is.
  """
  if not is_warp(model):
    return model, data
  base_model, base_data = jax_base(mj_model)
  public = {}
  for f in dataclasses.fields(mjx.Data):
    if f.name == '_impl':
      continue
    value, like = getattr(data, f.name), getattr(base_data, f.name)
    if jnp.shape(value) == jnp.shape(like):
      public[f.name] = value
  return jax_twin(model, base_model), base_data.replace(**public)


# -- Data: per-world and shared fields ------------------------------------------


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


def overflow(data) -> jax.Array:
  """MuJoCo Warp's buffer overflows per world since the reset (0: none).

  A bitmask of `mujoco.mjx.third_party.mujoco_warp.OverflowType`: 1
  constraint rows beyond `njmax`, 8 contacts beyond `naconmax` (the whole
  batch's), ...: contacts or constraints that were dropped. The solver
  reaching its iteration limits (`ITERATIONS`, `LS_ITERATIONS`) is left
  out: that is the model's setting, as on 'jax'. Zeros for 'jax' data,
  which has no fixed buffers.
  """
  if data.impl != mjx.Impl.WARP:
    return jnp.zeros(jnp.shape(data.time), jnp.int32)
  flags = internals.data_impl(data).overflow
  return flags & ~jnp.asarray(_solver_limits(), flags.dtype)


def contacts_in_use(data) -> jax.Array:
  """Contacts in MuJoCo Warp's shared buffer after the last collision.

  Compare it with `naconmax` to size the buffer; 0 for 'jax' data.
  """
  if data.impl != mjx.Impl.WARP:
    return jnp.zeros((), jnp.int32)
  return internals.data_impl(data).nacon[0]


def naconmax(data) -> int:
  """The contact buffer's size ('warp'); 0 for 'jax' data."""
  if data.impl != mjx.Impl.WARP:
    return 0
  return int(internals.data_impl(data).naconmax)


def njmax(data) -> int:
  """Constraint rows per world ('warp'); 0 for 'jax' data."""
  if data.impl != mjx.Impl.WARP:
    return 0
  return int(internals.data_impl(data).njmax)
