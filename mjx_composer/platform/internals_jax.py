"""Every use of JAX's private internals.

The package needs a few things that JAX does not export: a lowering rule of
JAX's Cholesky primitive (`cpu_linalg`), JAX's dead-code elimination of a
jaxpr (`runtime.data_reads`) and its partial evaluation
(`runtime.stored_restart`), JAX's partitioner setting (`partitioner`),
the barrier of JAX's coordination service (`training`), the entries of
JAX's persistent compilation cache (`compilation_cache`), and it puts back
`jax.device_put_replicated` for Brax (`adapters.brax`). This module, with
`internals` (MJX and MuJoCo Warp) and `internals_numpy` (NumPy's random
module), is the only one that imports a private module (`jax._src`) or
assigns JAX's attributes; every other module calls the names below. When JAX is upgraded, this file is the
one to revisit (`tests/package/test_layers.py` keeps private imports out of the rest
of the package).

Each name says what private thing it wraps and why the package needs it.
Written against jax 0.10.
"""

from __future__ import annotations

from typing import Any, Callable

# pylint: disable=protected-access
from jax._src.interpreters import mlir as _mlir
from jax._src.lax import linalg as _linalg

try:  # JAX's own configuration objects, beside the public `jax.config`.
  from jax._src import config as _jax_config
except ImportError:  # pragma: no cover - a JAX that moved it
  _jax_config = None

try:  # JAX's dead-code elimination and partial evaluation of a jaxpr.
  from jax._src.interpreters import partial_eval as _partial_eval
except ImportError:  # pragma: no cover - a JAX that moved it
  _partial_eval = None


# -- JAX ----------------------------------------------------------------------

# `jax._src.compilation_cache.get_executable_and_time`, which JAX's compiler
# calls (through the module) to load a persistent-cache entry. JAX has no
# public hook for an entry that fails to load: it warns, compiles, and does
# not overwrite the entry (`LRUCache.put` keeps an existing file), so a
# corrupted entry is read and recompiled in every process.
try:
  from jax._src import compilation_cache as _jax_compilation_cache
  from jax._src import lru_cache as _jax_lru_cache
except ImportError:  # pragma: no cover - a JAX that moved them
  _jax_compilation_cache = _jax_lru_cache = None


def remove_unreadable_cache_entries(on_removed: Callable[[str], Any]) -> bool:
  """Makes JAX delete a persistent-cache entry that fails to load.

  Wraps `jax._src.compilation_cache.get_executable_and_time` (once per
  process): when loading an entry raises (a truncated or corrupted file),
  its files are removed and `on_removed(path)` is called, then the error
  propagates to JAX, which warns and compiles as before and now writes a
  fresh entry. Returns False where this JAX lacks those internals.
  """
  module = _jax_compilation_cache
  if module is None or not hasattr(module, 'get_executable_and_time'):
    return False
  original = module.get_executable_and_time
  if getattr(original, 'removes_unreadable_entries', False):
    return True

  def get_executable_and_time(cache_key, compile_options, backend, *args):
    try:
      return original(cache_key, compile_options, backend, *args)
    except Exception:
      cache = module._get_cache(backend)
      folder = getattr(cache, 'path', None) or getattr(cache, '_path', None)
      removed = _remove_entry(folder, cache_key)
      if removed is not None:
        on_removed(removed)
      raise

  get_executable_and_time.removes_unreadable_entries = True
  module.get_executable_and_time = get_executable_and_time
  return True


# `jax._src.compilation_cache.get_file_cache`, which JAX calls once per
# process to make the persistent cache object (a `jax._src.lru_cache.LRUCache`,
# maybe inside a `VerificationCache`). An entry's file name is its key, and
# nothing inside the file says which program it holds: JAX loads whatever a
# file of that name holds, and an entry renamed, copied or swapped with
# another one loads another program, which fails far from the cause (an
# assertion in `safe_zip` when the outputs are counted) or, where the two
# programs take and return the same shapes, silently runs the wrong one.

