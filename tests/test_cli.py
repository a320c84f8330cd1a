"""The main job: `mjx-composer demo` runs end to end on the CPU."""

import pytest

import mjx_composer as composer
from mjx_composer import cli
from mjx_composer.suite.tasks import registry


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
  assert 'mean final hand-target distance' in out
  assert 'Diverged worlds: 0.' in out


def test_usage_without_command(capsys):
  assert cli.main([]) == 2
  out = capsys.readouterr().out
  assert 'usage' in out
  for command in ('demo', 'list', 'train', 'play', 'export'):
    assert f'mjx-composer {command}' in out


def test_train_help_lists_the_settings_with_the_tasks_defaults(capsys):
  with pytest.raises(SystemExit) as exit_info:
    cli.main(['train', 'walk', '--help'])
  assert exit_info.value.code == 0
  # The help is a box drawn to the terminal's width: read it as words.
  out = ' '.join(capsys.readouterr().out.replace('│', ' ').split())
  assert '--learning-rate' in out and '--policy-layers' in out
  assert '(default: 0.995)' in out  # walk's discount, not reach's 0.95


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


def test_demo_offers_every_registered_task():
  parser = cli.demo_parser()
  for name in registry.names():
    assert parser.parse_args(['--task', name]).task == name
  with pytest.raises(SystemExit):
    parser.parse_args(['--task', 'no_such_task'])


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
