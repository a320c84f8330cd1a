"""Trains a run with Brax's PPO, unchanged, and fills its run folder.

`train(config, run)` starts a new run; `train(config, run, resume=True)`
continues the run from its newest checkpoint:

* the step count continues (Brax counts from 0 again; every step this module
  reports, writes and saves is the run's, Brax's plus the checkpoint's);
* the normalizer and the policy and value parameters are the checkpoint's
  (Brax's `restore_params`); Adam's moments and count start fresh, since
  Brax's public API neither hands them out nor takes them back;
* evaluations stay at the same steps: the resumed `ppo.train` is given the
  remaining evaluations times the run's steps per evaluation;
* the environments start new episodes and Brax's keys derive from
  `seed + evaluations so far`, so the learning curve continues within noise,
  not bit for bit. Brax's evaluation of the restored policy before training
  is not logged (the checkpoint's step has one).

A run that stopped before its first evaluation has no checkpoint: resuming
it trains it again from step 0, its metrics cleared.

After each evaluation the run gets a checkpoint (`checkpoints`: the latest
and the best are kept), a `metrics.csv` row and TensorBoard scalars
(`metrics.MetricsWriter`), and every `video_every` evaluations a video of
the deterministic policy (`video`); at the end a `summary.json`, with the
time to the first evaluation that reached `target_return` where one is set.

In several processes (`jax.distributed`, joined before this runs), every
process trains its share of the worlds on its local devices, and process 0,
which Brax alone evaluates and reports to, writes the run folder.
"""

from __future__ import annotations

import math
import os
import shutil
import time

import jax
import numpy as np

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
        'video_every',
        'video_worlds',
        'video_steps',
        'video_size',
        'tensorboard',
        'wandb',
        'compilation_cache',
        'target_return',
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


