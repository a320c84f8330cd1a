"""The backend: what the chosen MJX implementation runs and how.

An environment is built on one MJX implementation, 'jax' or 'warp'
(`impl_choice.resolve_impl`), and resolves it once into a `Backend`
(`get`); code that holds only an `mjx.Model` or `mjx.Data` finds it from
them (`of`). Everything else in the package asks the backend what it
supports and has it run the operations that differ, never which
implementation it is:

* capabilities: whether the forward pass can run stage by stage
  (`staged_forward`), whether `mjx.Data` holds the JAX implementation's
  fields such as the per-world contact list (`jax_data_fields`), whether
  the physics runs MJX's JAX pipeline, whose collision functions and
  friction cones `model_checks` judges (`jax_pipeline`), whether the
  integrator runs apart from `mjx.forward`, which the fused restart needs
  (`fused_restart`), whether the batch shares `Data` buffers
  (`batch_shared_data`: no subset of worlds gathered, no device splitting
  one batch, no per-world loop over a whole `Data`), whether the buffers
  have sizes (`sized_buffers`: `naconmax`, `njmax`), and whether every
  model field may differ between worlds (`batches_every_model_field`).
* operations: `put` (the device model and data, with what MuJoCo Warp
  refuses re-raised as `WarpUnsupportedError`), `check_per_world_fields`,
  the JAX twin of a model for what only MJX's JAX code computes
  (`jax_model`, `jax_view`; `jax_twin`), and the buffer reports
  (`overflow`, `contacts_in_use`, `naconmax`, `njmax`).

The tree operations over Warp's batch-shared buffers (`select`,
`drop_shared`, `restore_shared`) need no backend: they are in
`shared_buffers`, and hold for either implementation.

What runs where on 'warp':

* `mjx.step`, `mjx.forward`, `mjx.kinematics`, `mjx.com_pos`,
  `mjx.tendon`: MuJoCo Warp, batched over the worlds of a `jax.vmap`.
* the derived quantities of a randomized model and `PropPlacer`'s
  collision tests: MJX's JAX implementation, on the JAX twin
  (`jax_twin`). `PropPlacer(settle_physics=True)` is refused.
* per-world model fields: MuJoCo Warp runs one kernel over every world of
  a batch, and only some model fields may differ between worlds (those
  with a batch dimension in `mujoco.mjx.warp.types._BATCH_DIM['Model']`:
  masses, inertias, frames, sizes, frictions, gains, option vectors, ...).
  A hook that writes any other field per world, e.g. a per-world height
  field profile (`hfield_data`), is refused (`check_per_world_fields`).
  Fields that MuJoCo Warp does not read at all (`dof_M0`, `stat`) may vary:
  they only matter to the 'jax' implementation.
* the fused same-step restart (`ExecutionOptions(share_reset_forward=True)`)
  runs the integrator (`mjx.euler`, `mjx.implicit`) apart from
  `mjx.forward`, which MJX provides on 'jax' only; on 'warp' the sub-steps
  run `mjx.step` and the restart is separate.

Contacts and constraints (`naconmax`, `njmax`): MuJoCo Warp keeps the
contacts of all the worlds of a batch in one buffer of `naconmax` contacts
(shared by the batch, `shared_buffers`), and `njmax` constraint rows per
world (`default_njmax`). Both are fixed when the environment is built. A
world that needs more loses contacts or constraints; MuJoCo Warp flags it
in its per-world overflow bitmask, which `overflow` reads and
`metrics['overflow']` reports: check it (the benchmarks and tests do) when
choosing the sizes.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from mujoco import mjx

from mjx_composer.platform import impl_choice
from mjx_composer.platform import internals
from mjx_composer.platform import jax_twin

# What callers of the backend name through it (`impl_choice` chooses).
IMPLS = impl_choice.IMPLS
DEFAULT_CONTACTS_PER_WORLD = impl_choice.DEFAULT_CONTACTS_PER_WORLD
DEFAULT_WORLDS = impl_choice.DEFAULT_WORLDS
WarpUnsupportedError = impl_choice.WarpUnsupportedError
warp_installed = impl_choice.warp_installed
resolve_impl = impl_choice.resolve_impl


class Backend:
  """What one MJX implementation supports, and the operations that differ.

  Attributes:
    name: the implementation's name, 'jax' or 'warp' (for messages and
      `ExecutionOptions.impl`; never to branch on).
    staged_forward: the forward pass can run stage by stage (kinematics,
      velocities, sensors apart), so that a reset or step runs only the
      stage its readers need; else it is one kernel sequence, always whole.
    jax_data_fields: `mjx.Data` holds the JAX implementation's data (the
      per-world contact list, constraint rows, com velocities), which
      bindings and contact queries read.
    jax_pipeline: the physics runs MJX's JAX pipeline: its collision
      functions and solver, whose limits `model_checks` refuses at build.
    fused_restart: the integrator runs apart from `mjx.forward`, as the
      restart fused into the sub-step loop needs.
    batch_shared_data: some `Data` buffers are one copy per batch
      (`shared_buffers`): worlds cannot be gathered into a smaller batch,
      a batch cannot be split over devices by `pmap`, and a per-world loop
      must not carry a whole `Data`.
    sized_buffers: the contact and constraint buffers have sizes fixed at
      build (`naconmax`, `njmax`).
    batches_every_model_field: any model field may differ between worlds
      (else `check_per_world_fields` refuses those that cannot).
  """

  name: str = ''
  staged_forward = True
  jax_data_fields = True
  jax_pipeline = True
  fused_restart = True
  batch_shared_data = False
  sized_buffers = False
  batches_every_model_field = True

  def put(self, mj_model, device, naconmax=None, njmax=None):
    """`(mjx.Model, mjx.Data)` of `mj_model` on `device`."""
    raise NotImplementedError

  def default_share_reset_forward(self, device) -> bool:
    """`ExecutionOptions(share_reset_forward=None)`: True on a CPU where the
    restart can fuse."""
    return self.fused_restart and device.platform == 'cpu'

  def check_share_reset_forward(self, share_reset_forward) -> None:
    """Refuses `share_reset_forward=True` where the restart cannot fuse."""

  def check_per_world_fields(self, writers: dict) -> None:
    """Refuses per-world model fields the implementation cannot batch.

    Args:
      writers: `{model field: the hooks that made it per-world}`
        (`Environment.per_world_model_fields`).
    """

  def jax_model(self, model: mjx.Model, mj_model) -> mjx.Model:
    """`model` on MJX's JAX implementation, for what only it computes."""
    del mj_model
    return model

  def jax_view(self, model: mjx.Model, data: mjx.Data, mj_model=None):
    """`(model, data)` on MJX's JAX implementation, with their values."""
    del mj_model
    return model, data

  def overflow(self, data) -> jax.Array:
    """Buffer overflows per world since the reset (0: none; `WarpBackend`)."""
    return jnp.zeros(jnp.shape(data.time), jnp.int32)

  def contacts_in_use(self, data) -> jax.Array:
    """Contacts in a batch-shared buffer after the last collision (0: none)."""
    del data
    return jnp.zeros((), jnp.int32)

  def naconmax(self, data) -> int:
    """The contact buffer's size (0: no fixed buffer)."""
    del data
    return 0

  def njmax(self, data) -> int:
    """Constraint rows per world (0: no fixed buffer)."""
    del data
    return 0

  def __repr__(self):
    return f'{type(self).__name__}()'


