"""`mjx-composer train|play|export` on the CPU: one tiny run, resumed.

The task is the tests' pendulum swing, registered as 'swing' for this
module: the commands are the same for every registered task, and the
pendulum compiles in seconds where a bundled robot takes minutes. One
module-scoped run folder (tiny networks, four worlds, one update per
evaluation) is trained for two evaluations, then resumed for one more; the
tests read it, play it, export it and break copies of it.
"""

import json
import os
import shutil

import jax
import numpy as np
import pytest

from mjx_composer import cli
from mjx_composer.observation import groups as groups_lib
from mjx_composer.suite.tasks import registry
from mjx_composer.training import checkpoints
from mjx_composer.training import config as config_lib
from mjx_composer.training import export as export_lib
from mjx_composer.training import metrics as metrics_lib
from mjx_composer.training import policy as policy_lib
from mjx_composer.training import run_folder
from mjx_composer.training import video
from tests import conftest

# 4 worlds x 5 steps x 2 minibatches of 4... : 40 env steps per update, one
# update per evaluation; episodes of 5 control steps (0.05 s).
_STEPS_PER_EVAL = 40
_TINY = [
    '--num-envs', '4', '--batch-size', '4', '--num-minibatches', '2',
    '--unroll-length', '5', '--num-updates-per-batch', '1',
    '--num-evals', '3', '--num-eval-envs', '2', '--time-limit', '0.05',
    '--policy-layers', '8', '--value-layers', '8',
    '--video-every', '2', '--video-worlds', '2', '--video-steps', '6',
    '--video-size', '32', '48',
]  # fmt: skip


class _Swing(conftest.SwingTask):
  """The swing task with the policy and critic groups training reads."""

  def observation_groups(self):
    return {
        'policy': groups_lib.ObservationGroup(keys=['tip'], flatten=True),
        'critic': groups_lib.ObservationGroup(
            keys=['tip'], corrupted=False, flatten=True
        ),
    }


@pytest.fixture(scope='module', autouse=True)
def swing():
  """The 'swing' task, registered while this module's tests run."""
  registry.register('swing', _Swing, description='The tests pendulum.')
  yield
  registry.unregister('swing')


@pytest.fixture(scope='module')
def trained(tmp_path_factory):
  """`(run path, the first part's newest checkpoint)` of a resumed run."""
  path = str(tmp_path_factory.mktemp('runs') / 'swing')
  argv = ['train', 'swing', '--run-dir', path, '--num-timesteps', '80']
  assert cli.main(argv + _TINY) == 0
  first = checkpoints.latest(run_folder.RunFolder(path))
  with open(os.path.join(path, 'summary.json')) as f:
    first_summary = json.load(f)
  assert cli.main(['train', '--resume', path, '--num-timesteps', '120']) == 0
  return path, first, first_summary


def test_the_run_folder_holds_everything(trained):
  path, _, first_summary = trained
  run = run_folder.RunFolder(path)
  config = run.read_config()
  assert config.task == 'swing' and config.num_timesteps == 120
  assert config.policy_layers == (8,) and config.num_envs == 4
  names = [os.path.basename(p) for p in checkpoints.paths(run)]
  assert names == [f'step_{s:012d}.pkl' for s in (40, 80, 120)]
  assert os.listdir(run.events_dir)  # TensorBoard event files
  # A video every 2 evaluations: after the second (step 80) only.
  assert first_summary['videos'] == [
      os.path.join(run.video_dir, f'eval_step_{80:012d}.mp4')
  ]
  frames = video.read_mp4(first_summary['videos'][0])
  # 6 steps after the reset; 2 worlds of 32 x 48 side by side, 2 px apart.
  assert frames.shape == (7, 32, 98, 3)
  with open(run.summary_path) as f:
    summary = json.load(f)
  assert summary['steps'] == 120 and summary['resumed_from_step'] == 80


