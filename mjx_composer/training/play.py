"""Watching a trained policy: videos, episode statistics and metrics of a run.

`play(run)` loads the run's newest checkpoint and runs it on a few worlds
three times from the same reset, with one compiled program
(`video.make_rollout`): with deterministic actions (the mode of the action
distribution), with sampled actions (what training explored with), and
with zero actions, a baseline of a robot that does nothing. It writes an MP4
of each policy run, the worlds tiled, and returns and writes (as JSON) each
run's episode statistics (episodes that ended, their mean return and
length, the mean reward per step) and the task's metrics (each float entry
of `State.metrics`, e.g. a tracking error, and the reward), averaged over
every world and step, so that a policy's tracking error reads against the
baseline's.
"""

from __future__ import annotations

import json
import os
import sys
import time

import jax
import numpy as np
import tqdm

from mjx_composer.training import checkpoints
from mjx_composer.training import policy as policy_lib
from mjx_composer.training import run_folder
from mjx_composer.training import video

MODES = video.MODES
# The runs that get a video (zero actions is a baseline for the numbers).
VIDEO_MODES = ('deterministic', 'sampled')


def episode_statistics(rewards, dones, metrics) -> dict:
  """Statistics of `video.rollout`'s rewards, dones and metrics."""
  dones = np.asarray(dones) > 0
  ended = int(dones.sum())
  stats = {
      'episodes': ended,
      'mean_reward_per_step': float(np.mean(rewards)),
      'mean_return': None,
      'mean_length': None,
  }
  if ended:
    stats['mean_return'] = float(
        np.asarray(metrics['episode_return'])[dones].mean()
    )
    stats['mean_length'] = float(
        np.asarray(metrics['episode_length'])[dones].mean()
    )
  return stats


def mean_metrics(rewards, metrics) -> dict:
  """Each float `State.metrics` entry and the reward, over worlds and steps.

  Args:
    rewards: `(steps, worlds)` rewards of a rollout.
    metrics: `{name: (steps, worlds)}`, the composer metrics of each step
      (the task's `get_metrics` and the environment's); integer entries
      (episode lengths) are left out.

  Returns:
    `{name: mean}`, with `reward` among them. A world whose episode ends
    continues in its next one (same-step auto-reset), so the means are over
    every step of every world.
  """
  means = {
      name: float(np.mean(value))
      for name, value in metrics.items()
      if np.issubdtype(np.asarray(value).dtype, np.floating)
  }
  means['reward'] = float(np.mean(rewards))
  return means


class _Log:
  """Progress lines on stdout (flushed: they precede long silences)."""

  def __init__(self, verbose: bool):
    self.verbose = verbose

  def __call__(self, message: str):
    if self.verbose:
      print(message, flush=True)

  def frames(self, mode: str, total: int):
    """A `render_rollout` progress callback: frames done / total."""
    if not self.verbose:
      return None
    bar = tqdm.tqdm(
        total=total,
        unit='frame',
        desc=f'rendering {mode}',
        file=sys.stdout,
        mininterval=1.0,
    )

    def progress(done, unused_total):
      bar.update(done - bar.n)
      if done == total:
        bar.close()

    return progress


def play(
    run_path: str,
    worlds: int = 4,
    steps: int | None = None,
    out: str | None = None,
    seed: int = 1,
    size=None,
    render: bool = True,
    verbose: bool = False,
) -> dict:
  """Plays the run's newest policy; returns `{mode: statistics}`.

  Args:
    run_path: the run folder.
    worlds: worlds run and tiled in each video.
    steps: control steps (default: one episode, the task's time limit).
    out: the folder of the videos and the JSON (default: the run's
      `videos/`).
    seed: seeds the reset (the same for every mode) and the sampled actions.
    size: (height, width) of each world's image (default: the run's).
    render: write the videos (False: statistics and metrics only).
    verbose: print what it compiles and how rendering progresses.

  Returns:
    `{mode: statistics}` for each of `MODES`: `episode_statistics`' keys,
    `step` (the checkpoint's), `metrics` (`mean_metrics`) and, for the
    policy's modes when rendered, `video` (the MP4's path). The same, under
    `modes`, with `worlds`, `steps` and `seed`, is written to
    `json_path(out, step)`: `play_step_<STEP>.json`.

  Raises:
    RunFolderError: for a missing or corrupted run folder or checkpoint, or
      one that no longer fits its task.
    ValueError: for worlds or steps below 1.
  """
  if worlds < 1:
    raise ValueError(f'--worlds must be at least 1, got {worlds}.')
  if steps is not None and steps < 1:
    raise ValueError(f'--steps must be at least 1, got {steps}.')
  log = _Log(verbose)
  run = run_folder.open_run(run_path)
  config = run.read_config()
  checkpoint = checkpoints.latest(run)
  env, brax_env = policy_lib.make_environment(config)
  checkpoints.check_compatible(
      checkpoint, config.task, brax_env.observation_size, brax_env.action_size
  )
  steps = steps or brax_env.episode_length
  out = out or run.video_dir
  os.makedirs(out, exist_ok=True)
  run_program = video.make_rollout(
      brax_env, policy_lib.make_inference(config, checkpoint), worlds, steps
  )
  key = jax.random.PRNGKey(seed)
  result = {}
  for mode in MODES:
    start = time.perf_counter()
    if not result:
      log(
          f'Building the rollout program of {worlds} worlds x {steps} steps '
          f'of {config.task!r}, one for the {", ".join(MODES)} runs: tracing '
          "the environment's step (tens of seconds on a CPU), then compiling "
          'it (minutes) or loading it from the compilation cache...'
      )
    states, rewards, dones, metrics, _ = jax.device_get(
        run_program(checkpoint.params, key, video.mode_index(mode))
    )
    seconds = time.perf_counter() - start
    log(
        f'{"Built the program and ran" if not result else "Ran"} the {mode} '
        f'rollout in {seconds:.1f}s.'
    )
    stats = episode_statistics(rewards, dones, metrics)
    stats['step'] = checkpoint.step
    stats['metrics'] = mean_metrics(rewards, metrics)
    if render and mode in VIDEO_MODES:
      start = time.perf_counter()
      frames = video.render_rollout(
          env,
          config.task,
          states,
          size or config.video_size,
          progress=log.frames(mode, steps + 1),
      )
      stats['video'] = video.write_mp4(
          os.path.join(out, f'play_{mode}_step_{checkpoint.step:012d}.mp4'),
          frames,
          fps=1.0 / env.control_timestep(),
      )
      log(
          f'Wrote {stats["video"]} ({len(frames)} frames in '
          f'{time.perf_counter() - start:.1f}s).'
      )
    result[mode] = stats
  path = json_path(out, checkpoint.step)
  with open(path, 'w') as f:
    json.dump(
        {'worlds': worlds, 'steps': steps, 'seed': seed, 'modes': result},
        f,
        indent=1,
    )
  log(f'Wrote {path}.')
  return result


def json_path(out: str, step: int) -> str:
  """Where `play` writes the statistics and metrics of a checkpoint's step."""
  return os.path.join(out, f'play_step_{step:012d}.json')
