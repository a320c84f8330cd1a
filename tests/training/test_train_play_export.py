"""`mjx-composer train|play|export` on the CPU: one tiny run, resumed.

The task is the tests' pendulum swing, registered as 'swing' for this
module: the commands are the same for every registered task, and the
pendulum compiles in seconds where a bundled robot takes minutes. One
module-scoped run folder (tiny networks, four worlds, one update per
evaluation) is trained for three evaluations, then resumed for one more;
the tests read it, play it, export it and break copies of it.
"""

import contextlib
import io
import json
import os
import shutil
import socket
import subprocess
import sys
import time

from brax.training.agents.ppo import train as ppo_train
import jax
import numpy as np
import pytest

from mjx_composer import cli
from mjx_composer.observation import groups as groups_lib
from mjx_composer.suite.tasks import registry
from mjx_composer.training import checkpoints
from mjx_composer.training import export as export_lib
from mjx_composer.training import policy as policy_lib
from mjx_composer.training import run_folder
from mjx_composer.training import trainer
from mjx_composer.training import video
from tests import conftest

# 4 worlds x 5 steps x 2 minibatches of 4... : 40 env steps per update, one
# update per evaluation; episodes of 5 control steps (0.05 s).
_STEPS_PER_EVAL = 40
_TINY = [
    '--num-envs', '4', '--batch-size', '4', '--num-minibatches', '2',
    '--unroll-length', '5', '--num-updates-per-batch', '1',
    '--num-evals', '4', '--num-eval-envs', '2', '--time-limit', '0.05',
    '--policy-layers', '8', '--value-layers', '8',
    '--video-every', '2', '--video-worlds', '2', '--video-steps', '6',
    '--video-size', '32', '48',
]  # fmt: skip
_NO_VIDEO = _TINY[: _TINY.index('--video-every')]


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


def _train(argv):
  """`(exit code, what it printed)` of `mjx-composer` with `argv`."""
  out = io.StringIO()
  with contextlib.redirect_stdout(out):
    code = cli.main(argv)
  return code, out.getvalue()


def _summary(path):
  with open(os.path.join(path, 'summary.json')) as f:
    return json.load(f)


@pytest.fixture(scope='module')
def trained(tmp_path_factory):
  """A run trained to step 120, then resumed to 160 with a target return.

  The resumed `ppo.train` is watched: the parameters it was handed and
  those it started training from.
  """
  path = str(tmp_path_factory.mktemp('runs') / 'swing')
  argv = ['train', 'swing', '--run-dir', path, '--num-timesteps', '120']
  code, first_out = _train(argv + _TINY)
  assert code == 0, first_out
  first = checkpoints.latest(run_folder.RunFolder(path))
  first_rows = trainer.read_csv(os.path.join(path, 'metrics.csv'))
  first_summary = _summary(path)
  # The best return so far: the first evaluation reaching it is known.
  target = max(r['eval_return'] for r in first_rows)
  seen = {}
  real_train = ppo_train.train

  def watched_train(**kwargs):
    seen['restore_params'] = kwargs['restore_params']
    keep = kwargs['policy_params_fn']

    def policy_params_fn(step, make_policy, params):
      if step == 0:
        seen['start_params'] = jax.device_get(params)
      keep(step, make_policy, params)

    return real_train(**{**kwargs, 'policy_params_fn': policy_params_fn})

  with pytest.MonkeyPatch.context() as patch:
    patch.setattr(ppo_train, 'train', watched_train)
    code, resumed_out = _train([
        'train', '--resume', path, '--num-timesteps', '160',
        '--target-return', repr(target),
    ])  # fmt: skip
  assert code == 0, resumed_out
  return dict(
      path=path,
      first=first,
      first_rows=first_rows,
      first_summary=first_summary,
      first_out=first_out,
      resumed_out=resumed_out,
      target=target,
      seen=seen,
  )


def test_the_run_folder_holds_everything(trained):
  path, first_summary = trained['path'], trained['first_summary']
  run = run_folder.RunFolder(path)
  config = run.read_config()
  assert config.task == 'swing' and config.num_timesteps == 160
  assert config.policy_layers == (8,) and config.num_envs == 4
  assert config.target_return == trained['target']
  assert os.listdir(run.events_dir)  # TensorBoard event files
  # A video every 2 evaluations: after the second (step 80) only.
  assert first_summary['videos'] == [
      os.path.join(run.video_dir, f'eval_step_{80:012d}.mp4')
  ]
  frames = video.read_mp4(first_summary['videos'][0])
  # 6 steps after the reset; 2 worlds of 32 x 48 side by side, 2 px apart.
  assert frames.shape == (7, 32, 98, 3)
  summary = _summary(path)
  assert summary['steps'] == 160 and summary['resumed_from_step'] == 120
  assert summary['checkpoints'] == checkpoints.paths(run)


