"""MJX imported quietly and completed, by whichever import comes first.

Importing `mujoco.mjx` takes seconds: MJX imports its MuJoCo Warp backend
and declares Warp's kernels. `import mjx_composer` does not import it (the
package's names import on first use), so a program that only configures
JAX (`mjx_composer.platform.configure`) or reads the version starts in
about a second. Whenever MJX is then imported, by this package or by the
user's own code, `install`'s finder runs that import:

* quietly: MJX probes its optional Warp backend and prints "Failed to
  import warp: ..." and "Failed to import mujoco_warp: ..." to stdout where
  it is absent; those lines go to this package's logger at DEBUG level and
  any other output passes through. Asking MJX for the Warp backend
  (`impl='warp'`) still raises MJX's own error;
* then completes it (`complete`): MJX's missing ray-geom functions
  (`internals.add_missing_ray_functions`) and the errors that say what to
  use where a dm_control idiom meets MJX's classes
  (`internals.explain_dm_control_idioms`).

Where MJX was imported before `mjx_composer`, `install` completes it at
once (its output, if any, was printed then).
"""

from __future__ import annotations

import contextlib
import importlib.abc
import io
import logging
import sys

MJX = 'mujoco.mjx'
# The lines MJX prints when its optional Warp backend cannot be imported.
WARP_PROBE_LINES = ('Failed to import warp:', 'Failed to import mujoco_warp:')

_LOG = logging.getLogger('mjx_composer')


def install() -> None:
  """Completes MJX now if it is imported, else when it first is."""
  if MJX in sys.modules:
    complete()
  elif not any(isinstance(f, _MjxFinder) for f in sys.meta_path):
    sys.meta_path.insert(0, _MjxFinder())


def complete() -> None:
  """What this package adds to MJX (idempotent)."""
  # pylint: disable=g-import-not-at-top
  from mjx_composer.platform import internals

  internals.add_missing_ray_functions()
  internals.explain_dm_control_idioms()


class _MjxFinder(importlib.abc.MetaPathFinder):
  """Finds `mujoco.mjx` with the finders after it and wraps its loader.

  It answers once: the import it serves takes it off `sys.meta_path`.
  """

  def find_spec(self, fullname, path, target=None):
    if fullname != MJX:
      return None
    if self in sys.meta_path:
      sys.meta_path.remove(self)
    for finder in sys.meta_path:
      find_spec = getattr(finder, 'find_spec', None)
      spec = find_spec(fullname, path, target) if find_spec else None
      if spec is not None:
        break
    else:
      return None
    if spec.loader is not None:
      spec.loader = _QuietCompletingLoader(spec.loader)
    return spec


class _QuietCompletingLoader(importlib.abc.Loader):
  """Runs the module with MJX's Warp probe's lines logged, then `complete`.

  Anything else (resources, source) is the wrapped loader's.
  """

  def __init__(self, loader):
    self._loader = loader

  def create_module(self, spec):
    return self._loader.create_module(spec)

  def exec_module(self, module):
    captured = io.StringIO()
    try:
      with contextlib.redirect_stdout(captured):
        self._loader.exec_module(module)
    finally:
      for line in captured.getvalue().splitlines(keepends=True):
        if line.startswith(WARP_PROBE_LINES):
          _LOG.debug('MJX Warp backend unavailable: %s', line.rstrip())
        else:
          sys.stdout.write(line)
    complete()

  def __getattr__(self, name):
    if name == '_loader':  # not set yet (a copy being made)
      raise AttributeError(name)
    return getattr(self._loader, name)
