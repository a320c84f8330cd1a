"""The task registry: bundled tasks by name, and tasks users add."""

import importlib
import subprocess
import sys
import textwrap
import warnings

import pytest

import mjx_composer as composer
from mjx_composer.suite.tasks import registry
from tests import conftest


@pytest.fixture
def scratch_names():
  """Names registered by a test, unregistered after it."""
  added = []
  yield added
  for name in added:
    if name in registry.names():
      registry.unregister(name)


def test_bundled_tasks_are_registered_without_importing_them():
  assert registry.names()[:5] == (
      'reach',
      'push',
      'walk',
      'joystick',
      'joystick_rough',
  )
  for name in registry.names():
    assert registry.describe(name)
  # Listing and describing built nothing: a fresh interpreter that imports
  # the registry has imported no task module.
  code = (
      'import sys; from mjx_composer.suite.tasks import registry; '
      'registry.names(); '
      'print(sorted(m for m in sys.modules '
      "if m.startswith('mjx_composer.suite.tasks.')))"
  )
  out = subprocess.run(
      [sys.executable, '-c', code], capture_output=True, text=True, check=True
  ).stdout
  assert out.strip().splitlines()[-1] == "['mjx_composer.suite.tasks.registry']"


def test_register_as_decorator_and_as_call(scratch_names):
  @registry.register('test_swing', description='A pendulum swings.')
  def make_swing():
    return conftest.SwingTask()

  scratch_names.append('test_swing')

  def make_swing_high():
    """A pendulum swings high.

    More text that the listing leaves out.
    """
    return conftest.SwingTask(terminate_above=0.0)

  assert (
      registry.register('test_swing_high', make_swing_high) is make_swing_high
  )
  scratch_names.append('test_swing_high')

  assert registry.names()[-2:] == ('test_swing', 'test_swing_high')
  assert registry.describe('test_swing') == 'A pendulum swings.'
  assert registry.describe('test_swing_high') == 'A pendulum swings high.'
  assert isinstance(registry.make_task('test_swing_high'), conftest.SwingTask)
  options = composer.ExecutionOptions(auto_reset='same_step')
  with warnings.catch_warnings():
    warnings.simplefilter('error', DeprecationWarning)
    env = registry.make_environment(
        'test_swing', time_limit=0.05, options=options
    )
  assert isinstance(env.task, conftest.SwingTask)
  assert env.time_limit == 0.05
  assert env.auto_reset == 'same_step'


def test_unknown_name_lists_the_registered_ones():
  with pytest.raises(
      registry.UnknownTaskError, match="Unknown task 'nope'.*reach, push"
  ):
    registry.make_environment('nope')
  with pytest.raises(KeyError, match='registered tasks'):
    registry.describe('nope')
  with pytest.raises(KeyError, match='registered tasks'):
    registry.unregister('nope')


def test_a_name_registers_once(scratch_names):
  with pytest.raises(ValueError, match="'reach' is already registered"):
    registry.register('reach', conftest.SwingTask)
  registry.register('test_once', conftest.SwingTask)
  scratch_names.append('test_once')
  with pytest.raises(ValueError, match='already registered'):

    @registry.register('test_once')
    def _():
      return conftest.SwingTask()

  registry.unregister('test_once')
  registry.register('test_once', conftest.SwingTask)  # again, once removed


@pytest.mark.parametrize('name', ['', 'two words', None])
def test_bad_names_and_factories_are_refused(name):
  with pytest.raises(ValueError, match='non-empty string without whitespace'):
    registry.register(name, conftest.SwingTask)