def test_resume_continues_the_step_count_and_the_optimizer(trained):
  path, first, first_summary = trained
  run = run_folder.RunFolder(path)
  rows = metrics_lib.read_csv(run.metrics_csv)
  # The step-0 evaluation, one per update, and the resumed one at 120; the
  # resumed run's evaluation of the restored policy is not repeated.
  assert [r['step'] for r in rows] == [0, 40, 80, 120]
  assert first.step == 80 and first_summary['steps'] == 80
  last = checkpoints.latest(run)
  assert (last.step, last.evaluations) == (120, 3)
  # Adam's count: 2 minibatch steps per update. Restored, it goes on from 4
  # (a fresh optimizer would be at 2).
  count = lambda c: int(c.optimizer_state[0].count)
  assert (count(first), count(last)) == (4, 6)
  # Brax began from the saved moments exactly (checked in the resumed run).
  with open(run.summary_path) as f:
    assert json.load(f)['optimizer_state_restored'] is True
  moved = [
      not np.array_equal(a, b)
      for a, b in zip(
          jax.tree.leaves(first.params), jax.tree.leaves(last.params)
      )
  ]
  assert any(moved)  # the resumed run trained the restored parameters


def test_export_matches_the_jax_policy_in_onnxruntime(trained, tmp_path):
  import onnxruntime  # pylint: disable=g-import-not-at-top

  path, _, _ = trained
  out = str(tmp_path / 'policy.onnx')
  assert cli.main(['export', path, '--format', 'onnx', '--out', out]) == 0
  run = run_folder.RunFolder(path)
  config = run.read_config()
  checkpoint = checkpoints.latest(run)
  env, brax_env = policy_lib.make_environment(config)
  # Observations recorded from a rollout of the sampled policy (the program
  # `play` ran: loaded from the compilation cache).
  make_policy = policy_lib.make_inference(config, checkpoint)
  observations = video.rollout(
      brax_env, make_policy, checkpoint.params, 2, 6, 5, deterministic=False
  )[-1]
  obs = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), observations)
  policy = make_policy(checkpoint.params, deterministic=True)
  want = np.asarray(policy(obs, jax.random.PRNGKey(0))[0])
  session = onnxruntime.InferenceSession(out)
  got = session.run(['action'], {'obs': np.asarray(obs['policy'])})[0]
  np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)

  meta = export_lib.read_metadata(out)
  group = env.task.observation_groups()['policy']
  assert meta['observation_names'] == list(group.keys)
  sizes = [int(np.prod(s)) for s in meta['observation_shapes']]
  assert sum(sizes) == meta['observation_size'] == obs['policy'].shape[-1]
  assert meta['control_timestep'] == pytest.approx(env.control_timestep())
  assert meta['action_size'] == brax_env.action_size
  assert meta['step'] == 120 and meta['task'] == 'swing'
  assert meta['default_joint_positions'] is None  # no home pose


def test_corrupted_run_folders_are_refused(trained, tmp_path, capsys):
  path, _, _ = trained
  copy = str(tmp_path / 'copy')
  shutil.copytree(path, copy)
  newest = checkpoints.paths(run_folder.RunFolder(copy))[-1]
  with open(newest, 'r+b') as f:
    f.truncate(100)
  assert cli.main(['export', copy]) == 2
  assert 'is corrupted and cannot be read' in capsys.readouterr().err
  with open(os.path.join(copy, 'config.json'), 'w') as f:
    f.write('{"task": "reach", "num_envs": ')
  assert cli.main(['play', copy]) == 2
  assert 'config.json could not be read' in capsys.readouterr().err
  assert cli.main(['train', '--resume', str(tmp_path / 'nothing')]) == 2
  assert 'No run folder at' in capsys.readouterr().err