# What a bound entry starts with, followed by its key and a NUL byte.
CACHE_KEY_HEADER = b'mjx_composer persistent cache entry, key: '


def _entry_key(raw: bytes) -> str | None:
  """The key a bound entry was written under, or None for an unbound one."""
  if not raw.startswith(CACHE_KEY_HEADER):
    return None
  end = raw.find(b'\0', len(CACHE_KEY_HEADER))
  if end < 0:
    return None
  try:
    return raw[len(CACHE_KEY_HEADER) : end].decode('utf-8')
  except UnicodeDecodeError:
    return None


def _remove_entry(folder, cache_key: str) -> str | None:
  """Deletes `cache_key`'s entry files in `folder`; returns the entry's path."""
  if folder is None or not cache_key or _jax_lru_cache is None:
    return None
  entry = folder / f'{cache_key}{_jax_lru_cache._CACHE_SUFFIX}'
  atime = folder / f'{cache_key}{_jax_lru_cache._ATIME_SUFFIX}'
  removed = None
  if entry.exists():
    entry.unlink()
    removed = str(entry)
  if atime.exists():
    atime.unlink()
  return removed


if _jax_compilation_cache is not None and hasattr(
    _jax_compilation_cache, 'CacheInterface'
):

  class _KeyBoundCache(_jax_compilation_cache.CacheInterface):
    """A file cache whose entries each carry the key they were written under.

    `put` writes `CACHE_KEY_HEADER + key + NUL` before JAX's bytes; `get`
    returns JAX's bytes only when the entry names the key it is read under.
    Any other entry (one renamed, copied or swapped from another key, or
    written without the header by a JAX that did not bind its entries) is
    removed, reported to `on_removed(path, key_it_holds_or_None)` and read
    as a miss: JAX compiles the program and writes a bound entry.
    """

    def __init__(self, base, on_removed):
      self._base_cache = base
      self._on_removed = on_removed

    @property
    def _path(self):  # pytype: disable=signature-mismatch
      return self._base_cache._path

    @_path.setter
    def _path(self, value):
      self._base_cache._path = value

    @property
    def path(self):
      return getattr(self._base_cache, 'path', self._base_cache._path)

    def get(self, key: str):
      raw = self._base_cache.get(key)
      if raw is None:
        return None
      holds = _entry_key(raw)
      if holds == key:
        return raw[len(CACHE_KEY_HEADER) + len(key.encode('utf-8')) + 1 :]
      removed = _remove_entry(self.path, key)
      if removed is not None:
        self._on_removed(removed, holds)
      return None

    def put(self, key: str, value: bytes):
      self._base_cache.put(
          key, CACHE_KEY_HEADER + key.encode('utf-8') + b'\0' + value
      )

    def clear(self):
      clear = getattr(self._base_cache, 'clear', None)
      if clear is not None:
        clear()

else:  # pragma: no cover - a JAX that moved them
  _KeyBoundCache = None


def bind_cache_entries_to_keys(
    on_removed: Callable[[str, str | None], Any],
) -> bool:
  """Makes every persistent-cache entry name the key it was written under.

  Wraps `jax._src.compilation_cache.get_file_cache` (once per process), so
  the cache JAX makes when it first compiles with a cache folder writes the
  key into each entry and refuses an entry that names another key (or
  none): such an entry is removed, `on_removed(path, key_it_holds)` is
  called (`key_it_holds` is None for an entry without a key) and JAX
  compiles the program afresh, as for an entry it never had. Call it before
  the first compilation with the cache folder set. Returns False where this
  JAX lacks those internals (entries are then read as JAX reads them).
  """
  module = _jax_compilation_cache
  if (
      module is None
      or _KeyBoundCache is None
      or not hasattr(module, 'get_file_cache')
  ):
    return False
  original = module.get_file_cache
  if getattr(original, 'binds_entries_to_keys', False):
    return True

  def get_file_cache(path):
    made = original(path)
    if made is None:
      return None
    cache, folder = made
    inner = getattr(cache, '_base_cache', None)
    if inner is not None:  # a VerificationCache compares JAX's own bytes
      cache._base_cache = _KeyBoundCache(inner, on_removed)
    else:
      cache = _KeyBoundCache(cache, on_removed)
    return cache, folder

  get_file_cache.binds_entries_to_keys = True
  module.get_file_cache = get_file_cache
  return True