@pytest.mark.parametrize(
    'fact, value, message',
    [
        ('kwargs', [('terminate_above', 0.5)], 'kwargs must be a mapping'),
        ('kwargs', {1: 0.5}, 'kwargs must be a mapping with string keys'),
        ('training', 'num_envs=4', 'training must be a mapping'),
        ('metrics', {'distance': 3}, 'values of metrics must be strs'),
        ('metrics', ['distance'], 'metrics must be a mapping'),
        ('camera', 3, 'camera must be the name of a camera'),
        ('camera', '', 'camera must be the name of a camera'),
        ('description', 'two\nlines', 'description must be one line'),
    ],
)
def test_bad_facts_are_refused_when_registered(fact, value, message):
  with pytest.raises(TypeError, match=message):
    registry.register('test_bad_fact', conftest.SwingTask, **{fact: value})
  assert 'test_bad_fact' not in registry.names()


def test_a_factory_must_make_a_task(scratch_names):
  with pytest.raises(TypeError, match='callable'):
    registry.register('test_not_callable', 42)
  assert 'test_not_callable' not in registry.names()
  registry.register('test_not_a_task', lambda: 'a task?')
  scratch_names.append('test_not_a_task')
  with pytest.raises(TypeError, match='not a Task'):
    registry.make_task('test_not_a_task')


def test_the_factory_gets_the_registered_kwargs_and_overrides(scratch_names):
  registry.register(
      'test_swing_kwargs',
      conftest.SwingTask,
      kwargs={'terminate_above': 0.5},
      training={'time_limit': 2.0},
      camera='pendulum/side',
      metrics={'tip_height': 'the tip height (m)'},
  )
  scratch_names.append('test_swing_kwargs')
  assert registry.make_task('test_swing_kwargs').terminate_above == 0.5
  task = registry.make_task('test_swing_kwargs', terminate_above=0.7)
  assert task.terminate_above == 0.7
  entry = registry.entry('test_swing_kwargs')
  assert entry.kwargs == {'terminate_above': 0.5}  # the override is not kept
  assert entry.training == {'time_limit': 2.0}
  assert entry.camera == 'pendulum/side'
  assert entry.metrics == {'tip_height': 'the tip height (m)'}


def test_bundled_entries_hold_their_facts():
  """Each bundled task's facts, against their sources: the task modules'
  episode lengths and constructors, the metrics their `get_metrics` report,
  and the cameras of their compiled models (checked in
  tests/training/test_every_task.py)."""
  # pylint: disable=g-import-not-at-top
  from mjx_composer.suite.tasks import joystick
  from mjx_composer.suite.tasks import walk

  # pylint: enable=g-import-not-at-top
  episode = {'walk': walk.EPISODE_SECONDS, 'joystick': joystick.EPISODE_SECONDS}
  for name in registry.names():
    entry = registry.entry(name)
    assert entry.description and entry.metrics, name
    family = name.partition('_')[0]
    if family == 'walk':
      assert entry.training['time_limit'] == episode['walk']
      assert entry.training['discounting'] == 0.995  # Playground's HumanoidWalk
      assert entry.camera == 'humanoid/side'
    elif family == 'joystick':
      assert entry.training['time_limit'] == episode['joystick']
      assert entry.training['critic_obs'] == 'critic'
      assert entry.camera == 'go1/tracking'
    else:  # the arm tasks: TrainConfig's defaults, a free camera
      assert entry.training == {} and entry.camera is None
  assert registry.entry('joystick').kwargs == {'terrain': 'flat'}
  assert registry.entry('joystick_rough').kwargs == {'terrain': 'rough'}
  classes = {
      'reach': 'reach.Reach',
      'push': 'push.Push',
      'walk': 'walk.Walk',
      'joystick': 'joystick.Joystick',
      'joystick_rough': 'joystick.Joystick',
      'joystick_terrain': 'joystick_terrain.TerrainJoystick',
      'walk_terrain': 'walk_terrain.TerrainWalk',
  }
  assert set(classes) == set(registry.names())
  for name, path in classes.items():
    module, cls = path.split('.')
    module = importlib.import_module(f'mjx_composer.suite.tasks.{module}')
    assert type(registry.make_task(name)) is getattr(module, cls), name


