"""benchmarks/train_results.py: run records, merging, summary and table."""

import json
import os
import shutil

import pytest

import train_results  # benchmarks/train_results.py

# The comparison's records in the repository (docs/performance.md).
_STORED = os.path.join(
    os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
    'results',
    'train_compare_walk_full_schedule',
)


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


def _segmented_run(env, seed, segments, status='finished', total_s=None):
  """A run trained in `segments`, each `(resume_overhead_s, points)`.

  The points are `_run`'s (wall_s, step, return), on the run's continued
  clock (as `train_compare.continued_row` writes them).
  """
  run = _run(env, seed, [p for _, points in segments for p in points])
  run.update(status=status, total_s=total_s, segments=len(segments))
  rows = iter(run['rows'])
  for k, (overhead, points) in enumerate(segments):
    for _ in points:
      next(rows).update(segment=k, resume_overhead_s=overhead)
  return run


def _write_run(out, run):
  os.makedirs(os.path.join(out, 'runs'), exist_ok=True)
  name = train_results.run_name(run['env'], run['seed'])
  with open(os.path.join(out, 'runs', name + '.json'), 'w') as f:
    json.dump(run, f)


def test_time_to_playgrounds_final_return():
  runs = [
      # Playground's final returns 300 and 500: the threshold is 400.
      _run('playground', 0, [(10, 0, 5), (50, 10, 300)], total_s=55),
      _run(
          'playground',
          1,
          [(12, 0, 5), (40, 10, 410), (60, 20, 500)],
          total_s=61,
      ),
      # Ours reaches 400 at its third evaluation, exactly at the threshold
      # on seed 0; seed 1 never does and was stopped.
      _run('ours', 0, [(20, 0, 5), (70, 10, 390), (90, 20, 400)], total_s=95),
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
  # Per seed, in seed order; the stopped seed's return is not a final one.
  assert ours['final_steps'] == [20, 10]
  assert ours['final_return_seeds'] == [0]
  assert ours['final_return_mean'] == pytest.approx(400.0)
  table = train_results.format_table(summary)
  assert 'time to 400.0' in table
  assert '80 (stopped)' in table
  assert '| 20, 10 |' in table
  assert '400.0 ± 0.0 (seeds 0)' in table
  assert '400.0 ± 100.0 |' in table  # Playground's two finished seeds
  # A stopped reference run does not lower the threshold.
  stopped = _run('playground', 2, [(11, 0, 5), (30, 10, 20)], 'stopped', 33)
  assert train_results.summarize(runs + [stopped])['threshold'] == (
      pytest.approx(400.0)
  )
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


def test_one_process_wall_is_wall_s_for_an_unsegmented_run():
  run = _run('ours', 0, [(20, 0, 5), (70, 10, 390), (90, 20, 400)])
  assert train_results.one_process_wall(run['rows']) == [20, 70, 90]
  # Rows of a run trained since `segment` was recorded: segment 0 only.
  single = _segmented_run('ours', 0, [(0.0, [(20, 0, 5), (70, 10, 390)])])
  assert train_results.one_process_wall(single['rows']) == [20, 70]
  assert train_results.one_process_wall([]) == []


def test_one_process_wall_subtracts_later_segments_overheads():
  seg0 = (0.0, [(20, 0, 5), (70, 10, 100)])
  # Segment 1 took 30 s before training (its rows' wall_s include them),
  # segment 2 took 25 s.
  seg1 = (30.0, [(150, 20, 200), (200, 30, 300)])
  seg2 = (25.0, [(290, 40, 350), (340, 50, 400)])
  two = _segmented_run('ours', 0, [seg0, seg1])
  assert train_results.one_process_wall(two['rows']) == pytest.approx(
      [20, 70, 120, 170]
  )
  three = _segmented_run('ours', 0, [seg0, seg1, seg2])
  assert train_results.one_process_wall(three['rows']) == pytest.approx(
      [20, 70, 120, 170, 235, 285]
  )
  # The mean curve is on the same clock.
  wall, ret = train_results.mean_curve([three, three])
  assert list(wall) == pytest.approx([20, 70, 120, 170, 235, 285])
  assert list(ret) == [5, 100, 200, 300, 350, 400]


def test_one_process_wall_leaves_out_compiling_the_training_program_again():
  seg0 = (0.0, [(20, 0, 5), (70, 10, 100)])
  seg1 = (30.0, [(150, 20, 200), (200, 30, 300)])
  run = _segmented_run('ours', 0, [seg0, seg1])
  rows = run['rows']
  # Segment 0 compiled 15 s in all; segment 1 compiled 20 s within its
  # 30 s overhead, and 12 s more (the training program) before its first
  # row.
  for row, compile_s in zip(rows, (10, 15, 47, 47)):
    row['compile_s'] = compile_s
  rows[2]['resume_compile_s'] = 20.0
  assert train_results.one_process_wall(rows) == pytest.approx(
      [20, 70, 150 - 30 - 12, 200 - 30 - 12]
  )
  # Rows without the overhead's compile seconds (older records): the
  # larger of the overhead (30) and the segment's compiling (32).
  del rows[2]['resume_compile_s']
  assert train_results.one_process_wall(rows) == pytest.approx(
      [20, 70, 150 - 32, 200 - 32]
  )
  for row in rows[2:]:
    row['compile_s'] = 40  # 25 s of compiling: the overhead is larger.
  assert train_results.one_process_wall(rows) == pytest.approx(
      [20, 70, 120, 170]
  )


def test_summary_times_leave_out_resume_overheads():
  runs = [
      _run('playground', 0, [(20, 0, 5), (70, 10, 300)], total_s=75),
      # Reaches 300 in segment 2, at 235 s in one process (290 - 30 - 25).
      _segmented_run(
          'ours',
          0,
          [
              (0.0, [(20, 0, 5), (70, 10, 100)]),
              (30.0, [(150, 20, 200), (200, 30, 250)]),
              (25.0, [(290, 40, 300), (340, 50, 400)]),
          ],
          total_s=350,
      ),
      # Still running (no total_s) in its second segment.
      _segmented_run(
          'ours',
          1,
          [
              (0.0, [(20, 0, 5), (70, 10, 100)]),
              (40.0, [(160, 20, 300)]),
          ],
          status='running',
      ),
  ]
  summary = train_results.summarize(runs)
  assert summary['threshold'] == pytest.approx(300.0)
  ours = summary['envs']['ours']['per_seed']
  assert ours[0]['time_to_threshold_s'] == pytest.approx(235)
  assert ours[0]['steps_to_threshold'] == 40
  assert ours[0]['total_s'] == pytest.approx(295)
  assert ours[0]['segments'] == 3
  assert ours[0]['resume_s'] == pytest.approx(55)
  assert ours[1]['time_to_threshold_s'] == pytest.approx(120)
  assert ours[1]['total_s'] == pytest.approx(120)
  assert ours[1]['segments'] == 2
  assert ours[1]['resume_s'] == pytest.approx(40)
  pg = summary['envs']['playground']['per_seed'][0]
  assert pg['time_to_threshold_s'] == 70
  assert pg['total_s'] == 75
  assert pg['segments'] == 1
  assert pg['resume_s'] == 0.0
  table = train_results.format_table(summary)
  assert '| 235, 120 | 295, 120 (running) |' in table
  footnote = table.splitlines()[-1]
  assert footnote.startswith('Times are one-process-equivalent wall-clock')
  assert 'ours 55, 40 s in all per seed' in footnote
  assert 'playground' not in footnote
  # A blank line parts the footnote from the table.
  assert table.splitlines()[-2] == ''


def test_no_footnote_for_unsegmented_runs():
  runs = [
      _run('playground', 0, [(10, 0, 5), (50, 10, 300)], total_s=55),
      # Segment keys, but one segment only.
      _segmented_run(
          'ours', 0, [(0.0, [(20, 0, 5), (70, 10, 390)])], total_s=75
      ),
  ]
  summary = train_results.summarize(runs)
  assert summary['envs']['ours']['per_seed'][0]['total_s'] == 75
  table = train_results.format_table(summary)
  assert 'one-process' not in table
  assert len(table.splitlines()) == 4


def test_the_training_rate_leaves_out_each_segments_first_interval():
  def row(step, walltime, segment):
    return dict(step=step, train_walltime_s=walltime, segment=segment)

  rows = [
      row(0, 0.0, 0),
      row(100, 50.0, 0),  # compiled in this interval
      row(200, 51.0, 0),
      row(300, 80.0, 1),  # resumed: compiled again
      row(400, 81.0, 1),
      row(500, 82.0, 1),
  ]
  assert train_results.training_rate(rows) == 300 / 3.0
  assert train_results.training_rate(rows[:3]) == 100.0
  assert train_results.training_rate(rows[:2]) is None


def test_env_steps_per_s_counts_each_step_once():
  def metrics(walltime, brax_sps):
    return {
        'training/walltime': walltime,
        'training/sps': brax_sps,
        'eval/episode_reward': 1.0,
        'eval/episode_reward_std': 0.0,
        'eval/avg_episode_length': 1000.0,
    }

  first = train_results.eval_row(0, metrics(0.0, 0.0), 10.0)
  assert first['env_steps_per_s'] == 0.0
  # Two epochs of 1,000 steps in 4 s of training, 2 s each: Brax reports
  # 2 x 1,000 / 2 s = 1,000/s for the last epoch; the rate is 500/s.
  second = train_results.eval_row(
      2000, metrics(4.0, 1000.0), 20.0, previous=first
  )
  assert second['env_steps_per_s'] == 500.0
  assert second['train_sps'] == 1000.0
  third = train_results.eval_row(
      4000, metrics(9.0, 800.0), 30.0, previous=second
  )
  assert third['env_steps_per_s'] == 400.0
  # The runs' rate leaves out the first interval (compiling).
  assert train_results.training_rate([first, second, third]) == 400.0
  assert train_results.training_rate([first, second]) is None


def test_a_continued_row_follows_the_earlier_ones():
  earlier = [
      dict(
          step=100,
          wall_s=50.0,
          compile_s=20.0,
          train_walltime_s=30.0,
          eval_walltime_s=10.0,
      )
  ]
  row = dict(
      step=40,
      wall_s=15.0,
      compile_s=5.0,
      train_walltime_s=6.0,
      eval_walltime_s=2.0,
      eval_return=3.0,
  )
  out = train_results.continued_row(row, earlier, 1, 4.0, 3.0)
  assert out == dict(
      step=140,
      wall_s=65.0,
      compile_s=25.0,
      train_walltime_s=36.0,
      eval_walltime_s=12.0,
      eval_return=3.0,
      segment=1,
      resume_overhead_s=4.0,
      resume_compile_s=3.0,
  )


def test_rows_keep_the_columns_of_the_stored_runs(tmp_path):
  metrics = {
      'training/walltime': 4.0,
      'training/sps': 10.0,
      'eval/walltime': 2.0,
      'eval/episode_reward': 3.0,
      'eval/episode_reward_std': 0.5,
      'eval/avg_episode_length': 1000.0,
  }
  row = train_results.eval_row(40, metrics, 12.0, compile_s=7.0)
  row.update(segment=0, resume_overhead_s=0.0, resume_compile_s=0.0)
  path = str(tmp_path / 'run.csv')
  train_results.append_csv(path, row)
  train_results.append_csv(path, dict(row, step=80))
  with open(path) as f:
    lines = f.read().splitlines()
  stored = os.path.join(_STORED, 'runs', 'ours_off_seed0.csv')
  with open(stored) as f:
    header = f.readline().strip()
  # The stored runs predate `resume_compile_s`; their columns come first,
  # in the same order.
  assert lines[0] == header + ',resume_compile_s'
  assert len(lines) == 3 and lines[2].startswith('80,12.0,7.0,4.0,')


def test_the_stored_comparison_reads_back_to_its_table(tmp_path):
  """`train_compare.py --plot` on the stored runs gives their table again."""
  import train_compare  # pylint: disable=g-import-not-at-top

  out = tmp_path / 'compare'
  shutil.copytree(os.path.join(_STORED, 'runs'), out / 'runs')
  assert train_compare.main(['--out', str(out), '--plot']) == 0
  for name in ('table.md', 'summary.json'):
    with open(out / name) as f, open(os.path.join(_STORED, name)) as g:
      if name.endswith('.json'):
        assert json.load(f) == json.load(g)
      else:
        assert f.read() == g.read()
