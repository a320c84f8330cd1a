"""`mjx-composer play` on the CPU, and the video pieces it is made of.

The task is the tests' pendulum swing with a metric (the tip's height),
registered as 'swing_metric' for this module: it compiles in seconds where a
bundled robot takes minutes. One module-scoped run folder is trained for
one tiny update, then played.
"""

import contextlib
import io
import json
import os
import subprocess
import warnings

import imageio.v2 as imageio
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_composer import cli
from mjx_composer.observation import groups as groups_lib
from mjx_composer.suite.tasks import registry
from mjx_composer.training import checkpoints
from mjx_composer.training import policy as policy_lib
from mjx_composer.training import run_folder
from mjx_composer.training import video
from tests import conftest

_TASK = 'swing_metric'
# 4 worlds x 5 steps x 2 minibatches: 40 env steps per update; episodes of
# 5 control steps (0.05 s).
_TINY = [
    '--num-envs', '4', '--batch-size', '4', '--num-minibatches', '2',
    '--unroll-length', '5', '--num-updates-per-batch', '1',
    '--num-evals', '1', '--num-eval-envs', '2', '--time-limit', '0.05',
    '--policy-layers', '8', '--value-layers', '8',
    '--video-size', '32', '48',
]  # fmt: skip
_PLAY = ['--worlds', '2', '--steps', '6']
_FORK_WARNING = 'os.fork() was called'


class _Swing(conftest.SwingTask):
  """The swing task with training's observation groups and a metric."""

  def observation_groups(self):
    return {
        'policy': groups_lib.ObservationGroup(keys=['tip'], flatten=True),
        'critic': groups_lib.ObservationGroup(
            keys=['tip'], corrupted=False, flatten=True
        ),
    }

  def get_metrics(self, physics):
    return {'tip_height': physics.bind(self.pendulum.tip).xpos[2]}


@pytest.fixture(scope='module', autouse=True)
def swing():
  registry.register(_TASK, _Swing, description='The tests pendulum.')
  yield
  registry.unregister(_TASK)


@pytest.fixture(scope='module')
def trained(tmp_path_factory):
  """The path of a run trained for one update (step 40)."""
  path = str(tmp_path_factory.mktemp('runs') / 'swing')
  argv = ['train', _TASK, '--run-dir', path, '--num-timesteps', '40']
  assert cli.main(argv + _TINY) == 0
  return path


@pytest.fixture(scope='module')
def played(trained, tmp_path_factory):
  """`(out folder, printed output, lowerings of the rollout program)`."""
  out = str(tmp_path_factory.mktemp('play'))
  lowerings = []

  def record(event, unused_duration, fun_name=None, **unused_kwargs):
    if event == '/jax/core/compile/jaxpr_to_mlir_module_duration':
      lowerings.append(fun_name)

  jax.monitoring.register_event_duration_secs_listener(record)
  printed = io.StringIO()
  try:
    with contextlib.redirect_stdout(printed):
      assert cli.main(['play', trained, '--out', out] + _PLAY) == 0
  finally:
    jax.monitoring.unregister_event_duration_listener(record)
  return out, printed.getvalue(), lowerings


def test_play_writes_videos_and_episode_statistics(played):
  out, printed, _ = played
  for mode in ('deterministic', 'sampled'):
    # 6 steps of 5-step episodes: each of the 2 worlds ends one episode.
    assert f'{mode:<14} step 40: 2 episodes ended' in printed
    frames = video.read_mp4(
        os.path.join(out, f'play_{mode}_step_{40:012d}.mp4')
    )
    # The reset and 6 steps; 2 worlds of 32 x 48 side by side, 2 px apart.
    assert frames.shape == (7, 32, 98, 3)
    assert frames.std() > 0  # a picture, not a blank frame
  assert 'mean length 5.0 steps' in printed
  # Zero actions is a baseline for the numbers: no video of it.
  assert not [name for name in os.listdir(out) if 'zero' in name]


def test_the_three_runs_are_one_compiled_program(played):
  _, _, lowerings = played
  assert lowerings.count('jit(policy_rollout)') == 1


def test_play_says_what_it_compiles_and_how_rendering_goes(played):
  _, printed, _ = played
  assert 'Building the rollout program of 2 worlds x 6 steps' in printed
  assert 'Built the program and ran the deterministic rollout' in printed
  for mode in ('deterministic', 'sampled'):
    assert f'rendering {mode}' in printed
  assert '7/7' in printed  # frames done / total
  # The metrics table: one column per run.
  assert 'deterministic' in printed.split('Metrics')[1]
  assert 'tip_height' in printed


@pytest.fixture(scope='module')
def rollouts(trained):
  """`({mode: video.make_rollout's outputs}, make_policy, params)`.

  With play's worlds, steps and seed.
  """
  run = run_folder.open_run(trained)
  config = run.read_config()
  checkpoint = checkpoints.latest(run)
  _, brax_env = policy_lib.make_environment(config)
  make_policy = policy_lib.make_inference(config, checkpoint)
  program = video.make_rollout(brax_env, make_policy, 2, 6)
  outputs = {
      mode: jax.device_get(
          program(
              checkpoint.params, jax.random.PRNGKey(1), video.mode_index(mode)
          )
      )
      for mode in video.MODES
  }
  return outputs, make_policy, checkpoint.params


