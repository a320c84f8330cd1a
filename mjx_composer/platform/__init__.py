"""What runs where: physics backends, devices and JAX's settings.

The MJX implementation that runs the physics (`impl_choice` chooses it;
`backend`, what it supports and runs differently; `jax_twin`, what only
MJX's JAX code computes, for a MuJoCo Warp model; `shared_buffers`, tree
operations that keep Warp's batch-shared `Data` buffers whole), a batch of
worlds over devices (`sharding`, `partitioner`), the JAX settings the
package's entry points switch on (`compilation_cache`, `prng_lowering`,
`cpu_linalg`; all three at once: `configure`), the analyses' answers kept
beside the compiled programs (`answer_cache`), how MJX is imported
(`mjx_import`: quietly, completed by `internals`), and the modules that use
other packages' private internals (`internals`: MJX and MuJoCo Warp;
`internals_jax`: JAX; `internals_numpy`: NumPy's random module).

This subpackage imports nothing else of `mjx_composer`
(`tests/package/test_layers.py`).
"""

from __future__ import annotations

import os

from mjx_composer.platform import compilation_cache as _compilation_cache
from mjx_composer.platform import cpu_linalg as _cpu_linalg
from mjx_composer.platform import mjx_import as _mjx_import
from mjx_composer.platform import prng_lowering as _prng_lowering


def configure(
    compilation_cache: bool | str | os.PathLike[str] | None = None,
) -> str | None:
  """Switches on the JAX settings that compose environments compile with.

  Call it first thing in a program (a script's `main`, a notebook's first
  cell), before the first compilation: each setting applies to programs
  lowered after it, and is part of JAX's compilation cache key. The command
  line, the examples, the benchmarks, the notebooks and the test suite call
  it. Each setting can be switched off by an environment variable, and
  JAX's own settings, where given, win:

  * JAX's persistent compilation cache (`compilation_cache.enable`):
    compiled programs are kept on disk and loaded when the same program is
    compiled again, in this process or a later one, instead of compiling
    for seconds (GPU) to minutes (CPU) again.
    `MJX_COMPOSER_COMPILATION_CACHE=0`: off; `MJX_COMPOSER_CACHE_DIR`: where.
  * threefry as JAX's GPU kernel (`prng_lowering.enable`): every random
    draw hashes with threefry, which JAX otherwise lowers to about a hundred
    HLO instructions per call on a GPU; one kernel call each makes a
    reset's program smaller and faster to compile. The same random values;
    nothing changes on a CPU. `MJX_COMPOSER_THREEFRY_KERNEL=0`: off.
  * Cholesky in plain XLA on the CPU (`cpu_linalg.enable`): jaxlib's
    LAPACK kernel for a batched Cholesky (MJX's solver factorizes in every
    forward pass) can deadlock XLA's CPU thread pool when several run at
    once. Importing `mjx_composer` already does this (`safe_defaults`);
    repeated here so that an environment variable changed since is obeyed.
    `MJX_COMPOSER_XLA_CHOLESKY=0`: off.

  Args:
    compilation_cache: None (the default): the persistent cache is on
      unless `MJX_COMPOSER_COMPILATION_CACHE` is 0, false, no or off; True
      or False: on or off, whatever the environment says; a folder: on, in
      that folder (instead of `compilation_cache.default_cache_dir()`).

  Returns:
    The persistent cache's folder, or None where the cache is off.
  """
  if compilation_cache is None or isinstance(compilation_cache, bool):
    cache_dir = _compilation_cache.enable(enabled=compilation_cache)
  else:
    cache_dir = _compilation_cache.enable(os.fspath(compilation_cache))
  _prng_lowering.enable()
  _cpu_linalg.enable()
  return cache_dir


def safe_defaults() -> None:
  """What importing `mjx_composer` sets: only what keeps programs correct.

  Cholesky in plain XLA on the CPU (`cpu_linalg.enable`), unless
  `MJX_COMPOSER_XLA_CHOLESKY` is 0: without it, a CPU program that runs two
  batched factorizations at once (a randomized reset beside MJX's forward
  pass, or two environments stepping in threads) can deadlock in jaxlib's
  LAPACK kernel, and nothing the user could see would say why. It is cheap
  (one lowering rule registered; no device is touched and nothing
  compiles) and changes results by float rounding at most. It applies to
  every program this process lowers afterwards, the user's own too: a large
  single Cholesky on the CPU may run slower than with LAPACK; switch it off
  with the environment variable or `cpu_linalg.enable(enabled=False)`.

  And MJX, when it is first imported (now, if it was before), quietly and
  with what this package adds to it (`mjx_import.install`): MJX's missing
  ray-geom functions (a touch sensor on a cylinder site), with MuJoCo's
  semantics, and errors that say what to use where a dm_control idiom meets
  MJX's classes (indexing or iterating `physics.data.contact`,
  `physics.model.ptr`).

  The other settings of `configure` change speed, not correctness, and
  write to disk (the cache): a user asks for them.
  """
  _mjx_import.install()
  _cpu_linalg.enable()
