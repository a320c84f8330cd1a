"""Trains a run with Brax's PPO, unchanged, and fills its run folder.

`train(config, run)` starts a new run; `train(config, run, resume=True)`
continues the run from its newest checkpoint:

* the step count continues (Brax counts from 0 again; every step this module
  reports, writes and saves is the run's, Brax's plus the checkpoint's);
* the normalizer and the policy and value parameters are Brax's
  `restore_params`; Adam's moments and count are restored too
  (`checkpoints.restoring_optimizer`);
* evaluations stay at the same steps: the resumed `ppo.train` is given the
  remaining evaluations times the run's steps per evaluation (so each of its
  epochs trains as many steps as the first run's did);
* what cannot be carried over is new: the environments start new episodes
  and Brax's keys derive from `seed + evaluations so far`, so the learning
  curve continues within noise, not bit for bit. Brax's evaluation of the
  restored policy before training is not logged (the checkpoint's step
  already has one).

After each evaluation the run gets a checkpoint, a `metrics.csv` row and
TensorBoard scalars (`metrics.MetricsWriter`), and every `video_every`
evaluations a video of the deterministic policy (`video`); at the end a
`summary.json`.

In several processes (`jax.distributed`; `launcher`), every process trains
its share of the worlds on its local devices, and process 0, which Brax
alone evaluates and reports to, writes the run folder.
"""

from __future__ import annotations

import math
import os
import sys
import time

import jax
import tqdm

from mjx_composer import platform
from mjx_composer.adapters import brax as brax_adapter
from mjx_composer.platform import backend
from mjx_composer.platform import internals_jax
from mjx_composer.platform import partitioner
from mjx_composer.training import checkpoints
from mjx_composer.training import config as config_lib
from mjx_composer.training import metrics as metrics_lib
from mjx_composer.training import policy as policy_lib
from mjx_composer.training import run_folder
from mjx_composer.training import video

# How long processes wait for process 0's first evaluation (its compile).
_START_TIMEOUT_S = 3600.0

# What a resumed run may change; the rest would change what it trains.
RESUMABLE = frozenset(
    {
        'num_timesteps',
        'devices',
        'processes',
        'video_every',
        'video_worlds',
        'video_steps',
        'video_size',
        'tensorboard',
        'wandb',
        'compilation_cache',
    }
)


def steps_per_evaluation(config: config_lib.TrainConfig) -> int:
  """Environment steps between two evaluations, as Brax's `ppo.train` runs.

  Brax trains `ceil(num_timesteps / (evaluations x steps per update))`
  updates per evaluation, each `batch_size x num_minibatches x
  unroll_length` steps, for `max(num_evals - 1, 1)` evaluations.
  """
  per_update = config.batch_size * config.num_minibatches * config.unroll_length
  evaluations = max(config.num_evals - 1, 1)
  updates = math.ceil(config.num_timesteps / (evaluations * per_update))
  return updates * per_update


def check_resume_changes(
    saved: config_lib.TrainConfig, requested: config_lib.TrainConfig
) -> None:
  """Raises RunFolderError if `requested` changes more than `RESUMABLE`."""
  old, new = config_lib.to_dict(saved), config_lib.to_dict(requested)
  changed = sorted(k for k in old if old[k] != new[k] and k not in RESUMABLE)
  if 'task' in changed:
    raise run_folder.RunFolderError(
        f'The run was trained on task {saved.task!r}, not {requested.task!r}: '
        'resume it with its own task, or start a new run.'
    )
  if changed:
    raise run_folder.RunFolderError(
        f'A resumed run keeps its settings; {changed} differ from the run '
        f"folder's config. Only {sorted(RESUMABLE)} may change."
    )


def _devices(config, log):
  local = jax.local_device_count()
  devices = config.devices or local
  if devices > local:
    raise ValueError(
        f'devices={devices}, but this process has {local} local devices.'
    )
  # Brax splits the batch over every process's devices.
  config_lib.check_devices(config, devices * jax.process_count())
  impl = config.impl
  if devices > 1:
    # MuJoCo Warp's contact buffer belongs to the whole batch; Brax's pmap
    # would split it.
    if impl is not None and backend.get(impl).batch_shared_data:
      raise ValueError(
          f'impl warp trains on one device; pass --devices 1, or --impl jax '
          f'to train on {devices}.'
      )
    impl = 'jax'
  device = jax.devices()[0]
  processes = jax.process_count()
  log(
      f'JAX {jax.__version__} on {device.platform}: {device.device_kind} x '
      f'{devices} (of {local})'
      + (
          f' in each of {processes} processes (this is process '
          f'{jax.process_index()}).'
          if processes > 1
          else '.'
      )
  )
  return devices, impl


