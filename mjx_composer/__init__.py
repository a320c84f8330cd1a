"""mjx_composer: dm_control composer's authoring model on MJX.

`import mjx_composer as composer` gives composer's public names: build
entities on MjSpec, compose them under a task, and get pure, batched
`reset(key)` / `step(state, action)` functions from `Environment`.
"""

import importlib.metadata

# The distribution's name (pyproject.toml's `[project] name`).
_DISTRIBUTION = 'mjx-composer'
# The version of a checkout imported without being installed (on
# PYTHONPATH): it has no distribution metadata to read a version from.
_UNINSTALLED_VERSION = '0+unknown'


def _version() -> str:
  """The installed distribution's version: pyproject.toml's, read once.

  Installing the package (`pip install -e .` too) records pyproject.toml's
  `version` in its metadata, so the number is written in one place only. A
  checkout that is not installed reads '0+unknown', never a number that
  could be stale.
  """
  try:
    return importlib.metadata.version(_DISTRIBUTION)
  except importlib.metadata.PackageNotFoundError:
    return _UNINSTALLED_VERSION


def _import_mjx_quietly():
  """Imports `mujoco.mjx` without its Warp probe's output.

  On first import, MJX tries to import its optional Warp backend and prints
  "Failed to import warp: ..." and "Failed to import mujoco_warp: ..." to
  stdout when it is absent. Those two lines go to this package's logger at
  DEBUG level instead; any other output is passed through. Asking MJX for the
  Warp backend (`impl='warp'`) still raises MJX's own error.
  """
  # pylint: disable=g-import-not-at-top
  import contextlib
  import io
  import logging
  import sys

  if 'mujoco.mjx.warp' in sys.modules:
    return  # Already imported (and printed, if it did) before us.
  captured = io.StringIO()
  try:
    with contextlib.redirect_stdout(captured):
      import mujoco.mjx  # pylint: disable=unused-import
  finally:
    for line in captured.getvalue().splitlines(keepends=True):
      if line.startswith(
          ('Failed to import warp:', 'Failed to import mujoco_warp:')
      ):
        logging.getLogger(__name__).debug(
            'MJX Warp backend unavailable: %s', line.rstrip()
        )
      else:
        sys.stdout.write(line)


_import_mjx_quietly()

# pylint: disable=g-import-not-at-top,wrong-import-position
from mjx_composer.arena import Arena
from mjx_composer.constants import SENSOR_SITES_GROUP
from mjx_composer.define import cached_property
from mjx_composer.define import observable
from mjx_composer.entity import Entity
from mjx_composer.entity import ModelWrapperEntity
from mjx_composer.environment import EpisodeInitializationError
from mjx_composer.environment import Environment
from mjx_composer.environment import ExecutionOptions
from mjx_composer.environment import HOOK_NAMES
from mjx_composer.environment import State
from mjx_composer.environment import StepType
from mjx_composer.host.host_environment import HostEnvironment
from mjx_composer.initializer import Initializer
from mjx_composer import initializers
from mjx_composer import observation
from mjx_composer.observation import FreePropObservableMixin
from mjx_composer.observation import ObservationGroup
from mjx_composer.observation import ObservationPadding
from mjx_composer.observation import Observables
from mjx_composer.physics import Physics
from mjx_composer.robot import Robot
from mjx_composer.task import NullTask
from mjx_composer.task import Task

__version__ = _version()

# Cholesky without jaxlib's LAPACK kernel on the CPU, which can deadlock.
from mjx_composer import platform  # pylint: disable=g-bad-import-order

platform.safe_defaults()

# The bundled content's old paths (`mjx_composer.entities`, `.tasks` and
# `.locomotion`, now in `mjx_composer.suite`), for this release.
from mjx_composer.suite import old_paths  # pylint: disable=g-bad-import-order

old_paths.install()
