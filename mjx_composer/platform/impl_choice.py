"""Which MJX implementation an environment runs on: 'jax' or 'warp'.

MJX 3.17 runs the same `mjx.Model`/`mjx.Data` API on two implementations:
'jax' (XLA, every device) and 'warp' (MuJoCo Warp kernels called through
JAX's FFI, on a CUDA GPU or, compiled through LLVM, on the CPU). An
`ExecutionOptions(impl=...)` names one, or None for the default
(`default_impls`); `resolve_impl` turns that into the implementations an
environment tries, in order, and refuses a choice that cannot run. What
each implementation then does differently is its `backend.Backend`.

The argument checks here take the implementation's name because they run
before (or while) it is chosen: `ExecutionOptions` checks its fields when
it is built, with `impl` possibly None.
"""

from __future__ import annotations

import mujoco.mjx.warp as mjx_warp

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


def check_impl(impl, owner: str) -> None:
  """Refuses an `impl` that names no implementation (None: the default)."""
  if impl is not None and impl not in IMPLS:
    raise ValueError(
        f"{owner}: impl must be 'jax', 'warp' or None, got {impl!r}."
    )


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


def check_buffer_arguments(
    impl: str | None, naconmax, njmax, requested: str | None = None
) -> None:
  """`naconmax` and `njmax` size MuJoCo Warp's buffers.

  Args:
    impl: the implementation the environment is built on (None: not chosen
      yet).
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


def check_auto_reset_batch(impl: str | None) -> None:
  """`ExecutionOptions(auto_reset_batch=...)` gathers worlds: 'jax' only."""
  if impl == 'warp':
    raise ValueError(
        "ExecutionOptions(auto_reset_batch=...) needs impl='jax': MuJoCo "
        "Warp's contact buffer is shared by the whole batch, so a subset of "
        "worlds cannot be gathered and reset on its own. Use impl='jax' (or "
        'leave auto_reset_batch unset).'
    )
