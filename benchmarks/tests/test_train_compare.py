"""benchmarks/train_compare.py without training: settings, GPUs, rates, and
continuing a stopped run (`--resume`)."""

import pickle

import pytest

import train_compare  # benchmarks/train_compare.py
import train_results  # benchmarks/train_results.py

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
  assert train_compare.brax_env_steps(config) == 90 * 983_040
  config.update(num_evals=31, num_resets_per_eval=3)
  assert train_compare.brax_env_steps(config) == 90 * 983_040
  config.update(num_timesteps=2000, num_evals=2, num_resets_per_eval=0)
  config.update(batch_size=8, unroll_length=5, num_minibatches=2)
  assert train_compare.brax_env_steps(config) == 2000


def test_child_command_line():
  argv = ['--out', 'x', '--gpus', '0,1', '--max-wall-s', '500', '--gpus=2']
  assert train_compare._child_argv(argv, 'ours', 2) == [
      '--out',
      'x',
      '--max-wall-s',
      '500',
      '--envs',
      'ours',
      '--seeds',
      '2',
  ]
  args = train_compare.parse_args(
      train_compare._child_argv(['--envs', 'playground', 'ours'], 'ours', 2)
  )
  assert args.envs == ['ours'] and args.seeds == [2]


def test_gpu_groups_give_each_run_its_devices():
  assert train_compare.gpu_groups('0,1,2', 1) == ['0', '1', '2']
  assert train_compare.gpu_groups('0+1, 2+3', 2) == ['0,1', '2,3']
  with pytest.raises(ValueError, match='--devices is 2'):
    train_compare.gpu_groups('0,1', 2)
  with pytest.raises(ValueError, match='in two runs'):
    train_compare.gpu_groups('0+1,1+2', 2)
  with pytest.raises(ValueError, match='distinct'):
    train_compare.gpu_groups('0+0', 2)
  with pytest.raises(ValueError, match='names no GPU'):
    train_compare.gpu_groups(',', 1)


def test_env_steps_per_s_counts_each_step_once():
  import train_ppo  # pylint: disable=g-import-not-at-top

  def metrics(walltime, brax_sps):
    return {
        'training/walltime': walltime,
        'training/sps': brax_sps,
        'eval/episode_reward': 1.0,
        'eval/episode_reward_std': 0.0,
        'eval/avg_episode_length': 1000.0,
    }

  first = train_ppo.eval_row(0, metrics(0.0, 0.0), 10.0)
  assert first['env_steps_per_s'] == 0.0
  # Two epochs of 1,000 steps in 4 s of training, 2 s each: Brax reports
  # 2 x 1,000 / 2 s = 1,000/s for the last epoch; the rate is 500/s.
  second = train_ppo.eval_row(2000, metrics(4.0, 1000.0), 20.0, previous=first)
  assert second['env_steps_per_s'] == 500.0
  assert second['train_sps'] == 1000.0
  third = train_ppo.eval_row(4000, metrics(9.0, 800.0), 30.0, previous=second)
  assert third['env_steps_per_s'] == 400.0
  # The runs' rate leaves out the first interval (compiling).
  assert train_results.training_rate([first, second, third]) == 400.0
  assert train_results.training_rate([first, second]) is None


def test_deadline_uses_the_last_interval():
  import train_ppo  # pylint: disable=g-import-not-at-top

  rows = [{'wall_s': 100.0}]
  assert not train_ppo.next_eval_too_late(rows, None)
  assert not train_ppo.next_eval_too_late(rows, 200.0)  # next at 200
  assert train_ppo.next_eval_too_late(rows, 199.0)
  rows.append({'wall_s': 130.0})  # next expected at 160
  assert not train_ppo.next_eval_too_late(rows, 160.0)
  assert train_ppo.next_eval_too_late(rows, 159.0)


def test_no_deadline_after_the_last_evaluation():
  import train_ppo  # pylint: disable=g-import-not-at-top

  rows = [{'step': 0, 'wall_s': 100.0}, {'step': 500, 'wall_s': 300.0}]
  # A next evaluation would end at 500 s, past the limit; but with 500
  # steps planned there is none, so the run finishes rather than stops.
  assert train_ppo.next_eval_too_late(rows, 400.0)
  assert train_ppo.next_eval_too_late(rows, 400.0, planned_steps=1000)
  assert not train_ppo.next_eval_too_late(rows, 400.0, planned_steps=500)
  assert not train_ppo.next_eval_too_late(rows, 400.0, planned_steps=400)


def test_deadline_leaves_out_the_time_spent_compiling():
  import train_ppo  # pylint: disable=g-import-not-at-top

  # 100 s to the first evaluation, 80 of them compiling the evaluator.
  rows = [{'wall_s': 100.0, 'compile_s': 80.0}]
  assert not train_ppo.next_eval_too_late(rows, 120.0)  # next at 120
  assert train_ppo.next_eval_too_late(rows, 119.0)
  # The first training updates took 130 s, 110 of them compiling: the
  # next updates are expected to take 20 s.
  rows.append({'wall_s': 230.0, 'compile_s': 190.0})
  assert not train_ppo.next_eval_too_late(rows, 250.0)
  assert train_ppo.next_eval_too_late(rows, 249.0)


def test_the_compile_clock_counts_compiles_since_it_started():
  import jax  # pylint: disable=g-import-not-at-top
  import train_ppo  # pylint: disable=g-import-not-at-top

  clock = train_ppo.CompileClock()
  assert clock.seconds == 0.0
  # A program no other test compiles (a fresh closure), so XLA compiles it.
  jax.jit(lambda x: x * 3.0 + 0.125).lower(1.0).compile()
  assert clock.seconds > 0.0
  later = train_ppo.CompileClock()
  assert later.seconds == 0.0 < clock.seconds