@pytest.fixture
def user_module(tmp_path, monkeypatch):
  """`write(name, source)`: a module on `sys.path`, forgotten after the test."""
  monkeypatch.syspath_prepend(str(tmp_path))
  written = []

  def write(name, source):
    (tmp_path / f'{name}.py').write_text(textwrap.dedent(source))
    written.append(name)

  yield write
  for name in written:
    sys.modules.pop(name, None)


_REGISTERS_SWING = """
from mjx_composer.suite.tasks import registry
from tests import conftest

registry.register('{name}', conftest.SwingTask, description='{name}')
"""


def test_import_modules_registers_their_tasks(user_module, scratch_names):
  user_module('test_user_tasks', _REGISTERS_SWING.format(name='test_imported'))
  scratch_names.append('test_imported')
  registry.import_modules(['test_user_tasks'])
  assert registry.describe('test_imported') == 'test_imported'
  registry.import_modules(['test_user_tasks'])  # imported once, not again
  with pytest.raises(TypeError, match=r"pass \['test_user_tasks'\]"):
    registry.import_modules('test_user_tasks')


def test_import_failures_are_one_line_naming_the_module(user_module):
  user_module('test_user_tasks_broken', 'import no_such_dependency_at_all\n')
  with pytest.raises(registry.TaskModuleError) as error:
    registry.import_modules(['test_user_tasks_broken'])
  assert str(error.value) == (
      "Could not import the task module 'test_user_tasks_broken' (--import): "
      "ModuleNotFoundError: No module named 'no_such_dependency_at_all'"
  )
  user_module('test_user_tasks_syntax', 'def (:\n')
  with pytest.raises(registry.TaskModuleError, match='SyntaxError') as error:
    registry.import_modules(['test_user_tasks_syntax'])
  assert '\n' not in str(error.value)


def _install_plugin(folder, module, value=None):
  """A distribution in `folder` declaring `module` in the tasks' group."""
  dist = folder / 'test_mjx_tasks_plugin-0.1.dist-info'
  dist.mkdir()
  (dist / 'METADATA').write_text(
      'Metadata-Version: 2.1\nName: test-mjx-tasks-plugin\nVersion: 0.1\n'
  )
  (dist / 'entry_points.txt').write_text(
      f'[{registry.ENTRY_POINT_GROUP}]\nplugin = {value or module}\n'
  )
  importlib.invalidate_caches()


def test_entry_points_are_imported_on_the_first_lookup(
    user_module, tmp_path, monkeypatch, scratch_names
):
  user_module('test_plugin_tasks', _REGISTERS_SWING.format(name='test_plugin'))
  scratch_names.append('test_plugin')
  _install_plugin(tmp_path, 'test_plugin_tasks')
  monkeypatch.setattr(registry, '_entry_points_loaded', False)  # a new process
  registry.register('test_before_lookup', conftest.SwingTask)
  scratch_names.append('test_before_lookup')
  assert 'test_plugin_tasks' not in sys.modules  # registering is no lookup
  assert registry.names()[-2:] == ('test_before_lookup', 'test_plugin')
  assert 'test_plugin_tasks' in sys.modules
  assert registry.describe('test_plugin') == 'test_plugin'


def test_a_broken_entry_point_is_named_at_every_lookup(
    user_module, tmp_path, monkeypatch
):
  del user_module
  _install_plugin(tmp_path, 'test_plugin_gone', 'test_plugin_gone:register')
  monkeypatch.setattr(registry, '_entry_points_loaded', False)
  for lookup in (registry.names, lambda: registry.entry('reach')):
    with pytest.raises(
        registry.TaskModuleError,
        match=r"task module 'test_plugin_gone' \(entry point 'plugin' of "
        r"test-mjx-tasks-plugin in the group 'mjx_composer.tasks'; fix or "
        r'uninstall it\): ModuleNotFoundError',
    ):
      lookup()