def test_only_the_latest_and_the_best_checkpoints_are_kept(trained):
  run = run_folder.RunFolder(trained['path'])
  rows = trainer.read_csv(run.metrics_csv)
  returns = {r['step']: r['eval_return'] for r in rows if r['step']}
  best = max(returns, key=returns.get)
  kept = [checkpoints.read(p) for p in checkpoints.paths(run)]
  assert [c.step for c in kept] == sorted({best, 160})
  # Nothing else is left: no older checkpoint, no half-written one.
  assert sorted(os.listdir(run.checkpoint_dir)) == [
      f'{s:012d}' for s in sorted({best, 160})
  ]
  for c in kept:
    assert c.eval_return == returns[c.step]
    assert (c.task, c.steps_per_evaluation) == ('swing', _STEPS_PER_EVAL)
    assert c.evaluations == c.step // _STEPS_PER_EVAL
  # Brax's own loader reads the parameters too.
  from brax.training.agents.ppo import checkpoint as brax_checkpoint  # pylint: disable=g-import-not-at-top

  latest = checkpoints.latest(run)
  by_brax = brax_checkpoint.load(checkpoints.path_for(run, 160))
  for a, b in zip(jax.tree.leaves(latest.params), jax.tree.leaves(by_brax)):
    np.testing.assert_array_equal(a, b)


def test_resume_continues_the_step_count_schedule_and_parameters(trained):
  run = run_folder.RunFolder(trained['path'])
  first, seen = trained['first'], trained['seen']
  rows = trainer.read_csv(run.metrics_csv)
  # The step-0 evaluation, one per update, and the resumed one at 160; the
  # resumed run's evaluation of the restored policy is not repeated.
  assert [r['step'] for r in rows] == [0, 40, 80, 120, 160]
  assert first.step == 120 and trained['first_summary']['steps'] == 120
  last = checkpoints.latest(run)
  assert (last.step, last.evaluations) == (160, 4)
  assert 'Resuming' in trained['resumed_out']
  assert 'at step 120 (3 evaluations done, 1 to go' in trained['resumed_out']
  # Brax was handed the saved parameters and started training from them.
  for got in (seen['restore_params'], seen['start_params']):
    leaves = jax.tree.leaves(got)
    assert len(leaves) == len(jax.tree.leaves(first.params))
    for a, b in zip(leaves, jax.tree.leaves(first.params)):
      np.testing.assert_array_equal(np.asarray(a), b)
  moved = [
      not np.array_equal(a, b)
      for a, b in zip(
          jax.tree.leaves(first.params), jax.tree.leaves(last.params)
      )
  ]
  assert any(moved)  # the resumed run trained the restored parameters


def test_progress_says_what_compiles_and_when_it_ends(trained):
  out = trained['first_out']
  compiling = out.index('Compiling the evaluation before the first')
  lines = [l for l in out.splitlines() if l.startswith('step ')]
  assert compiling < out.index(lines[0])
  # Brax compiles the training step after the first evaluation.
  training = out.index('Compiling the training step before the first epoch')
  assert out.index(lines[0]) < training < out.index(lines[1])
  assert 'nan' not in out.lower()
  # The ETA comes from the training rate after the first epoch (whose time
  # holds the compile): at step 80, from the epoch 40 -> 80.
  rows = {r['step']: r for r in trained['first_rows']}
  eta = (
      (120 - 80)
      * (rows[80]['train_walltime_s'] - rows[40]['train_walltime_s'])
      / (80 - 40)
  )
  by_step = {int(l.split()[1].replace(',', '')): l for l in lines}
  assert sorted(by_step) == [0, 40, 80, 120]
  assert by_step[80].endswith(f'ETA {eta:,.0f}s')
  assert all('ETA' not in by_step[s] for s in (0, 40, 120))


def test_the_time_to_the_target_return_is_reported(trained):
  target = trained['target']
  rows = trainer.read_csv(os.path.join(trained['path'], 'metrics.csv'))
  hit = next(r for r in rows if r['eval_return'] >= target)
  summary = _summary(trained['path'])
  assert summary['target_return'] == target
  assert summary['target_step'] == hit['step']
  assert summary['time_to_target_s'] == hit['wall_s']
  assert summary['train_time_to_target_s'] == hit['train_walltime_s']
  assert f'Return {target:g} reached at step {hit["step"]:,}, ' in (
      trained['resumed_out']
  )


