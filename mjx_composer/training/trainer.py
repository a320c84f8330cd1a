"""Trains a run with Brax's PPO, unchanged, and fills its run folder.

`train(config, run, resume=False)` starts a run, or continues it from its
newest checkpoint (docs/training.md). Each evaluation adds a checkpoint, a
`metrics.csv` row (`eval_row`), TensorBoard and W&B scalars and, every
`video_every`, a video; the end `summary.json`. In several processes, each
trains its share of the worlds; process 0, which Brax alone evaluates and
reports to, writes the run folder.
"""

from __future__ import annotations

import contextlib
import csv
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
from mjx_composer.training import policy as policy_lib
from mjx_composer.training import run_folder
from mjx_composer.training import video

CSV_FIELDS = (
    'step wall_s eval_return eval_return_std eval_episode_length '
    'env_steps_per_s train_walltime_s'
).split()


def eval_row(step, metrics, wall_s, previous=None, walltime_offset=0.0):
  """One evaluation's CSV row from Brax's `progress_fn(step, metrics)`.

  `env_steps_per_s`: env steps since `previous` (the row before) over Brax's
  training time, without evaluations (Brax's `training/sps` overstates it).
  """
  walltime = float(metrics.get('training/walltime', 0.0)) + walltime_offset
  rate = 0.0
  if previous is not None and walltime > previous['train_walltime_s']:
    seconds = walltime - previous['train_walltime_s']
    rate = (int(step) - previous['step']) / seconds
  get = lambda name: float(metrics.get(name, np.nan))
  return {
      'step': int(step),
      'wall_s': float(wall_s),
      'eval_return': get('eval/episode_reward'),
      'eval_return_std': get('eval/episode_reward_std'),
      'eval_episode_length': get('eval/avg_episode_length'),
      'env_steps_per_s': rate,
      'train_walltime_s': walltime,
  }


def read_csv(path: str) -> list[dict]:
  """The rows of a `metrics.csv` (numbers as floats, `step` as int)."""
  if not os.path.exists(path):
    return []
  with open(path, newline='') as f:
    return [
        {k: int(v) if k == 'step' else float(v) for k, v in row.items()}
        for row in csv.DictReader(f)
    ]


class MetricsWriter:
  """A run's `metrics.csv` (and its `rows`), TensorBoard and Weights & Biases
  as `config` asks, these in process 0 (`lead`) only; the W&B run is named
  after the run folder (a resumed run logs into the same)."""

  def __init__(self, run, config, lead):
    self._csv_path, self.rows = run.metrics_csv, read_csv(run.metrics_csv)
    self._tb = self._wandb = None
    # pylint: disable=g-import-not-at-top
    if config.tensorboard and lead:  # tensorboardX: of the train extra
      import tensorboardX

      self._tb = tensorboardX.SummaryWriter(run.events_dir)
    if config.wandb and lead:
      try:
        import wandb
      except ImportError as e:
        raise ImportError(
            'Weights & Biases logging needs wandb: pip install wandb, or '
            'leave out --wandb.'
        ) from e
      name = os.path.basename(os.path.abspath(run.path))
      self._wandb = wandb.init(
          project='mjx_composer', name=name, id=name, resume='allow',
          config=config_lib.to_dict(config),
      )  # fmt: skip
    # pylint: enable=g-import-not-at-top

  def write(self, row: dict, metrics: dict) -> None:
    """Appends `row` (an `eval_row`) and logs every scalar of `metrics`."""
    new_file = not os.path.exists(self._csv_path)
    with open(self._csv_path, 'a', newline='') as f:
      writer = csv.DictWriter(f, fieldnames=CSV_FIELDS, extrasaction='ignore')
      if new_file:
        writer.writeheader()
      writer.writerow(row)
    self.rows.append(row)
    scalars = {
        name: float(np.asarray(value))
        for name, value in metrics.items()
        if np.ndim(value) == 0
    }
    scalars['eval/env_steps_per_s'] = row['env_steps_per_s']
    if self._tb is not None:
      for name, value in scalars.items():
        self._tb.add_scalar(name, value, row['step'])
      self._tb.flush()
    if self._wandb is not None:
      self._wandb.log(scalars, step=row['step'])

  def close(self) -> None:
    if self._tb is not None:
      self._tb.close()
    if self._wandb is not None:
      self._wandb.finish()