class JaxBackend(Backend):
  """MJX's JAX implementation (XLA, every device): everything is per world."""

  name = 'jax'

  def put(self, mj_model, device, naconmax=None, njmax=None):
    del naconmax, njmax
    model = mjx.put_model(mj_model, device=device, impl='jax')
    return model, mjx.make_data(model, device=device, impl='jax')


class WarpBackend(Backend):
  """MuJoCo Warp (its kernels through JAX's FFI, on a CUDA GPU or the CPU)."""

  name = 'warp'
  staged_forward = False
  jax_data_fields = False
  jax_pipeline = False
  fused_restart = False
  batch_shared_data = True
  sized_buffers = True
  batches_every_model_field = False

  def put(self, mj_model, device, naconmax=None, njmax=None):
    """`(mjx.Model, mjx.Data)` on MuJoCo Warp.

    Args:
      mj_model: the compiled host model.
      device: the JAX device.
      naconmax: contacts held for all the worlds of a batch (default
        `DEFAULT_CONTACTS_PER_WORLD * DEFAULT_WORLDS`).
      njmax: constraint rows per world (default `default_njmax`).

    Raises:
      WarpUnsupportedError: the model uses something MuJoCo Warp does not
        implement (its own message, with what to do).
    """
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

  def check_share_reset_forward(self, share_reset_forward) -> None:
    if share_reset_forward:
      raise ValueError(
          "share_reset_forward=True cannot run on impl='warp': the fused "
          'restart runs the integrator (mjx.euler / mjx.implicit) apart from '
          "mjx.forward, and MJX implements those on impl='jax' only. Leave "
          "share_reset_forward unset (on 'warp' the sub-steps run mjx.step "
          'and the restart of ended episodes is separate; results are the '
          "same), or use impl='jax'."
      )

  def check_per_world_fields(self, writers: dict) -> None:
    """Refuses per-world fields that Warp cannot batch.

    Raises:
      WarpUnsupportedError: naming each field, who writes it, and what to
        do.
    """
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

  def jax_model(self, model: mjx.Model, mj_model) -> mjx.Model:
    """The JAX twin of `model` (`jax_twin.jax_twin`)."""
    return jax_twin.jax_twin(model, jax_twin.jax_base(mj_model)[0])

  def jax_view(self, model: mjx.Model, data: mjx.Data, mj_model=None):
    """The JAX twins of `model` and `data` (`jax_twin.jax_view`)."""
    if mj_model is None:
      raise ValueError(
          "The JAX view of a 'warp' model needs mj_model, the compiled host "
          'model.'
      )
    return jax_twin.jax_view(model, data, mj_model)

  def overflow(self, data) -> jax.Array:
    """MuJoCo Warp's buffer overflows per world since the reset (0: none).

    A bitmask of `mujoco.mjx.third_party.mujoco_warp.OverflowType`: 1
    constraint rows beyond `njmax`, 8 contacts beyond `naconmax` (the whole
    batch's), ...: contacts or constraints that were dropped. The solver
    reaching its iteration limits (`ITERATIONS`, `LS_ITERATIONS`) is left
    out: that is the model's setting, as on 'jax'.
    """
    flags = internals.data_impl(data).overflow
    return flags & ~jnp.asarray(_solver_limits(), flags.dtype)

  def contacts_in_use(self, data) -> jax.Array:
    """Contacts in MuJoCo Warp's shared buffer after the last collision.

    Compare it with `naconmax` to size the buffer.
    """
    return internals.data_impl(data).nacon[0]

  def naconmax(self, data) -> int:
    return int(internals.data_impl(data).naconmax)

  def njmax(self, data) -> int:
    return int(internals.data_impl(data).njmax)