def _tip_site():
  model = registry.make_environment(_TASK).mj_model
  (site,) = [
      i for i in range(model.nsite) if model.site(i).name.endswith('tip')
  ]
  return site


def test_metrics_json_and_the_zero_action_baseline(rollouts, played):
  out, _, _ = played
  with open(video.json_path(out, 40)) as f:
    written = json.load(f)
  assert (written['worlds'], written['steps'], written['seed']) == (2, 6, 1)
  assert list(written['modes']) == ['deterministic', 'sampled', 'zero']
  for mode, stats in written['modes'].items():
    states, rewards, dones, metrics, _ = rollouts[0][mode]
    # Each step's metric is the tip site's height in the state it stepped
    # to (an independent reference), except where an episode ended: there
    # the state is the next episode's first.
    heights = np.asarray(states.data.site_xpos)[1:, :, _tip_site(), 2]
    running = ~(np.asarray(dones) > 0)
    np.testing.assert_allclose(
        metrics['tip_height'][running], heights[running], rtol=1e-5
    )
    # Written: the mean over both worlds and all 6 steps.
    assert metrics['tip_height'].shape == (6, 2)
    assert stats['metrics']['tip_height'] == pytest.approx(
        np.mean(metrics['tip_height']), rel=1e-6
    )
    assert stats['metrics']['reward'] == pytest.approx(np.mean(rewards))
    assert stats['episodes'] == int(np.sum(dones)) == 2
  # Every run starts from the same reset.
  first = [rollouts[0][m][0].data.qpos[0] for m in video.MODES]
  np.testing.assert_array_equal(first[0], first[1])
  np.testing.assert_array_equal(first[0], first[2])
  metrics = {m: s['metrics'] for m, s in written['modes'].items()}
  assert metrics['zero']['tip_height'] != metrics['deterministic']['tip_height']


def test_each_mode_takes_its_actions(rollouts):
  """The control each step applied: zeros, the policy's mode, a sample."""
  outputs, make_policy, params = rollouts
  for mode in video.MODES:
    states, _, dones, _, observations = outputs[mode]
    ctrl = np.asarray(states.data.ctrl)[1:]  # after each step
    running = ~(np.asarray(dones) > 0)  # a restart resets the controls
    deterministic = np.asarray(
        jax.vmap(make_policy(params, deterministic=True), in_axes=(0, None))(
            observations, jax.random.PRNGKey(0)
        )[0]
    )
    if mode == 'zero':
      np.testing.assert_array_equal(ctrl[running], 0.0)
    elif mode == 'deterministic':
      np.testing.assert_allclose(
          ctrl[running], deterministic[running], atol=1e-6
      )
    else:
      assert np.all(np.abs(ctrl[running] - deterministic[running]) > 1e-6)


def test_no_video_writes_statistics_and_metrics_only(trained, tmp_path, capsys):
  out = str(tmp_path)
  assert cli.main(['play', trained, '--out', out, '--no-video'] + _PLAY) == 0
  assert os.listdir(out) == [os.path.basename(video.json_path(out, 40))]
  printed = capsys.readouterr().out
  assert 'rendering' not in printed and 'tip_height' in printed


def test_bad_play_arguments_are_refused(trained, capsys):
  assert cli.main(['play', trained, '--worlds', '0']) == 2
  assert '--worlds must be at least 1' in capsys.readouterr().err
  assert cli.main(['play', trained, '--steps', '0']) == 2
  assert '--steps must be at least 1' in capsys.readouterr().err


def _gradient_frames(count, height, width):
  """Smooth frames (H.264 keeps them to a few levels), one per brightness."""
  ramp = np.linspace(0, 200, width)[None, :, None]
  frames = np.stack(
      [np.broadcast_to(ramp + 5 * i, (height, width, 3)) for i in range(count)]
  )
  return frames.astype(np.uint8)


def test_write_mp4_does_not_fork_a_jax_process(tmp_path):
  jnp.ones(2).block_until_ready()  # JAX's backend (and fork hook) is up
  with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter('always')
    # The hook is armed: a fork through a preexec_fn (imageio's writer's)
    # warns.
    subprocess.run(['true'], preexec_fn=lambda: None, check=True)
  assert any(_FORK_WARNING in str(w.message) for w in caught)

  frames = _gradient_frames(9, 24, 40)
  path = str(tmp_path / 'clip.mp4')
  with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter('always')
    assert video.write_mp4(path, frames, fps=25) == path
  assert not [w for w in caught if _FORK_WARNING in str(w.message)]
  # imageio's reader, an independent decoder, sees the frames written.
  with warnings.catch_warnings():
    warnings.simplefilter('ignore')  # imageio's reader forks
    decoded = np.stack(imageio.mimread(path, memtest=False))
  assert decoded.shape == frames.shape
  assert np.abs(decoded.astype(int) - frames).max() <= 8
  np.testing.assert_array_equal(video.read_mp4(path), decoded)


def test_write_mp4_refuses_frames_h264_cannot_hold(tmp_path):
  path = str(tmp_path / 'clip.mp4')
  with pytest.raises(ValueError, match='even height and width'):
    video.write_mp4(path, np.zeros((2, 25, 40, 3), np.uint8), fps=25)
  with pytest.raises(ValueError, match=r'\(T, H, W, 3\)'):
    video.write_mp4(path, np.zeros((24, 40, 3), np.uint8), fps=25)
  assert not os.path.exists(path)
