"""benchmarks/train_results.py: run records, merging, summary and table."""

import json
import os
import sys

import pytest

sys.path.insert(
    0, os.path.join(os.path.dirname(os.path.dirname(__file__)), 'benchmarks')
)
import train_results  # pylint: disable=g-import-not-at-top,wrong-import-position


def _run(env, seed, points, status='finished', total_s=None):
  """A run record with evaluations at (wall_s, step, return) `points`."""
  return {
      'env': env,
      'seed': seed,
      'status': status,
      'total_s': total_s,
      'rows': [
          {
              'step': step,
              'wall_s': wall,
              'eval_return': ret,
              'eval_return_std': 1.0,
              'train_walltime_s': 0.0,
              'train_sps': 0.0,
              'eval_walltime_s': 0.0,
              'eval_episode_length': 1000.0,
          }
          for wall, step, ret in points
      ],
  }


def _write_run(out, run):
  os.makedirs(os.path.join(out, 'runs'), exist_ok=True)
  name = train_results.run_name(run['env'], run['seed'])
  with open(os.path.join(out, 'runs', name + '.json'), 'w') as f:
    json.dump(run, f)


def test_time_to_playgrounds_final_return():
  runs = [
      # Playground's final returns 300 and 500: the threshold is 400.
      _run('playground', 0, [(10, 0, 5), (50, 10, 300)], total_s=55),
      _run('playground', 1, [(12, 0, 5), (40, 10, 410), (60, 20, 500)], 61),
      # Ours reaches 400 at its third evaluation, exactly at the threshold
      # on seed 0; seed 1 never does and was stopped.
      _run('ours', 0, [(20, 0, 5), (70, 10, 390), (90, 20, 400)], 95),
      _run('ours', 1, [(21, 0, 5), (75, 10, 100)], 'stopped', 80),
  ]
  summary = train_results.summarize(runs)
  assert summary['threshold'] == pytest.approx(400.0)
  pg = summary['envs']['playground']
  assert pg['final_return_mean'] == pytest.approx(400.0)
  assert pg['final_return_std'] == pytest.approx(100.0)
  assert pg['per_seed'][0]['time_to_threshold_s'] is None
  assert pg['per_seed'][1]['time_to_threshold_s'] == 40
  assert pg['per_seed'][1]['steps_to_threshold'] == 10
  ours = summary['envs']['ours']
  assert ours['per_seed'][0]['time_to_threshold_s'] == 90
  assert ours['per_seed'][1]['time_to_threshold_s'] is None
  assert ours['per_seed'][1]['status'] == 'stopped'
  assert ours['final_steps'] == [10, 20]
  table = train_results.format_table(summary)
  assert 'time to 400.0' in table
  assert '80 (stopped)' in table
  # An explicit threshold wins.
  assert (
      train_results.summarize(runs, threshold=5.0)['envs']['ours']['per_seed'][
          1
      ]['time_to_threshold_s']
      == 21
  )


def test_invocations_merge_and_a_rerun_replaces_its_run(tmp_path):
  out = str(tmp_path)
  _write_run(out, _run('playground', 0, [(10, 0, 1.0)]))
  train_results.write_merged(out)
  _write_run(out, _run('ours', 1, [(10, 0, 2.0), (20, 5, 3.0)]))
  runs = train_results.write_merged(out)
  assert [(r['env'], r['seed']) for r in runs] == [
      ('ours', 1),
      ('playground', 0),
  ]
  with open(os.path.join(out, 'results.json')) as f:
    assert len(json.load(f)['runs']) == 2
  with open(os.path.join(out, 'results.csv')) as f:
    lines = f.read().splitlines()
  assert lines[0].startswith('env,seed,step,wall_s')
  assert len(lines) == 1 + 3
  # The same (env, seed) again: its file is replaced, not added to.
  _write_run(out, _run('ours', 1, [(11, 0, 7.0)]))
  runs = train_results.write_merged(out)
  assert len(runs) == 2
  assert runs[0]['rows'][0]['eval_return'] == 7.0
  assert train_results.load_runs(out) == runs


def test_the_plot_mode_writes_the_table_and_summary(tmp_path):
  import train_compare  # pylint: disable=g-import-not-at-top

  out = str(tmp_path)
  _write_run(out, _run('playground', 0, [(10, 0, 1.0), (20, 5, 4.0)]))
  _write_run(out, _run('ours_off', 0, [(10, 0, 1.0), (18, 5, 4.5)]))
  assert train_compare.main(['--out', out, '--plot']) == 0
  with open(os.path.join(out, 'table.md')) as f:
    table = f.read()
  assert '| ours_off | 0 | 5 | 4.5 ± 0.0 | 18 |' in table
  with open(os.path.join(out, 'summary.json')) as f:
    assert json.load(f)['threshold'] == 4.0
  try:
    import matplotlib  # pylint: disable=g-import-not-at-top,unused-import
  except ImportError:
    return
  assert os.path.getsize(os.path.join(out, 'returns.png')) > 0
