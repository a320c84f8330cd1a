"""benchmarks/train_segments.py: the schedule, the time limit, resuming."""

import jax
import pytest

import train_results  # benchmarks/train_results.py
import train_segments  # benchmarks/train_segments.py

# Playground 0.2.0's HumanoidWalk schedule: 90 training steps of 983,040.
PLAYGROUND = dict(
    num_timesteps=60_000_000,
    num_evals=10,
    num_resets_per_eval=10,
    batch_size=1024,
    unroll_length=30,
    num_minibatches=32,
)


def test_brax_env_steps_matches_brax_schedule():
  # Playground's HumanoidWalk config: 9 evaluation intervals x 10 resets,
  # one training step of 1024 x 30 x 32 env steps each.
  config = dict(
      num_timesteps=60_000_000,
      num_evals=10,
      num_resets_per_eval=10,
      batch_size=1024,
      unroll_length=30,
      num_minibatches=32,
  )
  assert train_segments.brax_env_steps(config) == 90 * 983_040
  config.update(num_evals=31, num_resets_per_eval=3)
  assert train_segments.brax_env_steps(config) == 90 * 983_040
  config.update(num_timesteps=2000, num_evals=2, num_resets_per_eval=0)
  config.update(batch_size=8, unroll_length=5, num_minibatches=2)
  assert train_segments.brax_env_steps(config) == 2000


def test_deadline_uses_the_last_interval():
  rows = [{'wall_s': 100.0}]
  assert not train_segments.next_eval_too_late(rows, None)
  assert not train_segments.next_eval_too_late(rows, 200.0)  # next at 200
  assert train_segments.next_eval_too_late(rows, 199.0)
  rows.append({'wall_s': 130.0})  # next expected at 160
  assert not train_segments.next_eval_too_late(rows, 160.0)
  assert train_segments.next_eval_too_late(rows, 159.0)


def test_no_deadline_after_the_last_evaluation():
  rows = [{'step': 0, 'wall_s': 100.0}, {'step': 500, 'wall_s': 300.0}]
  # A next evaluation would end at 500 s, past the limit; but with 500
  # steps planned there is none, so the run finishes rather than stops.
  assert train_segments.next_eval_too_late(rows, 400.0)
  assert train_segments.next_eval_too_late(rows, 400.0, planned_steps=1000)
  assert not train_segments.next_eval_too_late(rows, 400.0, planned_steps=500)
  assert not train_segments.next_eval_too_late(rows, 400.0, planned_steps=400)


def test_deadline_leaves_out_the_time_spent_compiling():
  # 100 s to the first evaluation, 80 of them compiling the evaluator.
  rows = [{'wall_s': 100.0, 'compile_s': 80.0}]
  assert not train_segments.next_eval_too_late(rows, 120.0)  # next at 120
  assert train_segments.next_eval_too_late(rows, 119.0)
  # The first training updates took 130 s, 110 of them compiling: the
  # next updates are expected to take 20 s.
  rows.append({'wall_s': 230.0, 'compile_s': 190.0})
  assert not train_segments.next_eval_too_late(rows, 250.0)
  assert train_segments.next_eval_too_late(rows, 249.0)


def test_the_compile_clock_counts_compiles_since_it_started():

  clock = train_segments.CompileClock()
  assert clock.seconds == 0.0
  # A program no other test compiles (a fresh closure), so XLA compiles it.
  jax.jit(lambda x: x * 3.0 + 0.125).lower(1.0).compile()
  assert clock.seconds > 0.0
  later = train_segments.CompileClock()
  assert later.seconds == 0.0 < clock.seconds


def test_the_segments_left_keep_the_evaluations_where_one_run_has_them():
  interval = train_segments.interval_steps(PLAYGROUND)
  assert interval == 10 * 983_040
  total = train_segments.brax_env_steps(PLAYGROUND)
  for done_intervals in range(9):
    done = done_intervals * interval
    num_timesteps, num_evals = train_segments.remaining_schedule(
        PLAYGROUND, done
    )
    rest = dict(PLAYGROUND, num_timesteps=num_timesteps, num_evals=num_evals)
    # Brax's own schedule for the rest: the steps left, in intervals of the
    # same length.
    assert train_segments.brax_env_steps(rest) == total - done
    assert train_segments.interval_steps(rest) == interval
  assert train_segments.remaining_schedule(PLAYGROUND, total) is None


def test_a_stop_between_evaluations_is_refused():
  with pytest.raises(ValueError, match='not at an evaluation'):
    train_segments.remaining_schedule(PLAYGROUND, 983_040)


def test_segments_draw_other_keys():
  seeds = {
      train_segments.segment_seed(s, k) for s in range(3) for k in range(3)
  }
  assert len(seeds) == 9
  assert train_segments.segment_seed(2, 0) == 2


def test_a_stopped_run_needs_trained_evaluations_and_their_parameters(
    tmp_path,
):
  json_path = str(tmp_path / 'run.json')
  policy_path = str(tmp_path / 'policy.pkl')
  load = train_segments.load_stopped_run
  assert load(json_path, policy_path) is None
  train_results.write_json(json_path, {'rows': []})
  assert load(json_path, policy_path) is None
  # Stopped at the first evaluation (Brax saves no parameters before it).
  train_results.write_json(json_path, {'rows': [{'step': 0}]})
  assert load(json_path, policy_path) is None
  train_results.write_json(json_path, {'rows': [{'step': 0}, {'step': 8}]})
  with pytest.raises(FileNotFoundError, match='leave out --resume'):
    load(json_path, policy_path)
  train_segments.save_params(policy_path, (1, 2, 3), {'task': 'walk'})
  run, params = load(json_path, policy_path)
  assert run['rows'][-1] == {'step': 8} and params == (1, 2, 3)


def test_resuming_checks_the_settings_and_what_is_left():
  run = {
      'status': 'stopped',
      'hyperparameters': PLAYGROUND,
      'rows': [{'step': 3 * 9_830_400}],
  }
  segment, config = train_segments.segment_to_train(run, PLAYGROUND, 'x')
  assert segment == 1  # records without 'segments' ran one
  assert (config['num_timesteps'], config['num_evals']) == (6 * 9_830_400, 7)
  with pytest.raises(ValueError, match='other hyper-parameters'):
    train_segments.segment_to_train(run, dict(PLAYGROUND, num_envs=8), 'x')
  assert (
      train_segments.segment_to_train(
          dict(run, status='finished'), PLAYGROUND, 'x'
      )
      is None
  )


def test_resume_goes_on_where_one_requested_run_has_a_record(tmp_path):
  check = train_segments.check_something_to_resume
  with pytest.raises(SystemExit, match='holds no record'):
    check(str(tmp_path), ['ours_off'], [0, 1])
  (tmp_path / 'runs').mkdir()
  (tmp_path / 'runs' / 'ours_off_seed1.json').write_text('{}')
  check(str(tmp_path), ['ours_off'], [0, 1])  # seed 1 has a record
  with pytest.raises(SystemExit, match='holds no record'):
    check(str(tmp_path), ['playground'], [1])
