"""The main job: `mjx-composer demo` runs end to end on the CPU."""

from mjx_composer import cli


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
  assert 'Diverged worlds: 0.' in out


def test_usage_without_command(capsys):
  assert cli.main([]) == 2
  assert 'usage' in capsys.readouterr().out


def test_compilation_cache_flag():
  parser = cli.demo_parser()
  assert not parser.parse_args([]).no_compilation_cache
  assert parser.parse_args(['--no-compilation-cache']).no_compilation_cache


def test_impl_flag_reaches_the_environment(monkeypatch):
  from mjx_composer import environment  # pylint: disable=g-import-not-at-top

  parser = cli.demo_parser()
  assert parser.parse_args([]).impl is None
  assert parser.parse_args(['--impl', 'warp']).impl == 'warp'
  built = []
  monkeypatch.setattr(
      environment, 'Environment', lambda task, **kwargs: built.append(kwargs)
  )
  cli.make_environment('reach', impl='warp')
  assert built[0]['impl'] == 'warp'