JAX = JaxBackend()
WARP = WarpBackend()
_BY_NAME = {backend.name: backend for backend in (JAX, WARP)}


def get(impl: str) -> Backend:
  """The backend of the implementation named `impl` ('jax' or 'warp')."""
  try:
    return _BY_NAME[impl]
  except KeyError:
    raise ValueError(f"impl must be 'jax' or 'warp', got {impl!r}.") from None


def of(model_or_data) -> Backend:
  """The backend an `mjx.Model` or `mjx.Data` was put on."""
  return WARP if model_or_data.impl == mjx.Impl.WARP else JAX


def resolve(impl, device, share_reset_forward=None) -> tuple[Backend, ...]:
  """The backends an environment on `device` tries, in order
  (`impl_choice.resolve_impl`)."""
  return tuple(
      get(name) for name in resolve_impl(impl, device, share_reset_forward)
  )


# -- reports on any `Data`: its backend's --------------------------------------


def overflow(data) -> jax.Array:
  """`Backend.overflow` of `data`'s backend: 0 per world on 'jax'."""
  return of(data).overflow(data)


def contacts_in_use(data) -> jax.Array:
  """`Backend.contacts_in_use` of `data`'s backend: 0 on 'jax'."""
  return of(data).contacts_in_use(data)


def naconmax(data) -> int:
  """The contact buffer's size ('warp'); 0 for 'jax' data."""
  return of(data).naconmax(data)


def njmax(data) -> int:
  """Constraint rows per world ('warp'); 0 for 'jax' data."""
  return of(data).njmax(data)


# -- MuJoCo Warp's buffers -----------------------------------------------------


def default_njmax(mj_model) -> int:
  """Constraint rows per world that `WarpBackend.put` gives unless told.

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


def unbatchable_fields(names) -> list[str]:
  """The model fields of `names` that cannot differ between Warp's worlds.

  A field MuJoCo Warp reads (it has an entry in `_BATCH_DIM['Model']`)
  without a batch dimension. 'opt' and 'stat' are judged by their leaves:
  every option MJX's `Option` carries is batchable or unread by Warp, and
  Warp never reads the statistics.
  """
  batch = internals.warp_model_batch_dims()
  return sorted(n for n in names if batch.get(n) is False)
