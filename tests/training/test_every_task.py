"""Every bundled task trains, plays with its own camera and exports, on the CPU.

Each registered task goes through the commands a user runs, with tiny
settings (four worlds, one update of one minibatch of two-step rollouts, two
evaluations, episodes of a few control steps, networks of four units):
`mjx-composer train`, `play` (whose video must be drawn from the camera the
task's registry entry names, and whose states must hold the metrics the
entry names) and `export` (whose ONNX policy must give the JAX policy's
actions). The time goes to compiling each task's programs (Brax's training
and evaluation programs, play's two rollouts): `--durations` reports it per
task.
"""

import json
import os

import jax
import mujoco
import numpy as np
import pytest

from mjx_composer import cli
from mjx_composer.host import rendering
from mjx_composer.suite.tasks import registry
from mjx_composer.training import checkpoints
from mjx_composer.training import export as export_lib
from mjx_composer.training import policy as policy_lib
from mjx_composer.training import run_folder
from mjx_composer.training import video

# Steps per training update: 4 worlds x 2 steps x 1 minibatch; one update.
_TINY = [
    '--num-timesteps', '8', '--num-envs', '4', '--batch-size', '4',
    '--num-minibatches', '1', '--unroll-length', '2',
    '--num-updates-per-batch', '1', '--num-evals', '2',
    '--num-eval-envs', '2', '--time-limit', '0.06',
    '--policy-layers', '4', '--value-layers', '4',
    '--video-size', '48', '64', '--no-tensorboard',
]  # fmt: skip


def _mean_error(a, b):
  return float(np.mean(np.abs(np.asarray(a, float) - np.asarray(b, float))))


@pytest.mark.parametrize('task', registry.names())
def test_trains_plays_with_its_camera_and_exports(
    task, tmp_path, monkeypatch, capsys
):
  import onnxruntime  # pylint: disable=g-import-not-at-top

  path = str(tmp_path / task)
  assert cli.main(['train', task, '--run-dir', path, *_TINY]) == 0
  run = run_folder.RunFolder(path)
  checkpoint = checkpoints.latest(run)
  assert checkpoint.step == 8

  # Play, its renderers recorded: from where they drew, and what.
  renders = []

  class RecordingRenderer(rendering.WorldRenderer):

    def __init__(self, env, height, width, **kwargs):
      super().__init__(env, height, width, **kwargs)
      self._record = (env, dict(height=height, width=width, **kwargs))

    def render(self, state, *args, **kwargs):
      renders.append((self._record[0], state, self._record[1]))
      return super().render(state, *args, **kwargs)

  monkeypatch.setattr(rendering, 'WorldRenderer', RecordingRenderer)
  out = str(tmp_path / 'videos')
  argv = ['play', path, '--worlds', '1', '--steps', '2', '--out', out]
  assert cli.main(argv) == 0
  capsys.readouterr()
  played = video.read_mp4(
      os.path.join(out, f'play_deterministic_step_{checkpoint.step:012d}.mp4')
  )
  assert played.shape[0] == 3  # the reset and 2 steps
  env, state, kwargs = renders[0]  # the deterministic video's first frame
  entry = registry.entry(task)
  with open(os.path.join(out, f'play_step_{checkpoint.step:012d}.json')) as f:
    reported = json.load(f)['modes']['deterministic']['metrics']
  assert set(entry.metrics) <= set(reported), sorted(reported)
  if entry.camera is None:
    own = video.FREE_CAMERA
    other = dict(own, azimuth=own['azimuth'] + 90.0)
  else:
    camera_id = mujoco.mj_name2id(
        env.mj_model, mujoco.mjtObj.mjOBJ_CAMERA, entry.camera
    )
    assert camera_id >= 0, f'{task}: the model has no camera {entry.camera!r}'
    own, other = entry.camera, video.FREE_CAMERA
  assert all(k['camera'] == own for _, _, k in renders)
  # The video's first frame is the recorded state seen from that camera
  # (within H.264's loss), not from another.
  errors = [
      _mean_error(
          played[0], rendering.render(env, state, **{**kwargs, 'camera': c})[0]
      )
      for c in (own, other)
  ]
  assert errors[0] < 8.0 and errors[0] < errors[1] / 3, errors

  onnx_path = str(tmp_path / 'policy.onnx')
  assert cli.main(['export', path, '--out', onnx_path]) == 0
  meta = export_lib.read_metadata(onnx_path)
  assert meta['task'] == task
  config = run.read_config()
  obs = (
      np.random.default_rng(0)
      .normal(size=(3, meta['observation_size']))
      .astype(np.float32)
  )
  policy = policy_lib.make_inference(config, checkpoint)(
      checkpoint.params, deterministic=True
  )
  want = np.asarray(policy({'policy': obs}, jax.random.PRNGKey(0))[0])
  session = onnxruntime.InferenceSession(onnx_path)
  got = session.run(['action'], {'obs': obs})[0]
  np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)
