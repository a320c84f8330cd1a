"""Watching a trained policy: videos and episode statistics of a run.

`play(run)` loads the run's newest checkpoint, runs its policy on a few
worlds with deterministic actions (the mode of the action distribution)
and with sampled actions (what training explored with), writes one MP4 of
each, the worlds tiled, and returns each mode's episode statistics: episodes
that ended, their mean return and length, the mean reward per step.
"""

from __future__ import annotations

import os

import numpy as np

from mjx_composer.training import checkpoints
from mjx_composer.training import policy as policy_lib
from mjx_composer.training import run_folder
from mjx_composer.training import video

MODES = ('deterministic', 'sampled')


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


def play(
    run_path: str,
    worlds: int = 4,
    steps: int | None = None,
    out: str | None = None,
    seed: int = 1,
    size=None,
    render: bool = True,
) -> dict:
  """Plays the run's newest policy; returns `{mode: statistics}`.

  Args:
    run_path: the run folder.
    worlds: worlds run and tiled in each video.
    steps: control steps (default: one episode, the task's time limit).
    out: the videos' folder (default: the run's `videos/`).
    seed: seeds the reset and the sampled actions.
    size: (height, width) of each world's image (default: the run's).
    render: write the videos (False: statistics only).

  Raises:
    RunFolderError: for a missing or corrupted run folder or checkpoint, or
      one that no longer fits its task.
  """
  if worlds < 1:
    raise ValueError(f'worlds must be positive, got {worlds}.')
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
  result = {}
  make_policy = policy_lib.make_inference(config, checkpoint)
  for mode in MODES:
    states, rewards, dones, metrics, _ = video.rollout(
        brax_env,
        make_policy,
        checkpoint.params,
        worlds,
        steps,
        seed,
        deterministic=mode == 'deterministic',
    )
    stats = episode_statistics(rewards, dones, metrics)
    stats['step'] = checkpoint.step
    if render:
      frames = video.render_rollout(
          env, config.task, states, size or config.video_size
      )
      stats['video'] = video.write_mp4(
          os.path.join(out, f'play_{mode}_step_{checkpoint.step:012d}.mp4'),
          frames,
          fps=1.0 / env.control_timestep(),
      )
    result[mode] = stats
  return result