# `jax._src.interpreters.mlir.lower_fun`: turns a JAX function into a
# lowering rule. `cpu_linalg` lowers Cholesky to plain XLA loops with it;
# JAX has no public way to replace a primitive's lowering.
lower_fun = _mlir.lower_fun

# `jax._src.lax.linalg.cholesky_p`: JAX's Cholesky primitive, whose CPU
# lowering `cpu_linalg` replaces.
cholesky_p = _linalg.cholesky_p

# `jax._src.lax.linalg._cholesky_cpu_lowering`: JAX's own CPU lowering of
# Cholesky (a LAPACK call), which `cpu_linalg.enable(enabled=False)` puts
# back.
lapack_cholesky_cpu_lowering = _linalg._cholesky_cpu_lowering


def wait_for_processes(barrier: str, timeout_s: float) -> None:
  """Blocks until every `jax.distributed` process reaches `barrier`.

  The coordination service's barrier (`jax._src.distributed`'s client),
  with a timeout of our choosing: the public `multihost_utils` barrier is a
  collective, which JAX's CPU collectives (Gloo) give up on when another
  process is more than 30 s late, e.g. still compiling. A single process
  returns at once.
  """
  # pylint: disable=g-import-not-at-top
  from jax._src import distributed as _distributed

  # pylint: enable=g-import-not-at-top
  client = _distributed.global_state.client
  if client is None:
    return
  client.wait_at_barrier(barrier, int(timeout_s * 1000))


def install_device_put_replicated(function) -> None:
  """Sets `jax.device_put_replicated`, which JAX 0.10 removed, to `function`.

  Brax 0.14 replicates its training state with it (`adapters.brax`
  installs JAX's documented replacement where it is missing).
  """
  import jax  # pylint: disable=g-import-not-at-top

  jax.device_put_replicated = function


def register_cpu_lowering(primitive, rule) -> None:
  """`jax._src.interpreters.mlir.register_lowering(..., platform='cpu')`.

  Makes `rule` the CPU lowering of `primitive` for programs lowered from
  now on (`cpu_linalg`).
  """
  _mlir.register_lowering(primitive, rule, platform='cpu')


def shardy_partitioner_state():
  """JAX's `jax_use_shardy_partitioner` state, or None where it is gone.

  `jax._src.config.use_shardy_partitioner`: a context manager that selects
  Shardy (True) or GSPMD (False) for what is traced and compiled inside it.
  `jax.config.update` sets it for the whole process; `partitioner.scope`
  needs it for one block only, which only the private object offers. None
  on a JAX without the setting (GSPMD removed).
  """
  if _jax_config is None:
    return None
  return getattr(_jax_config, 'use_shardy_partitioner', None)


# `jax._src.interpreters.partial_eval.dce_jaxpr`, or None on a JAX without
# it: dead-code elimination of a jaxpr given which outputs are used, what
# `runtime.data_reads` uses to tell which `mjx.Data` fields a traced function
# reads (without it, every field counts as read).
dce_jaxpr: Callable[..., Any] | None = getattr(_partial_eval, 'dce_jaxpr', None)

# `jax._src.interpreters.partial_eval.partial_eval_jaxpr_nounits`, or None on
# a JAX without it: a jaxpr split by data dependence on some of its inputs
# into the part computable without them and the rest (and the intermediate
# values the rest needs, its residuals), what `runtime.stored_restart` uses
# to tell which leaves of a reset depend on its key (without it, every
# restart runs the reset).
partial_eval_jaxpr_nounits: Callable[..., Any] | None = getattr(
    _partial_eval, 'partial_eval_jaxpr_nounits', None
)
