"""mjx_composer: dm_control composer's authoring model on MJX.

`import mjx_composer as composer` gives composer's public names: build
entities on MjSpec, compose them under a task, and get pure, batched
`reset(key)` / `step(state, action)` functions from `Environment`.
"""

import importlib
import importlib.metadata
import importlib.util
import typing

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


# The package's public names (composer's) and the modules that define
# them. They import on first use (`__getattr__`): importing MJX and the
# package's modules takes seconds, which a program that only configures JAX
# (`platform.configure`) or reads `__version__` need not wait for.
_PUBLIC_NAMES = {
    'Arena': 'mjx_composer.arena',
    'SENSOR_SITES_GROUP': 'mjx_composer.constants',
    'cached_property': 'mjx_composer.define',
    'observable': 'mjx_composer.define',
    'Entity': 'mjx_composer.entity',
    'ModelWrapperEntity': 'mjx_composer.entity',
    'EpisodeInitializationError': 'mjx_composer.environment',
    'Environment': 'mjx_composer.environment',
    'ExecutionOptions': 'mjx_composer.environment',
    'HOOK_NAMES': 'mjx_composer.environment',
    'State': 'mjx_composer.environment',
    'StepType': 'mjx_composer.environment',
    'HostEnvironment': 'mjx_composer.host.host_environment',
    'Initializer': 'mjx_composer.initializer',
    'FreePropObservableMixin': 'mjx_composer.observation',
    'ObservationGroup': 'mjx_composer.observation',
    'ObservationPadding': 'mjx_composer.observation',
    'Observables': 'mjx_composer.observation',
    'Physics': 'mjx_composer.physics',
    'Robot': 'mjx_composer.robot',
    'NullTask': 'mjx_composer.task',
    'Task': 'mjx_composer.task',
}

if typing.TYPE_CHECKING:  # the same names, for static tools (and the docs)
  # pylint: disable=g-import-not-at-top,unused-import
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
  from mjx_composer.observation import FreePropObservableMixin
  from mjx_composer.observation import ObservationGroup
  from mjx_composer.observation import ObservationPadding
  from mjx_composer.observation import Observables
  from mjx_composer.physics import Physics
  from mjx_composer.robot import Robot
  from mjx_composer.task import NullTask
  from mjx_composer.task import Task

__all__ = sorted(_PUBLIC_NAMES)


def __getattr__(name: str):
  """A public name (`_PUBLIC_NAMES`) or a subpackage, imported on first use."""
  if name in _PUBLIC_NAMES:
    value = getattr(importlib.import_module(_PUBLIC_NAMES[name]), name)
  elif not name.startswith('__') and importlib.util.find_spec(
      f'{__name__}.{name}'
  ):
    value = importlib.import_module(f'{__name__}.{name}')
  else:
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
  globals()[name] = value
  return value


def __dir__():
  return sorted(set(globals()) | set(_PUBLIC_NAMES))


__version__ = _version()

# pylint: disable=g-import-not-at-top,wrong-import-position
# Cholesky without jaxlib's LAPACK kernel on the CPU, which can deadlock;
# MJX, when it is imported, quietly and with what this package adds to it.
from mjx_composer import platform

platform.safe_defaults()

# The bundled content's old paths (`mjx_composer.entities`, `.tasks` and
# `.locomotion`, now in `mjx_composer.suite`), for this release.
from mjx_composer.suite import old_paths

old_paths.install()