def test_export_matches_the_jax_policy_in_onnxruntime(trained, tmp_path):
  import onnxruntime  # pylint: disable=g-import-not-at-top

  path = trained['path']
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
  assert meta['step'] == 160 and meta['task'] == 'swing'
  assert meta['default_joint_positions'] is None  # no home pose


def test_corrupted_run_folders_are_refused(trained, tmp_path, capsys):
  path = trained['path']
  copy = str(tmp_path / 'copy')
  shutil.copytree(path, copy)
  run = run_folder.RunFolder(copy)
  newest = checkpoints.paths(run)[-1]
  # A write interrupted before the checkpoint was complete: not picked up.
  shutil.copytree(newest, checkpoints.path_for(run, 200))
  os.remove(os.path.join(checkpoints.path_for(run, 200), checkpoints.INFO))
  assert checkpoints.latest(run).step == 160
  # Parameters or information unreadable: refused, saying what to do.
  os.remove(os.path.join(newest, '_METADATA'))  # orbax's tree of the params
  assert cli.main(['export', copy]) == 2
  assert 'is corrupted and cannot be read' in capsys.readouterr().err
  with open(os.path.join(newest, checkpoints.INFO), 'r+') as f:
    f.truncate(10)
  assert cli.main(['play', copy]) == 2
  assert 'is corrupted and cannot be read' in capsys.readouterr().err
  with open(os.path.join(copy, 'config.json'), 'w') as f:
    f.write('{"task": "reach", "num_envs": ')
  assert cli.main(['play', copy]) == 2
  assert 'config.json could not be read' in capsys.readouterr().err
  assert cli.main(['train', '--resume', str(tmp_path / 'nothing')]) == 2
  assert 'No run folder at' in capsys.readouterr().err


def test_mismatched_run_folders_are_refused(trained, tmp_path, capsys):
  path = trained['path']
  assert cli.main(['train', 'push', '--resume', path]) == 2
  assert "trains task 'swing', not 'push'" in capsys.readouterr().err
  assert cli.main(['train', '--resume', path, '--learning-rate', '1']) == 2
  assert "['learning_rate'] differ" in capsys.readouterr().err
  # A checkpoint whose networks no longer fit the task's observations.
  copy = str(tmp_path / 'copy')
  shutil.copytree(path, copy)
  info = os.path.join(
      checkpoints.paths(run_folder.RunFolder(copy))[-1], 'checkpoint.json'
  )
  with open(info) as f:
    saved = json.load(f)
  saved['observation_size'] = {'policy': [5], 'critic': [7]}
  with open(info, 'w') as f:
    json.dump(saved, f)
  assert cli.main(['play', copy, '--no-video']) == 2
  err = capsys.readouterr().err
  assert 'incompatible with task' in err and "'policy': (5,)" in err


def test_a_run_stopped_before_its_first_evaluation_trains_again(
    tmp_path, capsys
):
  """No checkpoint: `--resume` trains it from step 0, its metrics cleared;
  training into its folder anew, or playing it, says to resume it."""
  path = str(tmp_path / 'swing')
  argv = ['swing', '--run-dir', path, '--num-timesteps', '40']
  argv += _NO_VIDEO + ['--no-tensorboard']
  argv[argv.index('--num-evals') + 1] = '2'  # one epoch of 40 steps
  assert cli.resolve_train_config(argv)[0].num_evals == 2
  with open(os.path.join(path, 'metrics.csv'), 'w') as f:
    f.write('step,wall_s\n7,1.0\n')  # an evaluation of the stopped run
  assert cli.main(['train'] + argv) == 2
  assert f'continue it with --resume {path}' in capsys.readouterr().err
  assert cli.main(['play', path]) == 2
  assert f'again from step 0 with --resume {path}' in capsys.readouterr().err
  code, out = _train(['train', '--resume', path, '--target-return', '1e9'])
  assert code == 0, out
  assert (
      'has no checkpoint (it stopped before its first evaluation): '
      'training it again from step 0.' in out
  )
  rows = trainer.read_csv(os.path.join(path, 'metrics.csv'))
  assert [r['step'] for r in rows] == [0, 40]
  assert checkpoints.latest(run_folder.RunFolder(path)).step == 40
  summary = _summary(path)
  assert summary['resumed_from_step'] is None
  assert summary['target_step'] is summary['time_to_target_s'] is None
  assert 'Return 1e+09 not reached.' in out


