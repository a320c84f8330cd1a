"""`import mjx_composer` leaves MJX to first use, and MJX's import, whoever
makes it, is quiet and completed (`platform.mjx_import`).

What a process has imported is process-wide, so each check that starts from
a bare interpreter runs in a fresh Python process.
"""

import ast
import pathlib

import pytest

import mjx_composer as composer
from mjx_composer.platform import internals
from tests import conftest

# Imports the package (after MJX where asked), then reports which modules
# are loaded, at each point, and what MJX looks like once loaded, as JSON.
_SCRIPT = """
import json, sys

argument = json.loads(sys.argv[1])
report = {}
if argument == 'mjx_first':
  import mujoco.mjx
import mjx_composer
from mjx_composer.platform import compilation_cache
report['mjx_after_import'] = 'mujoco.mjx' in sys.modules
report['own_modules_after_import'] = sorted(
    m for m in sys.modules
    if m.startswith('mjx_composer.') and m.split('.')[1] != 'platform')
if argument == 'user_imports_mjx':
  import mujoco.mjx
else:
  mjx_composer.Environment
report['mjx_after_use'] = 'mujoco.mjx' in sys.modules

from mujoco import mjx
from mujoco.mjx._src import ray
report['cylinder_ray'] = ray.GeomType.CYLINDER in ray._RAY_FUNC
try:
  mjx.Contact.__getitem__(None, 0)
except TypeError as e:
  report['contact_indexing'] = str(e)
print(json.dumps(report))
"""

# MJX's Warp probe where Warp cannot be imported: what reaches stdout and
# what reaches the package's logger.
_NO_WARP_SCRIPT = """
import io, json, logging, sys

sys.modules['warp'] = None  # `import warp` raises ImportError
records = []
handler = logging.Handler(logging.DEBUG)
handler.emit = lambda record: records.append(record.getMessage())
logging.getLogger('mjx_composer').addHandler(handler)
logging.getLogger('mjx_composer').setLevel(logging.DEBUG)

import mjx_composer
stdout, sys.stdout = sys.stdout, io.StringIO()
try:
  import mujoco.mjx
  print('printed by the user')
finally:
  captured, sys.stdout = sys.stdout.getvalue(), stdout
print(json.dumps({'stdout': captured, 'log': records}))
"""


@pytest.mark.parametrize('first', ['package', 'mjx_first', 'user_imports_mjx'])
def test_mjx_is_imported_on_first_use_and_completed(tmp_path, first):
  report = conftest.run_script(_SCRIPT, first, tmp_path)
  assert report['mjx_after_import'] == (first == 'mjx_first')
  # Only the package itself and the bundled content's old-path finder.
  assert report['own_modules_after_import'] == [
      'mjx_composer.suite',
      'mjx_composer.suite.old_paths',
  ]
  assert report['mjx_after_use']
  assert report['cylinder_ray']
  assert report['contact_indexing'] == internals.CONTACT_INDEXING_MESSAGE


def test_the_warp_probe_goes_to_the_log_and_the_rest_to_stdout(tmp_path):
  report = conftest.run_script(_NO_WARP_SCRIPT, None, tmp_path)
  assert report['stdout'] == 'printed by the user\n'
  assert len(report['log']) == 2
  assert report['log'][0].startswith(
      'MJX Warp backend unavailable: Failed to import warp:'
  )
  assert report['log'][1].startswith(
      'MJX Warp backend unavailable: Failed to import mujoco_warp:'
  )


def test_public_names_are_the_modules_own():
  # pylint: disable=g-import-not-at-top
  from mjx_composer import environment
  from mjx_composer import observation

  assert composer.Environment is environment.Environment
  assert composer.Observables is observation.Observables
  assert composer.observation is observation
  assert set(composer.__all__) <= set(dir(composer))
  for name in composer.__all__:
    assert getattr(composer, name) is not None


def test_an_unknown_name_is_an_attribute_error_naming_it():
  with pytest.raises(AttributeError, match="no attribute 'Enviroment'"):
    composer.Enviroment  # pylint: disable=pointless-statement
  assert not hasattr(composer, '__wrapped__')


def test_static_tools_see_the_names_served():
  """The imports under `typing.TYPE_CHECKING` (what type checkers and the
  API reference read) are `_PUBLIC_NAMES`, name for name."""
  tree = ast.parse(pathlib.Path(composer.__file__).read_text())
  (block,) = [
      node
      for node in tree.body
      if isinstance(node, ast.If)
      and ast.unparse(node.test).endswith('TYPE_CHECKING')
  ]
  seen = {
      alias.name: node.module
      for node in block.body
      if isinstance(node, ast.ImportFrom)
      for alias in node.names
  }
  assert seen == composer._PUBLIC_NAMES  # pylint: disable=protected-access


_LIST_SCRIPT = """
import contextlib, io, json, sys
from mjx_composer import cli

with contextlib.redirect_stdout(io.StringIO()) as listed:
  cli.main(['list'])
print(json.dumps({
    'mjx': 'mujoco.mjx' in sys.modules, 'listed': listed.getvalue()}))
"""


def test_listing_the_tasks_imports_no_mjx(tmp_path):
  report = conftest.run_script(_LIST_SCRIPT, None, tmp_path)
  assert not report['mjx']
  assert report['listed'].splitlines()[0].startswith('reach ')
