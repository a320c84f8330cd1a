"""The content's old import paths, kept for one release with a warning.

The bundled robots, props, arenas, tasks and the locomotion kit moved from
`mjx_composer.entities`, `mjx_composer.tasks` and `mjx_composer.locomotion`
into `mjx_composer.suite`. `install()` (run by `import mjx_composer`) puts
a finder first on `sys.meta_path` that answers an old path with the module
at the new one, the same module object, and warns once per old path with a
`DeprecationWarning` naming the new path:

    import mjx_composer.entities.go1    # is mjx_composer.suite.entities.go1
    from mjx_composer.tasks import walk  # is mjx_composer.suite.tasks.walk

`mjx_composer.tasks.locomotion` was dissolved: its names resolve to their
new homes (`MOVED_NAMES`) through a module of its own, made here.
"""

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
import types
import warnings

# Old package -> new package; their submodules follow.
MOVED_PACKAGES = {
    'mjx_composer.entities': 'mjx_composer.suite.entities',
    'mjx_composer.tasks': 'mjx_composer.suite.tasks',
    'mjx_composer.locomotion': 'mjx_composer.suite.locomotion',
}
# Old modules whose new home is not where their package's move puts them.
MOVED_MODULES = {
    'mjx_composer.tasks.terrain_part': (
        'mjx_composer.suite.locomotion.terrain.terrain_part'
    ),
    'mjx_composer.locomotion.sub_terrains': (
        'mjx_composer.suite.locomotion.terrain.sub_terrains'
    ),
}
# `mjx_composer.tasks.locomotion`'s names -> the modules now holding them.
DISSOLVED = 'mjx_composer.tasks.locomotion'
MOVED_NAMES = {
    'tolerance': 'mjx_composer.utils.rewards',
    'yaw_quaternion': 'mjx_composer.utils.transformations',
    'uniform_noise': 'mjx_composer.suite.locomotion.policy_critic',
    'policy_observable': 'mjx_composer.suite.locomotion.policy_critic',
    'clean_twin': 'mjx_composer.suite.locomotion.policy_critic',
    'split_policy_and_critic': 'mjx_composer.suite.locomotion.policy_critic',
    'Pushes': 'mjx_composer.suite.locomotion.pushes',
}


def _by_package(old):
  """Where the move of `old`'s package puts it (None: no moved package)."""
  for package, moved in MOVED_PACKAGES.items():
    if old == package or old.startswith(package + '.'):
      return moved + old[len(package) :]
  return None


# `from mjx_composer.tasks import terrain_part` imports the module through
# the package's new name (`mjx_composer.suite.tasks.terrain_part`): each
# name a moved or dissolved module is asked for -> its old path.
_ASKED_AS = {
    **{old: old for old in [*MOVED_MODULES, DISSOLVED]},
    **{_by_package(old): old for old in [*MOVED_MODULES, DISSOLVED]},
}


def new_path(name):
  """The module now at the old path `name` (None: `name` did not move)."""
  old = _ASKED_AS.get(name, name)
  if old in MOVED_MODULES:
    return MOVED_MODULES[old]
  if old == DISSOLVED:
    return None
  return _by_package(old)


def is_old_path(name):
  """Whether `name` is a path this module answers (moved or dissolved)."""
  return name in _ASKED_AS or new_path(name) is not None


def _dissolved_module():
  """`mjx_composer.tasks.locomotion`: its old names, from their new homes."""
  module = types.ModuleType(
      DISSOLVED,
      'Dissolved: each name lives in the module that '
      'mjx_composer.suite.old_paths.MOVED_NAMES gives.',
  )
  for name, home in MOVED_NAMES.items():
    setattr(module, name, getattr(importlib.import_module(home), name))
  module.__all__ = sorted(MOVED_NAMES)
  return module


class _Loader(importlib.abc.Loader):
  """Puts the new module in `sys.modules` under the old path."""

  def create_module(self, spec):
    return None  # A placeholder, replaced in exec_module.

  def exec_module(self, module):
    name = module.__name__
    old = _ASKED_AS.get(name, name)
    if old == DISSOLVED:
      homes = ', '.join(f'{n} from {m}' for n, m in MOVED_NAMES.items())
      warnings.warn(
          f'{old} was dissolved; import its names from their new homes: '
          f'{homes}.',
          DeprecationWarning,
          stacklevel=2,
      )
      found = _dissolved_module()
    else:
      new = new_path(name)
      warnings.warn(
          f'{old} moved to {new}; import it from there.',
          DeprecationWarning,
          stacklevel=2,
      )
      found = importlib.import_module(new)
    # The import system returns what `sys.modules` holds under the name
    # once this returns: the new module itself, not a copy. The other name
    # it may be asked by gets it too (one module, one warning).
    for asked, was in _ASKED_AS.items():
      if was == old:
        sys.modules[asked] = found
    sys.modules[name] = found


class _Finder(importlib.abc.MetaPathFinder):
  """Finds the old paths (and only those) first, before the path finder."""

  _loader = _Loader()

  def find_spec(self, fullname, path=None, target=None):
    del path, target
    if not is_old_path(fullname):
      return None
    new = new_path(fullname)
    if new is not None and importlib.util.find_spec(new) is None:
      return None  # No such module: the usual error, under the old name.
    return importlib.machinery.ModuleSpec(fullname, self._loader)


def install():
  """Answers the old paths from now on (idempotent)."""
  if not any(isinstance(f, _Finder) for f in sys.meta_path):
    sys.meta_path.insert(0, _Finder())