def test_settings_come_from_defaults_file_and_flags(tmp_path):
  settings = tmp_path / 'settings.yaml'
  settings.write_text('learning_rate: 0.01\npolicy_layers: [16, 16]\n')
  config, run, resume = cli.resolve_train_config([
      'walk', '--run-dir', str(tmp_path / 'walk'), '--config', str(settings),
      '--policy-layers', '4',
  ])  # fmt: skip
  assert not resume
  walk = registry.entry('walk').training
  assert config.learning_rate == 0.01  # the file over the task's default
  assert config.policy_layers == (4,)  # the flag over the file
  assert config.discounting == walk['discounting']  # the task's default
  assert config.value_layers == tuple(walk['value_layers'])
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
  assert cli.main(['train', 'reach', '--process-id', '1']) == 2
  assert 'join a distributed run: pass --distributed too' in (
      capsys.readouterr().err
  )
  jax.devices()  # JAX started: too late to join processes
  assert cli.main(['train', 'reach', '--distributed']) == 2
  err = capsys.readouterr().err
  assert '--distributed could not join the processes' in err
  assert '--coordinator HOST:PORT --num-processes N --process-id I' in err


# One training process, as each host of a cluster runs it: the swing task
# registered, then the command line.
_WORKER = """
import sys
from mjx_composer import cli
from mjx_composer.suite.tasks import registry
from tests.training import test_train_play_export as module
registry.register('swing', module._Swing)
sys.exit(cli.main(sys.argv[1:]))
"""


def _free_port() -> int:
  with socket.socket() as s:
    s.bind(('localhost', 0))
    return s.getsockname()[1]


def _run_processes(script, argv, tmp_path, attempts=3):
  """Runs `script argv --distributed ...` as processes 0 and 1 of 2.

  Process 0 binds the coordinator's port: where another program took the
  free port first, it fails to start its server, and both start again on
  another port.

  Returns:
    Each process's exit code and output.
  """
  root = os.path.dirname(
      os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
  )
  path = os.pathsep.join(
      [root] + os.environ.get('PYTHONPATH', '').split(os.pathsep)
  )
  env = dict(os.environ, PYTHONPATH=path, JAX_PLATFORMS='cpu')
  for _ in range(attempts):
    port, processes, logs = _free_port(), [], []
    for i in range(2):
      logs.append(open(tmp_path / f'process_{i}.log', 'w+'))
      flags = ['--distributed', '--coordinator', f'localhost:{port}']
      flags += ['--num-processes', '2', '--process-id', str(i)]
      processes.append(
          subprocess.Popen(
              [sys.executable, str(script)] + argv + flags,
              env=env,
              stdout=logs[-1],
              stderr=subprocess.STDOUT,
          )
      )
    deadline = time.monotonic() + 1200
    while time.monotonic() < deadline and None in [p.poll() for p in processes]:
      if processes[0].poll() not in (None, 0):
        break  # process 0 failed: process 1 would wait for it
      time.sleep(0.5)
    for p in processes:
      if p.poll() is None:
        p.kill()
      p.wait()
    outputs = []
    for log in logs:
      log.seek(0)
      outputs.append(log.read())
      log.close()
    if 'Failed to start RPC server' not in outputs[0]:
      break
  return [p.returncode for p in processes], outputs


def test_distributed_processes_train_one_run(tmp_path):
  """`--distributed`: two CPU processes joined by `jax.distributed`, one
  command each as on two hosts; process 0 writes the run folder."""
  path = str(tmp_path / 'swing')
  script = tmp_path / 'worker.py'
  script.write_text(_WORKER)
  argv = ['train', 'swing', '--run-dir', path, '--num-timesteps', '40']
  argv += _NO_VIDEO + ['--no-tensorboard']
  argv[argv.index('--num-evals') + 1] = '2'  # one epoch of 40 steps
  codes, outputs = _run_processes(script, argv, tmp_path)
  assert codes == [0, 0], '\n\n'.join(outputs)
  assert 'in each of 2 processes (this is process 1)' in outputs[1]
  assert 'Trained' not in outputs[1]  # process 0 reports
  summary = _summary(path)
  assert (summary['processes'], summary['devices']) == (2, 1)
  # Brax's step count is of both processes' worlds: 4 worlds, 2 in each.
  assert summary['steps'] == 40
  rows = trainer.read_csv(os.path.join(path, 'metrics.csv'))
  assert [r['step'] for r in rows] == [0, 40]  # written once
  last = checkpoints.latest(run_folder.RunFolder(path))
  assert (last.step, last.evaluations) == (40, 1)
  assert all(np.isfinite(x).all() for x in jax.tree.leaves(last.params))
