"""JAX's persistent compilation cache.

A composed environment's reset and step programs take seconds (GPU) to
minutes (CPU) to compile, and every new Python process compiles them again.
JAX can keep compiled programs on disk and load them when the same program
(same JAX, jaxlib, backend, device, flags and program text) is compiled again.
`enable()` turns that on; `platform.configure()` calls it, as the command
line (`mjx-composer demo`), the examples, the benchmarks, the notebooks and
the test suite do, first thing:

    from mjx_composer import platform
    platform.configure()

Where: `$MJX_COMPOSER_CACHE_DIR` if set, else
`$XDG_CACHE_HOME/mjx_composer/jax` (`~/.cache/mjx_composer/jax` when
`XDG_CACHE_HOME` is unset). Nothing evicts entries: delete the folder to
reclaim the space.

Off: `MJX_COMPOSER_COMPILATION_CACHE=0` in the environment,
`enable(enabled=False)`, or `mjx-composer demo --no-compilation-cache`.
JAX's own settings win: if a cache folder is already configured
(`JAX_COMPILATION_CACHE_DIR`, `jax.config.update('jax_compilation_cache_dir',
...)`) or JAX's cache is disabled (`JAX_ENABLE_COMPILATION_CACHE=false`),
`enable()` changes nothing.

The same folder keeps the answers of the analyses that trace MJX's forward
pass, in a subfolder (`answer_cache`).

A library import never calls `enable()`: importing `mjx_composer` leaves the
JAX configuration as it is.

JAX trusts what it loads from the cache folder: an entry is a compiled
program that runs as you. `enable()` creates the folder with mode 0700, and
refuses (with a warning, leaving the cache off) an existing folder that
another user owns or that its group or others can write.

An entry that fails to load (a file truncated by a process killed while
writing it, a full disk) is removed, with a warning, and written afresh by
the compilation that follows: JAX itself keeps such an entry, and would
read it and compile again in every process.

Each entry also names the key it was written under (its file name is the
key, but JAX would load whatever a file of that name holds). An entry that
names another key (files renamed, copied between keys or swapped) or none
(written by JAX without this package, or cut short) is removed, with a
warning, and compiled afresh: loaded as it is, it would run another
program, failing inside JAX's call machinery where the number of outputs
differs, or silently returning the other program's results where the
shapes agree.
"""

import os
import stat
import warnings

import jax

from mjx_composer.platform import internals_jax

# Environment variables.
CACHE_DIR_ENV = 'MJX_COMPOSER_CACHE_DIR'
SWITCH_ENV = 'MJX_COMPOSER_COMPILATION_CACHE'

# Programs that compile faster than this are not written to the cache (JAX's
# default is 1 s); below it, disk writes would cost about what they save.
MIN_COMPILE_TIME_SECS = 0.1

_OFF_VALUES = ('0', 'false', 'no', 'off')


def default_cache_dir() -> str:
  """`$MJX_COMPOSER_CACHE_DIR`, else the per-user cache folder."""
  path = os.environ.get(CACHE_DIR_ENV)
  if path:
    return os.path.abspath(os.path.expanduser(path))
  base = os.environ.get('XDG_CACHE_HOME') or os.path.join(
      os.path.expanduser('~'), '.cache'
  )
  return os.path.join(base, 'mjx_composer', 'jax')


def switched_off_by_environment() -> bool:
  """Whether `MJX_COMPOSER_COMPILATION_CACHE` turns the cache off."""
  value = os.environ.get(SWITCH_ENV, '').strip().lower()
  return value in _OFF_VALUES


def enable(
    cache_dir: str | None = None,
    *,
    enabled: bool | None = None,
    min_compile_time_secs: float = MIN_COMPILE_TIME_SECS,
) -> str | None:
  """Turns on JAX's persistent compilation cache, unless told otherwise.

  Call it before the first compilation you want cached (usually at the top
  of `main`); programs compiled before it are not written to the cache.

  Args:
    cache_dir: the folder; default: `default_cache_dir()`.
    enabled: True or False to decide here; None (the default): on unless
      `MJX_COMPOSER_COMPILATION_CACHE` is 0, false, no or off.
    min_compile_time_secs: programs compiling faster are not cached.

  Returns:
    The cache folder JAX uses after the call (possibly one configured before
    it, which is kept), or None if the persistent cache is off.
  """
  configured = jax.config.jax_compilation_cache_dir
  if not jax.config.jax_enable_compilation_cache:
    return None  # switched off in JAX itself: leave it off
  if configured:
    return configured  # the user's own cache settings win
  if enabled is None:
    enabled = not switched_off_by_environment()
  if not enabled:
    return None
  path = cache_dir or default_cache_dir()
  try:
    os.makedirs(path, mode=0o700, exist_ok=True)
  except OSError as e:
    warnings.warn(f'No persistent compilation cache: cannot create {path}: {e}')
    return None
  if not os.access(path, os.W_OK | os.X_OK):
    warnings.warn(f'No persistent compilation cache: {path} is not writable.')
    return None
  unsafe = unsafe_folder_reason(path)
  if unsafe:
    warnings.warn(
        f'No persistent compilation cache: {path} {unsafe}, and JAX runs '
        'whatever a cache entry holds. Make it private (chmod 700 '
        f'{path}, owned by you) or choose another folder '
        f'(${CACHE_DIR_ENV}, or enable(cache_dir=...)).'
    )
    return None
  internals_jax.remove_unreadable_cache_entries(_warn_removed)
  internals_jax.bind_cache_entries_to_keys(_warn_misfiled)
  jax.config.update('jax_compilation_cache_dir', path)
  jax.config.update(
      'jax_persistent_cache_min_compile_time_secs', min_compile_time_secs
  )
  # -1: no minimum entry size, and no backend-chosen override of it.
  jax.config.update('jax_persistent_cache_min_entry_size_bytes', -1)
  return path


def unsafe_folder_reason(path: str) -> str | None:
  """Why others could plant programs in `path`, or None if they cannot.

  A folder is unsafe when another user owns it, or when its group or
  everyone may write to it (even with the sticky bit: a newcomer could
  still create entries that do not exist yet).
  """
  info = os.stat(path)
  getuid = getattr(os, 'getuid', None)
  if getuid is not None and info.st_uid != getuid():
    return f'belongs to another user (uid {info.st_uid})'
  writable = info.st_mode & (stat.S_IWGRP | stat.S_IWOTH)
  if writable:
    who = 'everyone' if info.st_mode & stat.S_IWOTH else 'its group'
    return f'can be written by {who} (mode {stat.S_IMODE(info.st_mode):o})'
  return None


def _warn_removed(entry: str) -> None:
  warnings.warn(
      f'Removed the unreadable compilation cache entry {entry}: the program '
      'compiles again and is written afresh.'
  )


def _warn_misfiled(entry: str, holds: str | None) -> None:
  if holds is None:
    what = (
        'holds no key: it was written without this package (by JAX alone) '
        'or cut short'
    )
  else:
    what = (
        f'holds the program of key {holds!r} (entries renamed, copied or '
        'swapped)'
    )
  warnings.warn(
      f'Removed the compilation cache entry {entry}: it {what}, and loading '
      'it would run another program. The program compiles again and is '
      'written afresh; delete the cache folder to drop every entry.'
  )


def is_enabled() -> bool:
  """Whether JAX will read and write a persistent compilation cache."""
  return bool(
      jax.config.jax_compilation_cache_dir
      and jax.config.jax_enable_compilation_cache
  )
