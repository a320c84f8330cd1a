"""benchmarks/scaling.py without devices: the train part's runs and rates,
and the devices' kernel time read from a profile."""

import types

import pytest

import scaling  # benchmarks/scaling.py
from mjx_composer.training import config as config_lib


def _flags(task, devices, scale, intervals=4, updates=30):
  args = types.SimpleNamespace(train_intervals=intervals, train_updates=updates)
  flags = scaling.train_flags(task, devices, scale, args)
  return dict(zip(flags[::2], flags[1::2])) | {'tensorboard': flags[-1]}


def test_weak_scaling_gives_each_device_the_worlds_and_minibatch_of_one():
  defaults = config_lib.defaults('joystick')
  one, weak = _flags('joystick', 1, 1), _flags('joystick', 2, 2)
  strong = _flags('joystick', 2, 1)
  assert int(one['--num-envs']) == defaults.num_envs
  assert int(one['--batch-size']) == defaults.batch_size
  assert strong['--num-envs'] == one['--num-envs']
  assert int(weak['--num-envs']) == 2 * defaults.num_envs
  assert int(weak['--batch-size']) == 2 * defaults.batch_size
  assert (one['--devices'], weak['--devices']) == ('1', '2')
  # Each interval is the same number of training steps (Brax's epoch), each
  # one unroll of every world: twice the env steps with twice the worlds.
  per_update = (
      defaults.batch_size * defaults.num_minibatches * defaults.unroll_length
  )
  assert int(one['--num-timesteps']) == 4 * 30 * per_update
  assert int(weak['--num-timesteps']) == 2 * int(one['--num-timesteps'])
  assert one['--num-evals'] == '5'
  assert one['tensorboard'] == '--no-tensorboard'


def test_the_weak_runs_settings_pass_the_training_commands_checks():
  flags = _flags('joystick', 2, 2)
  config = config_lib.defaults('joystick').replace(
      num_envs=int(flags['--num-envs']),
      batch_size=int(flags['--batch-size']),
  )
  config_lib.check(config)  # batch_size x minibatches a multiple of worlds


def test_the_rate_leaves_out_the_evaluation_before_training_and_the_compile():
  rows = [
      {'env_steps_per_s': 0.0},
      {'env_steps_per_s': 10.0},  # holds the compile
      {'env_steps_per_s': 500.0},
      {'env_steps_per_s': 520.0},
      {'env_steps_per_s': 480.0},
  ]
  assert scaling.train_rate(rows) == 500.0
  with pytest.raises(ValueError, match='--train-intervals'):
    scaling.train_rate(rows[:2])


def test_efficiency_is_all_devices_over_n_times_one_per_scaling():
  results = {
      'train': {
          '1': {'steps_per_s': 100.0},
          '2': {'steps_per_s': 150.0},
          '2_weak': {'steps_per_s': 190.0},
      },
      'raw': {'1': {'steps_per_s': 10.0}, '2': None},  # a failed run
  }
  summary = scaling.summarize(results, 2, ['strong', 'weak'])
  assert [(r['part'], r['scaling'], r['efficiency']) for r in summary] == [
      ('train', 'strong', 0.75),
      ('train', 'weak', 0.95),
  ]
  one_device = scaling.summarize(
      {'raw': {'1': {'steps_per_s': 10.0}}}, 1, ['weak']
  )
  assert one_device[0]['efficiency'] == 1.0


def test_runs_are_one_device_then_all_devices_per_scaling():
  both = types.SimpleNamespace(scaling=['strong', 'weak'])
  assert scaling._runs(4, both) == {'1': (1, 1), '4': (4, 1), '4_weak': (4, 4)}
  # With one device there is nothing to scale to.
  assert scaling._runs(1, both) == {'1': (1, 1)}


def _trace(kernels):
  """Perfetto events: two device rows and a host row, and `kernels`, each
  `(pid, tid, start, duration)`."""
  names = {1: '/device:GPU:0', 2: '/device:GPU:1', 3: '/host:CPU'}
  events = [
      {'ph': 'M', 'name': 'process_name', 'pid': pid, 'args': {'name': n}}
      for pid, n in names.items()
  ]
  for pid, tid, start, duration in kernels:
    events.append(
        {'ph': 'X', 'pid': pid, 'tid': tid, 'ts': start, 'dur': duration}
    )
  return events


def test_a_devices_busy_time_counts_overlapping_kernels_once():
  busy = scaling.device_busy(
      _trace(
          [
              # GPU 0: two streams overlap on [5, 10), then a gap, then [20, 30)
              # holding a kernel nested inside another.
              (1, 7, 0.0, 10.0),
              (1, 8, 5.0, 10.0),
              (1, 7, 20.0, 10.0),
              (1, 8, 22.0, 3.0),
              # GPU 1: back to back.
              (2, 7, 100.0, 4.0),
              (2, 7, 104.0, 4.0),
              # The host's events are not a device's.
              (3, 1, 0.0, 1000.0),
          ]
      )
  )
  assert busy == {
      '/device:GPU:0': {'busy_us': 25.0, 'kernels': 4, 'span_us': 30.0},
      '/device:GPU:1': {'busy_us': 8.0, 'kernels': 2, 'span_us': 8.0},
  }
  assert scaling.device_busy(_trace([(3, 1, 0.0, 5.0)])) == {}


def test_the_summary_holds_the_least_busy_devices_fraction():
  def profiled(*fractions):
    return {
        'devices': {
            f'/device:GPU:{i}': {'busy_fraction': f}
            for i, f in enumerate(fractions)
        }
    }

  results = {
      'raw': {
          '1': {'steps_per_s': 100.0, 'profile': profiled(0.9)},
          '2': {'steps_per_s': 180.0, 'profile': profiled(0.8, 0.7)},
      },
      'ppo': {'1': {'steps_per_s': 10.0}, '2': {'steps_per_s': 20.0}},
  }
  raw, ppo = scaling.summarize(results, 2, ['strong'])
  assert raw['busy_fraction_one_device'] == 0.9
  assert raw['busy_fraction_all_devices'] == 0.7
  assert raw['efficiency'] == pytest.approx(0.9)
  assert 'busy_fraction_one_device' not in ppo
