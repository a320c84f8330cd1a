"""Training settings refuse what no run would use."""

import re

import pytest

from mjx_composer.suite.tasks import registry
from mjx_composer.training import config
from tests import conftest


def test_training_defaults_are_a_tasks_registered_ones():
  registry.register(
      'balance', conftest.SwingTask, training={'num_envs': 64, 'seed': 3}
  )
  try:
    want = config.TrainConfig(task='balance', num_envs=64, seed=3)
    assert config.defaults('balance') == want
  finally:
    registry.unregister('balance')


@pytest.mark.parametrize(
    'training, message',
    [
        ({'num_env': 64}, r"unknown setting\(s\) \['num_env'\]"),
        ({'normalize': 1}, 'normalize must be true or false, got 1'),
        ({'num_envs': 0}, 'num_envs must be a positive integer, got 0'),
        ({'task': 'reach'}, 'leave out task and imports'),
    ],
)
def test_bad_training_defaults_name_the_task_and_the_setting(training, message):
  """Found when a run reads them, in one line naming the task."""
  registry.register('balance', conftest.SwingTask, training=training)
  try:
    with pytest.raises(ValueError) as error:
      config.defaults('balance')
  finally:
    registry.unregister('balance')
  text = str(error.value)
  assert text.startswith("The training defaults of task 'balance'"), text
  assert re.search(message, text) and '\n' not in text, text


def test_defaults_of_an_unknown_task_are_refused():
  with pytest.raises(registry.UnknownTaskError, match="Unknown task 'Walk'"):
    config.defaults('Walk')
