"""Tests of benchmarks/segments.py: a PPO run continued across processes."""

import os
import pickle
import sys

import pytest

sys.path.insert(0, os.path.join(os.path.dirname(__file__), '..', 'benchmarks'))

import segments  # pylint: disable=g-import-not-at-top,wrong-import-position
import train_compare  # pylint: disable=g-import-not-at-top,wrong-import-position
import train_results  # pylint: disable=g-import-not-at-top,wrong-import-position

# Playground 0.2.0's HumanoidWalk schedule: 90 training steps of 983,040.
PLAYGROUND = dict(
    num_timesteps=60_000_000,
    num_evals=10,
    num_resets_per_eval=10,
    batch_size=1024,
    unroll_length=30,
    num_minibatches=32,
)


def test_the_segments_left_keep_the_evaluations_where_one_run_has_them():
  interval = segments.interval_steps(PLAYGROUND)
  assert interval == 10 * 983_040
  total = train_compare.brax_env_steps(PLAYGROUND)
  for done_intervals in range(9):
    done = done_intervals * interval
    num_timesteps, num_evals = segments.remaining_schedule(PLAYGROUND, done)
    rest = dict(PLAYGROUND, num_timesteps=num_timesteps, num_evals=num_evals)
    # Brax's own schedule for the rest: the steps left, in intervals of the
    # same length.
    assert train_compare.brax_env_steps(rest) == total - done
    assert segments.interval_steps(rest) == interval
  assert segments.remaining_schedule(PLAYGROUND, total) is None


def test_a_stop_between_evaluations_is_refused():
  with pytest.raises(ValueError, match='not at an evaluation'):
    segments.remaining_schedule(PLAYGROUND, 983_040)


def test_segments_draw_other_keys():
  seeds = {segments.segment_seed(s, k) for s in range(3) for k in range(3)}
  assert len(seeds) == 9
  assert segments.segment_seed(2, 0) == 2


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
  out = segments.continued_row(row, earlier, 1, 4.0, 3.0)
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


def test_load_needs_trained_evaluations_and_their_parameters(tmp_path):
  json_path = str(tmp_path / 'run.json')
  policy_path = str(tmp_path / 'policy.pkl')
  assert segments.load(json_path, policy_path) is None
  train_results.write_json(json_path, {'rows': []})
  assert segments.load(json_path, policy_path) is None
  # Stopped at the first evaluation (Brax saves no parameters before it).
  train_results.write_json(json_path, {'rows': [{'step': 0}]})
  assert segments.load(json_path, policy_path) is None
  train_results.write_json(json_path, {'rows': [{'step': 0}, {'step': 8}]})
  with pytest.raises(FileNotFoundError, match='leave out --resume'):
    segments.load(json_path, policy_path)
  with open(policy_path, 'wb') as f:
    pickle.dump({'params': (1, 2, 3), 'config': {}}, f)
  run, params = segments.load(json_path, policy_path)
  assert run['rows'][-1] == {'step': 8} and params == (1, 2, 3)


def test_resuming_checks_the_settings_and_what_is_left():
  run = {
      'status': 'stopped',
      'hyperparameters': PLAYGROUND,
      'rows': [{'step': 3 * 9_830_400}],
  }
  segment, config = train_compare._segment_to_train(run, PLAYGROUND, 'x')
  assert segment == 1  # records without 'segments' ran one
  assert (config['num_timesteps'], config['num_evals']) == (6 * 9_830_400, 7)
  with pytest.raises(ValueError, match='other hyper-parameters'):
    train_compare._segment_to_train(run, dict(PLAYGROUND, num_envs=8), 'x')
  assert (
      train_compare._segment_to_train(
          dict(run, status='finished'), PLAYGROUND, 'x'
      )
      is None
  )
