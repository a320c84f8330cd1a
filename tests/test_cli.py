"""The command line: `mjx-composer demo` runs end to end on the CPU, a user's
own task is a task of every command (`--import`), and errors are one line."""

import json
import os
import shutil
import sys

import pytest

import mjx_composer as composer
from mjx_composer import cli
from mjx_composer.suite.tasks import registry
from mjx_composer.training import checkpoints
from mjx_composer.training import export as export_lib
from mjx_composer.training import run_folder
from tests import conftest


def test_demo_runs_and_reports(capsys):
  assert (
      cli.main(
          [
              'demo',
              '--worlds',
              '3',
              '--steps',
              '6',
              '--chunk',
              '3',
              '--time-limit',
              '0.06',
          ]
      )
      == 0
  )
  out = capsys.readouterr().out
  assert 'physics steps/s' in out
  # 0.06 s episodes at 0.02 s per step: every world finishes 2 episodes.
  assert 'Episodes finished: 6;' in out
  # The metrics reach's registry entry names, one line each.
  (line,) = [l for l in out.splitlines() if l.split()[:1] == ['distance']]
  assert line.endswith(registry.entry('reach').metrics['distance'])
  assert 0.0 < float(line.split()[1]) < 2.0  # metres, within the arm's reach
  assert 'Diverged worlds: 0.' in out


def test_usage_without_command(capsys):
  assert cli.main([]) == 2
  out = capsys.readouterr().out
  assert 'usage' in out
  for command in ('demo', 'list', 'train', 'play', 'export'):
    assert f'mjx-composer {command}' in out
  play = out[out.index('mjx-composer play') : out.index('mjx-composer export')]
  assert '--no-video' in play and '--seed' in play


def test_train_help_lists_the_settings_with_the_tasks_defaults(capsys):
  with pytest.raises(SystemExit) as exit_info:
    cli.main(['train', 'walk', '--help'])
  assert exit_info.value.code == 0
  # The help is a box drawn to the terminal's width: read it as words.
  out = ' '.join(capsys.readouterr().out.replace('│', ' ').split())
  assert '--learning-rate' in out and '--policy-layers' in out
  assert '(default: 0.995)' in out  # walk's discount, not reach's 0.95
  # The flags that join a distributed run, parsed before the settings.
  for flag in ['--distributed', '--coordinator HOST:PORT']:
    assert flag in out
  assert '--num-processes N --process-id I' in out


def test_list_prints_every_registered_task_on_its_own_line(capsys):
  assert cli.main(['list']) == 0
  lines = capsys.readouterr().out.splitlines()
  assert [line.split()[0] for line in lines] == list(registry.names())
  assert set(registry.names()) >= {
      'reach',
      'push',
      'walk',
      'joystick',
      'joystick_rough',
  }
  reach_line = lines[registry.names().index('reach')]
  assert registry.describe('reach') in reach_line


def test_compilation_cache_flag():
  parser = cli.demo_parser()
  assert not parser.parse_args([]).no_compilation_cache
  assert parser.parse_args(['--no-compilation-cache']).no_compilation_cache


def test_demo_offers_every_registered_task(capsys):
  parser = cli.demo_parser()
  for name in registry.names():
    assert parser.parse_args(['--task', name]).task == name
  help_text = ' '.join(parser.format_help().split())
  assert ', '.join(registry.names()) in help_text
  assert cli.main(['demo', '--task', 'no_such_task']) == 2
  _assert_one_error_line(capsys, "Unknown task 'no_such_task'")


def test_impl_flag_reaches_the_environment(monkeypatch):
  parser = cli.demo_parser()
  assert parser.parse_args([]).impl is None
  assert parser.parse_args(['--impl', 'warp']).impl == 'warp'
  built = []

  def make_environment(name, time_limit, options):
    built.append((name, time_limit, options))
    raise RuntimeError('built')  # stop before compiling anything

  monkeypatch.setattr(registry, 'make_environment', make_environment)
  monkeypatch.setattr(composer.platform, 'configure', lambda **kwargs: None)
  with pytest.raises(RuntimeError, match='built'):
    cli.demo(['--impl', 'warp', '--task', 'push', '--no-compilation-cache'])
  assert built == [
      (
          'push',
          1.0,
          composer.ExecutionOptions(auto_reset='same_step', impl='warp'),
      )
  ]