def _restored(run, config, brax_env, lead, log):
  """The checkpoint a resumed run continues, or None to train from step 0."""
  if not checkpoints.paths(run):
    log(
        f'{run.path} has no checkpoint (it stopped before its first '
        'evaluation): training it again from step 0.'
    )
    if lead:
      for path in (run.metrics_csv, run.summary_path):
        if os.path.exists(path):
          os.remove(path)
      shutil.rmtree(run.events_dir, ignore_errors=True)
    return None
  restored = checkpoints.latest(run)
  checkpoints.check_compatible(
      restored, config.task, brax_env.observation_size, brax_env.action_size
  )
  return restored


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
    RunFolderError: when resuming a run whose checkpoint is corrupted or
      whose networks do not fit the task, or a finished run.
  """
  from brax.training.agents.ppo import train as ppo  # pylint: disable=g-import-not-at-top

  start = time.perf_counter()
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
  # Process 0 writes the run folder (Brax reports to it alone).
  lead = jax.process_index() == 0
  restored = _restored(run, config, brax_env, lead, log) if resume else None
  offset, evaluations, spe = 0, 0, steps_per_evaluation(config)
  wall, walltime = 0.0, 0.0
  if restored is not None:
    offset, evaluations = restored.step, restored.evaluations
    spe = restored.steps_per_evaluation
    rows = metrics_lib.read_csv(run.metrics_csv)
    if rows:
      wall, walltime = rows[-1]['wall_s'], rows[-1]['train_walltime_s']
  remaining = math.ceil((config.num_timesteps - offset) / spe)
  if remaining <= 0:
    raise run_folder.RunFolderError(
        f'The run {run.path!r} has trained {offset:,} of its '
        f'{config.num_timesteps:,} steps: it is finished. Pass a larger '
        '--num-timesteps to train it further.'
    )
  if restored is not None:
    log(
        f'Resuming {run.path} at step {offset:,} ({evaluations} evaluations '
        f'done, {remaining} to go; Adam starts afresh).'
    )
  writer = metrics_lib.MetricsWriter(
      run.metrics_csv,
      run.events_dir if config.tensorboard and lead else None,
      config_lib.to_dict(config) if config.wandb and lead else None,
      os.path.basename(os.path.abspath(run.path)),
  )
  done = {'evaluations': evaluations, 'videos': []}

  def keep(step, make_policy, params):
    done.update(make_policy=make_policy, params=params)
    if step == 0 and jax.process_count() > 1:
      _join_processes(f'mjx_composer_train_start_{offset}', devices)
    if step:  # process 0 only: Brax calls the others at step 0 alone
      checkpoints.save_params(run, offset + int(step), params)

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
    if step:
      done['evaluations'] += 1
      checkpoints.finish(
          run,
          checkpoints.Checkpoint(
              total,
              done['evaluations'],
              spe,
              config.task,
              obs_size,
              brax_env.action_size,
              row['eval_return'],
          ),
      )
    # The rate since the evaluation before, unless that one came before
    # this process's first epoch, whose time holds its compile.
    eta, rate = '', row['env_steps_per_s']
    if step > spe and total < config.num_timesteps and rate > 0:
      eta = f'  ETA {(config.num_timesteps - total) / rate:,.0f}s'
    log(
        f'step {total:>12,}  return {row["eval_return"]:9.3f} ± '
        f'{row["eval_return_std"]:.3f}  {row["wall_s"]:8.1f}s{eta}'
    )
    index = done['evaluations']
    if step and config.video_every and index % config.video_every == 0:
      path = os.path.join(run.video_dir, f'eval_step_{total:012d}.mp4')
      _video(env, brax_env, config, done, path)
      done['videos'].append(path)

  log(
      'Compiling the evaluation and the training step before the first '
      'evaluation (minutes on a CPU; '
      + (
          'loaded from the compilation cache next time).'
          if cache
          else 'the compilation cache is off).'
      )
  )
  try:
    with partitioner.scope(jax.local_devices()[:devices]):
      ppo.train(
          environment=brax_env,
          num_timesteps=remaining * spe if restored else config.num_timesteps,
          num_evals=remaining + 1 if restored else config.num_evals,
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
  finally:
    writer.close()
  if not lead:
    return {'process': jax.process_index(), 'task': config.task}
  return _summarize(
      config,
      run,
      writer.rows,
      done,
      restored,
      devices,
      env,
      log,
      wall + time.perf_counter() - start,
  )


def _summarize(config, run, rows, done, restored, devices, env, log, wall_s):
  """Writes and returns `summary.json`; logs the final line."""
  device = jax.devices()[0]
  returns = [r['eval_return'] for r in rows]
  target = config.target_return
  hit = next(
      (r for r in rows if target is not None and r['eval_return'] >= target),
      None,
  )
  summary = {
      'task': config.task,
      'device': f'{device.platform}: {device.device_kind}',
      'devices': devices,
      'processes': jax.process_count(),
      'impl': env.impl,
      'jax': jax.__version__,
      'steps': rows[-1]['step'],
      'evaluations': done['evaluations'],
      'resumed_from_step': restored.step if restored else None,
      'initial_return': returns[0],
      'final_return': returns[-1],
      'best_return': max(returns),
      'wall_s': wall_s,
      'target_return': target,
      'target_step': hit['step'] if hit else None,
      'time_to_target_s': hit['wall_s'] if hit else None,
      'train_time_to_target_s': hit['train_walltime_s'] if hit else None,
      'checkpoints': checkpoints.paths(run),
      'videos': done['videos'],
  }
  run_folder.write_json(run.summary_path, summary)
  line = (
      f'Trained {config.task!r} to step {summary["steps"]:,}: return '
      f'{returns[0]:.3f} -> {returns[-1]:.3f} (best {max(returns):.3f}) in '
      f'{wall_s:.1f}s; run folder {run.path}.'
  )
  if hit:
    line += (
        f' Return {target:g} reached at step {hit["step"]:,}, '
        f'{hit["wall_s"]:.1f}s after the start ({hit["train_walltime_s"]:.1f}s '
        'of training).'
    )
  elif target is not None:
    line += f' Return {target:g} not reached.'
  log(line)
  return summary


def _join_processes(barrier: str, devices: int) -> None:
  """Waits for every process, then connects their collectives.

  Brax calls `policy_params_fn` at step 0 in every process, after process
  0's first evaluation (which compiles the evaluator), and before the first
  training epoch. JAX's CPU collectives (Gloo) give up when a process
  reaches its first collective more than 30 s after another, e.g. still
  compiling; once connected, a collective waits as long as it takes. So
  each process compiles a sum over the devices Brax trains on (each
  process's first `devices`), the processes wait for each other at the
  coordination service's barrier (no such limit), and then run it.
  """
  by_process = {}
  for device in jax.devices():
    by_process.setdefault(device.process_index, []).append(device)
  used = [d for ds in by_process.values() for d in ds[:devices]]
  mesh = jax.sharding.Mesh(np.array(used), ('i',))
  ones = jax.make_array_from_process_local_data(
      jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec('i')),
      np.ones((devices,), np.float32),
  )
  total = jax.jit(jax.numpy.sum).lower(ones).compile()
  internals_jax.wait_for_processes(barrier, _START_TIMEOUT_S)
  jax.block_until_ready(total(ones))


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