def test_training_on_several_devices_uses_jax():
  import train_ppo  # pylint: disable=g-import-not-at-top

  assert train_ppo.impl_for_devices(None, 1, _fail) is None
  assert train_ppo.impl_for_devices('warp', 1, _fail) == 'warp'
  assert train_ppo.impl_for_devices(None, 2, _fail) == 'jax'
  assert train_ppo.impl_for_devices('jax', 4, _fail) == 'jax'
  with pytest.raises(SystemExit, match='--devices 1'):
    train_ppo.impl_for_devices('warp', 2, _fail)


def _fail(message):
  raise SystemExit(message)


def test_feature_variants_train_like_ours_off_with_those_features():
  args = train_compare.parse_args(
      ['--envs', 'playground', 'only_noise+randomize', '--seeds', '0']
  )
  assert args.envs == ['playground', 'only_noise+randomize']
  with pytest.raises(SystemExit):
    train_compare.parse_args(['--envs', 'only_wings'])
  config = dict(train_compare.FALLBACK_EXTRA)
  import train_ppo  # pylint: disable=g-import-not-at-top

  defaults = train_ppo.parse_args(['--task', 'walk'])
  for flag, ppo in train_compare._TRAIN_PPO_NAMES.items():
    config[ppo] = getattr(defaults, flag)
  brax_env, kwargs, _ = train_compare._ours_setup(
      'only_noise+randomize', config, args
  )
  task = brax_env.environment.task
  # The two features on; pushes and fall terminations stay off, so the
  # episodes are HumanoidWalk's 1,000 steps.
  assert task._randomize and task._pushes.interval == 0
  assert not task._terminate_on_fall
  assert brax_env.episode_length == 1000
  assert kwargs['num_envs'] == config['num_envs']


def test_a_shared_feature_variant_fuses_the_restart():
  args = train_compare.parse_args(
      ['--envs', 'only_noise_shared', '--no-share-reset-forward']
  )
  assert args.envs == ['only_noise_shared']
  config = dict(train_compare.FALLBACK_EXTRA)
  import train_ppo  # pylint: disable=g-import-not-at-top

  defaults = train_ppo.parse_args(['--task', 'walk'])
  for flag, ppo in train_compare._TRAIN_PPO_NAMES.items():
    config[ppo] = getattr(defaults, flag)
  brax_env, _, _ = train_compare._ours_setup('only_noise_shared', config, args)
  assert brax_env.environment.share_reset_forward
  assert not brax_env.environment.task._randomize  # only the noise is on


def test_resume_refuses_an_out_without_the_runs(tmp_path):
  # The mistake it guards against: the previous call's runs not brought.
  with pytest.raises(SystemExit, match='holds no record'):
    train_compare.main(
        [
            '--out',
            str(tmp_path),
            '--envs',
            'ours_off',
            '--seeds',
            '0',
            '--resume',
        ]
    )
  assert not (tmp_path / 'runs').exists()


def test_resume_goes_on_where_one_requested_run_has_a_record(tmp_path):
  (tmp_path / 'runs').mkdir()
  (tmp_path / 'runs' / 'ours_off_seed1.json').write_text('{}')
  args = train_compare.parse_args(
      ['--out', str(tmp_path), '--envs', 'ours_off', '--seeds', '0', '1']
      + ['--resume']
  )
  train_compare._check_something_to_resume(args)  # pylint: disable=protected-access


def test_the_segments_left_keep_the_evaluations_where_one_run_has_them():
  interval = train_compare.interval_steps(PLAYGROUND)
  assert interval == 10 * 983_040
  total = train_compare.brax_env_steps(PLAYGROUND)
  for done_intervals in range(9):
    done = done_intervals * interval
    num_timesteps, num_evals = train_compare.remaining_schedule(
        PLAYGROUND, done
    )
    rest = dict(PLAYGROUND, num_timesteps=num_timesteps, num_evals=num_evals)
    # Brax's own schedule for the rest: the steps left, in intervals of the
    # same length.
    assert train_compare.brax_env_steps(rest) == total - done
    assert train_compare.interval_steps(rest) == interval
  assert train_compare.remaining_schedule(PLAYGROUND, total) is None


def test_a_stop_between_evaluations_is_refused():
  with pytest.raises(ValueError, match='not at an evaluation'):
    train_compare.remaining_schedule(PLAYGROUND, 983_040)


def test_segments_draw_other_keys():
  seeds = {train_compare.segment_seed(s, k) for s in range(3) for k in range(3)}
  assert len(seeds) == 9
  assert train_compare.segment_seed(2, 0) == 2


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
  out = train_compare.continued_row(row, earlier, 1, 4.0, 3.0)
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


def test_a_stopped_run_needs_trained_evaluations_and_their_parameters(
    tmp_path,
):
  json_path = str(tmp_path / 'run.json')
  policy_path = str(tmp_path / 'policy.pkl')
  load = train_compare.load_stopped_run
  assert load(json_path, policy_path) is None
  train_results.write_json(json_path, {'rows': []})
  assert load(json_path, policy_path) is None
  # Stopped at the first evaluation (Brax saves no parameters before it).
  train_results.write_json(json_path, {'rows': [{'step': 0}]})
  assert load(json_path, policy_path) is None
  train_results.write_json(json_path, {'rows': [{'step': 0}, {'step': 8}]})
  with pytest.raises(FileNotFoundError, match='leave out --resume'):
    load(json_path, policy_path)
  with open(policy_path, 'wb') as f:
    pickle.dump({'params': (1, 2, 3), 'config': {}}, f)
  run, params = load(json_path, policy_path)
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