def _assert_one_error_line(capsys, *parts):
  """The command printed one line, `error: ...` holding `parts`, on stderr."""
  err = capsys.readouterr().err
  assert err.startswith('error: ') and err.count('\n') == 1, err
  for part in parts:
    assert part in err, err
  return err


# -- a user's own task, from a module named by --import -------------------------

# A module a user writes: the tests' pendulum swing with the observation
# groups training reads, registered with its training defaults (tiny: four
# worlds, one update per evaluation, 5-step episodes).
_USER_MODULE = 'user_tasks_for_the_cli_test'
_USER_TASK = 'user_swing'
_USER_SOURCE = f"""
from mjx_composer.observation import groups
from mjx_composer.suite.tasks import registry
from tests import conftest


class UserSwing(conftest.SwingTask):
  def observation_groups(self):
    return {{
        'policy': groups.ObservationGroup(keys=['tip'], flatten=True),
        'critic': groups.ObservationGroup(
            keys=['tip'], corrupted=False, flatten=True),
    }}


registry.register(
    {_USER_TASK!r}, UserSwing, description='A user swings a pendulum.',
    training=dict(
        num_envs=4, batch_size=4, num_minibatches=2, unroll_length=5,
        num_updates_per_batch=1, num_evals=3, num_eval_envs=2,
        time_limit=0.05, policy_layers=[8], value_layers=[8]))
"""


def _forget_user_module():
  """As a new process: the module not imported, its task not registered."""
  sys.modules.pop(_USER_MODULE, None)
  if _USER_TASK in registry.names():
    registry.unregister(_USER_TASK)


@pytest.fixture(scope='module')
def user_module_dir(tmp_path_factory):
  """A folder holding the user's module, on `sys.path` for this module."""
  folder = tmp_path_factory.mktemp('user_code')
  (folder / f'{_USER_MODULE}.py').write_text(_USER_SOURCE)
  with pytest.MonkeyPatch.context() as patch:
    patch.syspath_prepend(str(folder))
    yield folder
  _forget_user_module()


@pytest.fixture(scope='module')
def user_run(user_module_dir, tmp_path_factory):
  """A run of the user's task, trained through `--import`, then forgotten."""
  del user_module_dir
  path = str(tmp_path_factory.mktemp('runs') / 'user')
  argv = ['train', _USER_TASK, '--import', _USER_MODULE, '--run-dir', path]
  assert cli.main(argv + ['--num-timesteps', '80']) == 0
  _forget_user_module()
  return path


def test_list_imports_the_users_module(user_module_dir, capsys):
  del user_module_dir
  _forget_user_module()
  assert cli.main(['list', '--import', _USER_MODULE]) == 0
  (line,) = [l for l in capsys.readouterr().out.splitlines() if _USER_TASK in l]
  assert line.split(maxsplit=1) == [_USER_TASK, 'A user swings a pendulum.']


def test_a_users_task_trains_plays_exports_and_resumes(user_run, capsys):
  """Each command imports the module the run recorded, in a fresh registry."""
  run = run_folder.RunFolder(user_run)
  config = run.read_config()
  assert config.imports == (_USER_MODULE,)
  with open(run.config_path) as f:
    assert json.load(f)['imports'] == [_USER_MODULE]
  # The task's registered training defaults, not TrainConfig's.
  assert (config.num_envs, config.policy_layers) == (4, (8,))
  assert config.time_limit == 0.05
  assert checkpoints.latest(run).step == 80
  capsys.readouterr()

  assert _USER_MODULE not in sys.modules
  argv = ['play', user_run, '--no-video', '--worlds', '2', '--steps', '6']
  assert cli.main(argv) == 0
  # 6 steps of 5-step episodes: each of the 2 worlds ends one episode.
  assert 'step 80: 2 episodes ended' in capsys.readouterr().out
  assert _USER_TASK in registry.names()

  _forget_user_module()
  out = os.path.join(os.path.dirname(user_run), 'user.onnx')
  assert cli.main(['export', user_run, '--out', out]) == 0
  assert export_lib.read_metadata(out)['task'] == _USER_TASK

  _forget_user_module()
  argv = ['train', '--resume', user_run, '--num-timesteps', '120']
  assert cli.main(argv) == 0
  assert checkpoints.latest(run).step == 120
  assert run.read_config().imports == (_USER_MODULE,)