def test_mismatched_run_folders_are_refused(trained, tmp_path, capsys):
  path, _, _ = trained
  assert cli.main(['train', 'push', '--resume', path]) == 2
  assert "trains task 'swing', not 'push'" in capsys.readouterr().err
  assert cli.main(['train', '--resume', path, '--learning-rate', '1']) == 2
  assert "['learning_rate'] differ" in capsys.readouterr().err
  # A checkpoint whose networks no longer fit the task's observations.
  copy = str(tmp_path / 'copy')
  shutil.copytree(path, copy)
  run = run_folder.RunFolder(copy)
  newest = checkpoints.latest(run)
  newest.observation_size = {'policy': (5,), 'critic': (7,)}
  checkpoints.save(run, newest)
  assert cli.main(['play', copy, '--no-video']) == 2
  err = capsys.readouterr().err
  assert 'incompatible with task' in err and "'policy': (5,)" in err


def test_settings_come_from_defaults_file_and_flags(tmp_path):
  settings = tmp_path / 'settings.yaml'
  settings.write_text('learning_rate: 0.01\npolicy_layers: [16, 16]\n')
  config, run, resume = cli.resolve_train_config([
      'walk', '--run-dir', str(tmp_path / 'walk'), '--config', str(settings),
      '--policy-layers', '4',
  ])  # fmt: skip
  assert not resume
  walk = config_lib.TASK_DEFAULTS['walk']
  assert config.learning_rate == 0.01  # the file over the task's default
  assert config.policy_layers == (4,)  # the flag over the file
  assert config.discounting == walk['discounting']  # the task's default
  assert config.value_layers == walk['value_layers']
  assert run.read_config() == config
  joystick = cli.resolve_train_config(
      ['joystick', '--run-dir', str(tmp_path / 'joystick')]
  )[0]
  assert joystick.critic_obs == 'critic' and joystick.max_grad_norm == 1.0


def test_bad_settings_are_named(tmp_path, capsys):
  settings = tmp_path / 'settings.json'
  settings.write_text('{"learning_rat": 0.01}')
  assert cli.main(['train', 'reach', '--config', str(settings)]) == 2
  assert "unknown setting(s) ['learning_rat']" in capsys.readouterr().err
  assert cli.main(['train', 'no_such_task']) == 2
  assert "Unknown task 'no_such_task'" in capsys.readouterr().err
  argv = ['train', 'reach', '--run-dir', str(tmp_path / 'r'), '--num-envs', '3']
  assert cli.main(argv) == 2
  assert 'must be a multiple of num_envs' in capsys.readouterr().err
  assert not os.path.exists(tmp_path / 'r')  # no folder for a refused run


def test_two_processes_train_one_run(tmp_path):
  """`--processes 2`: two processes on the CPU joined by `jax.distributed`,
  the task sent to them pickled; process 0 writes the run folder."""
  path = str(tmp_path / 'swing')
  no_video = _TINY[: _TINY.index('--video-every')]
  argv = ['train', 'swing', '--run-dir', path, '--num-timesteps', '80']
  assert cli.main(argv + no_video + ['--processes', '2']) == 0
  run = run_folder.RunFolder(path)
  assert run.read_config().processes == 2
  with open(run.summary_path) as f:
    summary = json.load(f)
  assert (summary['processes'], summary['devices']) == (2, 1)
  # Brax's step count is of both processes' worlds: 4 worlds, 2 in each.
  assert summary['steps'] == 80
  rows = metrics_lib.read_csv(run.metrics_csv)
  assert [r['step'] for r in rows] == [0, 40, 80]  # written once
  last = checkpoints.latest(run)
  assert (last.step, last.evaluations) == (80, 2)
  assert all(np.isfinite(x).all() for x in jax.tree.leaves(last.params))
  with open(os.path.join(path, 'logs', 'process_1.log')) as f:
    assert 'in each of 2 processes (this is process 1)' in f.read()


def test_processes_need_an_importable_factory(tmp_path, capsys):
  registry.register('swing_lambda', lambda: _Swing())
  try:
    argv = ['train', 'swing_lambda', '--run-dir', str(tmp_path / 'r')]
    assert cli.main(argv + ['--processes', '2']) == 2
  finally:
    registry.unregister('swing_lambda')
  err = capsys.readouterr().err
  assert "Task 'swing_lambda' cannot be sent to the training processes" in err
  assert 'module-level function or class' in err
