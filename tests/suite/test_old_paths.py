"""The content's old import paths: the new modules, with a DeprecationWarning.

`mjx_composer.entities`, `.tasks` and `.locomotion` moved into
`mjx_composer.suite`; `suite/old_paths.py` answers the old paths for this
release. An old path gives the new module object itself (not a copy: one
module, one set of classes), warns once naming the new path, and the
dissolved `mjx_composer.tasks.locomotion` gives its names from their new
homes. The package itself uses the new paths only.
"""

import ast
import importlib
import pathlib
import sys
import warnings

import pytest

import mjx_composer
from mjx_composer.suite import old_paths

# Where the import system records an old path as an attribute: (parent
# module, attribute).
_ATTRIBUTES = (
    ('mjx_composer', 'entities'),
    ('mjx_composer', 'tasks'),
    ('mjx_composer', 'locomotion'),
    ('mjx_composer.suite.tasks', 'locomotion'),
    ('mjx_composer.suite.tasks', 'terrain_part'),
    ('mjx_composer.suite.locomotion', 'sub_terrains'),
)


@pytest.fixture(autouse=True)
def _forget_old_paths():
  """Each test imports the old paths afresh (the new modules stay)."""

  def forget():
    for name in list(sys.modules):
      if old_paths.is_old_path(name):
        del sys.modules[name]
    for parent, attribute in _ATTRIBUTES:
      if attribute in vars(sys.modules.get(parent, object)):
        delattr(sys.modules[parent], attribute)

  forget()
  yield
  forget()


def _import(name):
  with pytest.warns(DeprecationWarning) as caught:
    module = importlib.import_module(name)
  return module, [str(w.message) for w in caught]


@pytest.mark.parametrize(
    'old, new',
    [
        ('mjx_composer.entities', 'mjx_composer.suite.entities'),
        ('mjx_composer.entities.go1', 'mjx_composer.suite.entities.go1'),
        (
            'mjx_composer.entities.manipulators.base',
            'mjx_composer.suite.entities.manipulators.base',
        ),
        ('mjx_composer.tasks.walk', 'mjx_composer.suite.tasks.walk'),
        ('mjx_composer.tasks.registry', 'mjx_composer.suite.tasks.registry'),
        (
            'mjx_composer.locomotion.commands',
            'mjx_composer.suite.locomotion.commands',
        ),
        (
            'mjx_composer.locomotion.terrain.generator',
            'mjx_composer.suite.locomotion.terrain.generator',
        ),
        (
            'mjx_composer.tasks.terrain_part',
            'mjx_composer.suite.locomotion.terrain.terrain_part',
        ),
        (
            'mjx_composer.locomotion.sub_terrains',
            'mjx_composer.suite.locomotion.terrain.sub_terrains',
        ),
    ],
)
def test_an_old_path_is_the_new_module_and_warns(old, new):
  module, messages = _import(old)
  assert module is importlib.import_module(new)
  assert module.__name__ == new
  assert any(m.startswith(f'{old} moved to {new};') for m in messages)


def test_from_the_old_package_import_a_module():
  # pylint: disable=g-import-not-at-top
  with pytest.warns(DeprecationWarning, match='mjx_composer.suite.tasks'):
    from mjx_composer.tasks import walk
  with pytest.warns(DeprecationWarning, match='terrain.terrain_part'):
    from mjx_composer.tasks import terrain_part
  from mjx_composer.suite.locomotion.terrain import terrain_part as new_part
  from mjx_composer.suite.tasks import walk as new_walk

  assert walk is new_walk
  assert terrain_part is new_part


def test_an_old_path_warns_once():
  _import('mjx_composer.entities.props')
  with warnings.catch_warnings():
    warnings.simplefilter('error')
    again = importlib.import_module('mjx_composer.entities.props')
  assert again is importlib.import_module('mjx_composer.suite.entities.props')


def test_the_dissolved_module_gives_its_names_from_their_new_homes():
  # pylint: disable=g-import-not-at-top
  module, messages = _import('mjx_composer.tasks.locomotion')
  assert any('was dissolved' in m for m in messages)
  for name, home in old_paths.MOVED_NAMES.items():
    assert getattr(module, name) is getattr(importlib.import_module(home), name)
    assert home in messages[-1]
  with warnings.catch_warnings():
    warnings.simplefilter('error')
    from mjx_composer.tasks import locomotion
  assert locomotion is module


def test_a_missing_old_module_is_the_usual_error():
  _import('mjx_composer.tasks')
  with warnings.catch_warnings():
    warnings.simplefilter('error')
    with pytest.raises(ModuleNotFoundError, match='no_such_task'):
      importlib.import_module('mjx_composer.tasks.no_such_task')


def test_paths_that_did_not_move_are_left_alone():
  assert old_paths.new_path('mjx_composer.environment') is None
  assert old_paths.new_path('mjx_composer.suite.tasks.walk') is None
  assert old_paths.new_path('mjx_composer.tasksx') is None


def test_the_package_uses_the_new_paths_only():
  root = pathlib.Path(mjx_composer.__file__).resolve().parent
  found = []
  for path in sorted(root.rglob('*.py')):
    for node in ast.walk(ast.parse(path.read_text())):
      if isinstance(node, ast.ImportFrom) and not node.level:
        names = [f'{node.module}.{a.name}' for a in node.names]
      elif isinstance(node, ast.Import):
        names = [a.name for a in node.names]
      else:
        continue
      for name in names:
        if old_paths.is_old_path(name):
          found.append(f'{path.relative_to(root)}:{node.lineno}: {name}')
  assert not found, 'Old paths imported:\n' + '\n'.join(found)
