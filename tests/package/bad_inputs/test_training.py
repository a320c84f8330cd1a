"""Training settings refuse what no run would use."""

import pytest

from mjx_composer.suite.tasks import registry
from mjx_composer.training import config
from tests import conftest


@pytest.mark.parametrize('task', ['balance', 'Walk', None])
def test_register_defaults_refuses_a_task_that_is_not_registered(task):
  """An unknown name (a typo, a task not yet registered) was accepted."""
  with pytest.raises(
      ValueError,
      match=rf'register_defaults: `task` {task!r} is not a registered task.*'
      r'Register the task first \(mjx_composer.suite.tasks.registry.register\(.*'
      r'registered tasks: .*walk',
  ):
    config.register_defaults(task, num_envs=64)
  assert task not in config.TASK_DEFAULTS


def test_register_defaults_of_a_registered_task_are_its_defaults():
  registry.register('balance', conftest.SwingTask)
  try:
    config.register_defaults('balance', num_envs=64)
    assert config.defaults('balance').num_envs == 64
  finally:
    registry.unregister('balance')
    config.TASK_DEFAULTS.pop('balance', None)