def train(config, run, resume=False, log=print) -> dict:
  """Trains a `TrainConfig` into a `RunFolder` (new, or `resume` it).

  Returns the summary written to `summary.json` (processes but the first
  write nothing and return their index and the task).
  """
  from brax.training.agents.ppo import train as ppo  # pylint: disable=g-import-not-at-top

  start = time.perf_counter()
  cache = platform.configure(
      compilation_cache=None if config.compilation_cache else False
  )
  local, processes = jax.local_device_count(), jax.process_count()
  devices = config.devices or local
  if devices > local:
    raise ValueError(f'devices={devices}, but this process has {local}.')
  for name in ('num_envs', 'batch_size'):  # Brax splits them over all
    if (value := getattr(config, name)) % (devices * processes):
      raise ValueError(
          f'{name} {value} is not a multiple of the {devices * processes} '
          'devices trained on: Brax splits it evenly over them. Change it, '
          'or the number of devices (--devices).'
      )
  # Brax's pmap would split MuJoCo Warp's contact buffer, the whole batch's.
  impl = 'jax' if devices > 1 else config.impl
  if devices > 1 and config.impl and backend.get(config.impl).batch_shared_data:
    raise ValueError(
        f'impl warp trains on one device; pass --devices 1, or --impl jax '
        f'to train on {devices}.'
    )
  device = jax.devices()[0]
  this = f'this is process {jax.process_index()}'
  where = f' in each of {processes} processes ({this})' if processes > 1 else ''
  log(
      f'JAX {jax.__version__} on {device.platform}: {device.device_kind} x '
      f'{devices} (of {local}){where}.'
  )
  env, brax_env = policy_lib.make_environment(config, impl)
  log(
      f'Task {config.task!r} (physics on impl={env.impl!r}): episodes of '
      f'{brax_env.episode_length} steps; observations '
      f'{brax_env.observation_size}, {brax_env.action_size} actions; '
      f'compilation cache: {cache or "off"}.'
  )
  lead = jax.process_index() == 0  # writes the run folder: Brax reports to it
  # Brax's steps per evaluation: whole updates, for max(num_evals - 1, 1).
  per_update = config.batch_size * config.num_minibatches * config.unroll_length
  evals = max(config.num_evals - 1, 1)
  spe = math.ceil(config.num_timesteps / (evals * per_update)) * per_update
  restored, offset, evaluations, wall, walltime = None, 0, 0, 0.0, 0.0
  kwargs = config_lib.ppo_kwargs(config)
  if resume and not checkpoints.paths(run):
    log(
        f'{run.path} has no checkpoint (it stopped before its first '
        'evaluation): training it again from step 0.'
    )
    if lead:
      for path in (run.metrics_csv, run.summary_path):
        with contextlib.suppress(FileNotFoundError):
          os.remove(path)
      shutil.rmtree(run.events_dir, ignore_errors=True)
  elif resume:
    restored = checkpoints.latest(run)
    checkpoints.check_compatible(restored, config.task, brax_env)
    offset, evaluations = restored.step, restored.evaluations
    spe = restored.steps_per_evaluation
    rows = read_csv(run.metrics_csv)
    if rows:
      wall, walltime = rows[-1]['wall_s'], rows[-1]['train_walltime_s']
    remaining = math.ceil((config.num_timesteps - offset) / spe)
    if remaining <= 0:
      raise run_folder.RunFolderError(
          f'The run {run.path!r} has trained {offset:,} of its '
          f'{config.num_timesteps:,} steps: it is finished. Pass a larger '
          '--num-timesteps to train it further.'
      )
    log(
        f'Resuming {run.path} at step {offset:,} ({evaluations} evaluations '
        f'done, {remaining} to go; Adam starts afresh).'
    )
    kwargs.update(num_timesteps=remaining * spe, num_evals=remaining + 1)
    kwargs['restore_params'] = restored.params
  writer = MetricsWriter(run, config, lead)
  done = {'evaluations': evaluations, 'videos': []}

  def keep(step, make_policy, params):
    done.update(make_policy=make_policy, params=params)
    if step == 0 and jax.process_count() > 1:
      _join_processes(f'mjx_composer_train_start_{offset}', devices)
    if step:  # process 0 only: Brax calls the others at step 0 alone
      checkpoints.save_params(run, offset + int(step), params)

  cached = 'loaded from the compilation cache next time'
  cached = cached if cache else 'the compilation cache is off'

  def progress(step, metrics):
    if restored is not None and step == 0:
      return  # the checkpoint's step has its evaluation already
    total = offset + int(step)
    previous = writer.rows[-1] if writer.rows else None
    elapsed = wall + time.perf_counter() - start
    row = eval_row(total, metrics, elapsed, previous, walltime)
    writer.write(row, metrics)
    index = done['evaluations'] = done['evaluations'] + bool(step)
    if step:
      sizes = (brax_env.observation_size, brax_env.action_size)
      info = (total, index, spe, config.task, *sizes)
      checkpoints.finish(run, checkpoints.Checkpoint(*info, row['eval_return']))
    # The rate since the evaluation before, unless that one came before
    # this process's first epoch, whose time holds its compile.
    eta, rate = '', row['env_steps_per_s']
    if step > spe and total < config.num_timesteps and rate > 0:
      eta = f'  ETA {(config.num_timesteps - total) / rate:,.0f}s'
    log(
        f'step {total:>12,}  return {row["eval_return"]:9.3f} ± '
        f'{row["eval_return_std"]:.3f}  {row["wall_s"]:8.1f}s{eta}'
    )
    if not step:
      # Brax compiles its training step at its first call, after this
      # evaluation: the next evaluation's time holds that compile.
      log(f'Compiling the training step before the first epoch ({cached}).')
    if step and config.video_every and not index % config.video_every:
      path = os.path.join(run.video_dir, f'eval_step_{total:012d}.mp4')
      policy = (done['make_policy'], done['params'])
      shape = (config.video_worlds, config.video_steps, config.seed + 1)
      states = video.rollout(brax_env, *policy, *shape)[0]
      frames = video.render_rollout(env, config.task, states, config.video_size)
      fps = 1.0 / env.control_timestep()
      done['videos'].append(video.write_mp4(path, frames, fps=fps))

  log(
      'Compiling the evaluation before the first evaluation (minutes on a '
      f'CPU; {cached}).'
  )
  try:
    with partitioner.scope(jax.local_devices()[:devices]):
      ppo.train(
          environment=brax_env,
          **{**kwargs, 'seed': config.seed + evaluations},
          deterministic_eval=True,
          max_devices_per_host=devices,
          network_factory=policy_lib.network_factory(config),
          progress_fn=progress,
          policy_params_fn=keep,
          **brax_adapter.training_kwargs(brax_env),
      )
  finally:
    writer.close()
  if not lead:
    return {'process': jax.process_index(), 'task': config.task}
  wall_s = wall + time.perf_counter() - start
  rows, target = writer.rows, config.target_return
  returns = [r['eval_return'] for r in rows]
  hits = [r for r in rows if target is not None and r['eval_return'] >= target]
  hit = hits[0] if hits else None
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

  JAX's CPU collectives (Gloo) give up when a process reaches its first one
  30 s after another (process 0 compiles its evaluator before step 0): each
  compiles a sum over the devices trained on, waits for the others at the
  coordination service's barrier, then runs it.
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
  internals_jax.wait_for_processes(barrier, 3600.0)  # process 0 compiles
  jax.block_until_ready(total(ones))