def test_the_current_directory_is_searched_for_imports(
    tmp_path, monkeypatch, capsys
):
  """An installed script starts without it on the path; `--import` adds it."""
  monkeypatch.setattr(sys, 'path', [p for p in sys.path if p not in ('', '.')])
  module = 'user_tasks_in_the_current_directory'
  (tmp_path / f'{module}.py').write_text(
      'from mjx_composer.suite.tasks import registry\n'
      'from tests import conftest\n'
      "registry.register('user_swing_here', conftest.SwingTask)\n"
  )
  monkeypatch.chdir(tmp_path)
  try:
    assert cli.main(['list', '--import', module]) == 0
    assert 'user_swing_here' in capsys.readouterr().out
  finally:
    sys.modules.pop(module, None)
    if 'user_swing_here' in registry.names():
      registry.unregister('user_swing_here')


# -- errors: one line on stderr, exit status 2 -----------------------------------


def test_a_module_that_cannot_be_imported_is_named(
    tmp_path, monkeypatch, capsys
):
  monkeypatch.syspath_prepend(str(tmp_path))
  (tmp_path / 'user_tasks_that_fail.py').write_text(
      "raise RuntimeError('the tasks are not ready\\nyet')\n"
  )
  for command in (['list'], ['demo'], ['train', 'reach']):
    assert cli.main(command + ['--import', 'no_such_user_module']) == 2
    _assert_one_error_line(
        capsys,
        "the task module 'no_such_user_module'",
        "ModuleNotFoundError: No module named 'no_such_user_module'",
    )
  assert cli.main(['list', '--import', 'user_tasks_that_fail']) == 2
  _assert_one_error_line(
      capsys,
      "'user_tasks_that_fail'",
      'RuntimeError: the tasks are not ready yet',
  )


def test_a_run_whose_module_is_gone_is_refused(user_run, tmp_path, capsys):
  """The recorded module cannot be imported: named, in one line."""
  copy = str(tmp_path / 'copy')
  shutil.copytree(user_run, copy)
  run = run_folder.RunFolder(copy)
  run.write_config(run.read_config().replace(imports=['moved_user_module']))
  for command in (['play', copy, '--no-video'], ['export', copy]):
    assert cli.main(command) == 2
    _assert_one_error_line(capsys, "'moved_user_module'", 'ModuleNotFoundError')
  assert cli.main(['train', '--resume', copy]) == 2
  _assert_one_error_line(capsys, "'moved_user_module'")


def test_unknown_tasks_are_one_line(user_run, tmp_path, capsys):
  """Named by a flag, or by a run whose module no longer registers it."""
  assert cli.main(['train', 'no_such_task']) == 2
  _assert_one_error_line(capsys, "Unknown task 'no_such_task'", 'reach')
  _forget_user_module()
  copy = str(tmp_path / 'copy')
  shutil.copytree(user_run, copy)
  run = run_folder.RunFolder(copy)
  run.write_config(run.read_config().replace(imports=[]))
  for command in (['play', copy, '--no-video'], ['export', copy]):
    assert cli.main(command) == 2
    _assert_one_error_line(
        capsys, f"Unknown task '{_USER_TASK}'", '--import MODULE'
    )


@pytest.mark.parametrize(
    'module, command',
    [
        ('tyro', ['train', 'reach']),
        ('onnx', ['export', '{run}']),
    ],
)
def test_a_missing_extra_says_what_to_install(
    user_run, module, command, monkeypatch, capsys
):
  """A module of the train extra that is not installed (None in sys.modules:
  Python's own way of making an import fail)."""
  monkeypatch.setitem(sys.modules, module, None)
  argv = [a.format(run=user_run) for a in command]
  assert cli.main(argv + ['--import', _USER_MODULE]) == 2
  _assert_one_error_line(
      capsys,
      f'mjx-composer {command[0]} needs {module}, which is not installed',
      "pip install 'mjx-composer[train]'",
  )


def test_a_metric_the_task_does_not_report_is_named(capsys):
  registry.register(
      'swing_with_metrics',
      conftest.SwingTask,
      metrics={'tip_height': 'the height of the tip (m)'},
  )
  try:
    argv = ['demo', '--task', 'swing_with_metrics', '--worlds', '2']
    assert cli.main(argv + ['--steps', '2', '--chunk', '2']) == 2
  finally:
    registry.unregister('swing_with_metrics')
  _assert_one_error_line(capsys, "reports no metrics ['tip_height']")
