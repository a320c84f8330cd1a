"""The task registry: bundled tasks by name, and tasks users add."""

import subprocess
import sys
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
  with pytest.raises(KeyError, match="Unknown task 'nope'.*reach, push"):
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


def test_a_factory_must_make_a_task(scratch_names):
  with pytest.raises(TypeError, match='callable'):
    registry.register('test_not_callable', 42)
  assert 'test_not_callable' not in registry.names()
  registry.register('test_not_a_task', lambda: 'a task?')
  scratch_names.append('test_not_a_task')
  with pytest.raises(TypeError, match='not a Task'):
    registry.make_task('test_not_a_task')