def train(
    config: config_lib.TrainConfig,
    run: run_folder.RunFolder,
    resume: bool = False,
    log=print,
) -> dict:
  """Trains `config` into `run` (a new run, or `resume` its checkpoint).

  Returns:
    The summary written to `summary.json` (in processes but the first,
    which write nothing, only the process index and the task).

  Raises:
    RunFolderError: when resuming a run without a usable checkpoint, or one
      whose networks do not fit the task.
  """
  # pylint: disable=g-import-not-at-top
  from brax.training.agents.ppo import train as ppo
  # pylint: enable=g-import-not-at-top

  cache = platform.configure(
      compilation_cache=None if config.compilation_cache else False
  )
  devices, impl = _devices(config, log)
  env, brax_env = policy_lib.make_environment(config, impl)
  obs_size = brax_env.observation_size
  log(
      f'Task {config.task!r} (physics on impl={env.impl!r}): episodes of '
      f'{brax_env.episode_length} steps; observations {obs_size}, '
      f'{brax_env.action_size} actions; compilation cache: {cache or "off"}.'
  )

  restored = None
  offset, evaluations, walltime, wall = 0, 0, 0.0, 0.0
  spe = steps_per_evaluation(config)
  if resume:
    restored = checkpoints.latest(run)
    checkpoints.check_compatible(
        restored, config.task, obs_size, brax_env.action_size
    )
    offset, evaluations = restored.step, restored.evaluations
    spe = restored.steps_per_evaluation
  # Process 0 writes the run folder (Brax reports to it alone).
  lead = jax.process_index() == 0
  writer = metrics_lib.MetricsWriter(
      run.metrics_csv,
      run.events_dir if config.tensorboard and lead else None,
      config_lib.to_dict(config) if config.wandb and lead else None,
      os.path.basename(os.path.abspath(run.path)),
  )
  if resume and writer.rows:
    walltime = writer.rows[-1]['train_walltime_s']
    wall = writer.rows[-1]['wall_s']
  remaining = math.ceil((config.num_timesteps - offset) / spe)
  if remaining <= 0:
    writer.close()
    raise run_folder.RunFolderError(
        f'The run {run.path!r} has trained {offset:,} of its '
        f'{config.num_timesteps:,} steps: it is finished. Pass a larger '
        '--num-timesteps to train it further.'
    )
  if resume:
    brax_timesteps, brax_evals = remaining * spe, remaining + 1
    log(
        f'Resuming {run.path} at step {offset:,} ({evaluations} evaluations '
        f'done, {remaining} to go).'
    )
  else:
    brax_timesteps, brax_evals = config.num_timesteps, config.num_evals

  bar = tqdm.tqdm(
      total=config.num_timesteps,
      initial=offset,
      unit='step',
      unit_scale=True,
      desc='training (the first update compiles)',
      file=sys.stdout,
      disable=None,  # off when stdout is not a terminal (logs, CI)
  )
  latest = {}
  done = {'evaluations': evaluations, 'videos': [], 'restored_ok': None}
  start = time.perf_counter()

  def keep(step, make_policy, params):
    latest.update(make_policy=make_policy, params=params)
    state = checkpoints.training_state_of_caller()
    if step == 0 and jax.process_count() > 1:
      _join_processes(f'mjx_composer_train_start_{offset}')
    if step == 0:
      if restored is not None:
        done['restored_ok'] = all(
            bool((a == b).all())
            for a, b in zip(
                jax.tree.leaves(state.optimizer_state),
                jax.tree.leaves(restored.optimizer_state),
            )
        )
      return
    done['evaluations'] += 1
    checkpoints.save(
        run,
        checkpoints.Checkpoint(
            step=offset + int(step),
            evaluations=done['evaluations'],
            params=params,
            optimizer_state=state.optimizer_state,
            task=config.task,
            observation_size=obs_size,
            action_size=brax_env.action_size,
            steps_per_evaluation=spe,
        ),
    )

  def progress(step, metrics):
    if restored is not None and step == 0:
      return  # the checkpoint's step has its evaluation already
    total = offset + int(step)
    row = metrics_lib.eval_row(
        total,
        metrics,
        wall + time.perf_counter() - start,
        previous=writer.rows[-1] if writer.rows else None,
        walltime_offset=walltime,
    )
    writer.write(row, metrics)
    bar.set_description(f'return {row["eval_return"]:.2f}')
    bar.update(max(0, min(total, config.num_timesteps) - bar.n))
    rate = row['env_steps_per_s']
    eta = (config.num_timesteps - total) / rate if rate > 0 else float('nan')
    tqdm.tqdm.write(
        f'step {total:>12,}  return {row["eval_return"]:9.3f} ± '
        f'{row["eval_return_std"]:.3f}  {rate:,.0f} env steps/s  '
        f'ETA {eta:,.0f}s',
        file=sys.stdout,
    )
    index = done['evaluations']
    if config.video_every and index and index % config.video_every == 0:
      path = os.path.join(run.video_dir, f'eval_step_{total:012d}.mp4')
      _video(env, brax_env, config, latest, path)
      done['videos'].append(path)

  ppo_kwargs = dict(
      num_timesteps=brax_timesteps,
      num_evals=brax_evals,
      num_envs=config.num_envs,
      batch_size=config.batch_size,
      num_minibatches=config.num_minibatches,
      unroll_length=config.unroll_length,
      num_updates_per_batch=config.num_updates_per_batch,
      learning_rate=config.learning_rate,
      entropy_cost=config.entropy_cost,
      discounting=config.discounting,
      reward_scaling=config.reward_scaling,
      max_grad_norm=config.max_grad_norm,
      normalize_observations=config.normalize,
      num_eval_envs=config.num_eval_envs,
      deterministic_eval=True,
      seed=config.seed + evaluations,
      max_devices_per_host=devices,
      network_factory=policy_lib.network_factory(config),
      progress_fn=progress,
      policy_params_fn=keep,
      restore_params=restored.params if restored else None,
      **brax_adapter.training_kwargs(brax_env),
  )
  adam_state = None
  if restored is not None:
    adam_state = restored.optimizer_state
    if config.max_grad_norm is not None:
      adam_state = adam_state[1]  # optax.chain(clip, adam)'s state
  try:
    with partitioner.scope(jax.local_devices()[:devices]):
      with checkpoints.restoring_optimizer(adam_state):
        ppo.train(environment=brax_env, **ppo_kwargs)
  finally:
    bar.close()
    writer.close()

  if not lead:
    return {'process': jax.process_index(), 'task': config.task}
  rows = writer.rows
  device = jax.devices()[0]
  summary = {
      'task': config.task,
      'device': f'{device.platform}: {device.device_kind}',
      'devices': devices,
      'processes': jax.process_count(),
      'impl': env.impl,
      'jax': jax.__version__,
      'steps': rows[-1]['step'] if rows else offset,
      'evaluations': done['evaluations'],
      'resumed_from_step': offset if resume else None,
      'optimizer_state_restored': done['restored_ok'],
      'initial_return': rows[0]['eval_return'] if rows else None,
      'final_return': rows[-1]['eval_return'] if rows else None,
      'best_return': max(r['eval_return'] for r in rows) if rows else None,
      'wall_s': wall + time.perf_counter() - start,
      'checkpoint': checkpoints.paths(run)[-1],
      'videos': done['videos'],
  }
  run_folder.write_json(run.summary_path, summary)
  log(
      f'Trained {config.task!r} to step {summary["steps"]:,}: return '
      f'{summary["initial_return"]:.3f} -> {summary["final_return"]:.3f} '
      f'(best {summary["best_return"]:.3f}) in {summary["wall_s"]:.1f}s; '
      f'run folder {run.path}.'
  )
  return summary


def _join_processes(barrier: str) -> None:
  """Waits for every process, then connects their collectives.

  Brax calls `policy_params_fn` at step 0 in every process, after process
  0's first evaluation (which compiles the evaluator), and before the first
  training epoch. JAX's CPU collectives (Gloo) give up when a process
  reaches its first collective more than 30 s after another, e.g. still
  compiling; once connected, a collective waits as long as it takes. So the
  processes wait for each other at the coordination service's barrier (no
  such limit), then run one collective over every device.
  """
  internals_jax.wait_for_processes(barrier, _START_TIMEOUT_S)
  ones = jax.numpy.ones((jax.local_device_count(),))
  jax.block_until_ready(
      jax.pmap(lambda x: jax.lax.psum(x, 'i'), axis_name='i')(ones)
  )


def _video(env, brax_env, config, latest, path):
  """Renders the latest deterministic policy into `path`."""
  states = video.rollout(
      brax_env,
      latest['make_policy'],
      latest['params'],
      config.video_worlds,
      config.video_steps,
      config.seed + 1,
  )[0]
  frames = video.render_rollout(env, config.task, states, config.video_size)
  video.write_mp4(path, frames, fps=1.0 / env.control_timestep())
