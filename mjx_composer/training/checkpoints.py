"""A run's checkpoints: the latest and the best, each resumable by Brax.

A checkpoint is a folder `checkpoints/<step, 12 digits>/` holding

* the `(normalizer, policy, value)` parameters that Brax's `ppo.train` hands
  its public `policy_params_fn` callback after each training epoch, written
  with orbax in the layout of Brax's own `ppo.checkpoint.save` (so Brax's
  `ppo.checkpoint.load` reads it too), and
* `checkpoint.json`: the step, evaluations, steps per evaluation, task,
  observation sizes, action size and the evaluation return.

`ppo.train(restore_params=checkpoint.params)` starts from them. What Brax's
public API does not hand out or take back is not saved: Adam's moments and
count start fresh on resume.

Brax calls `policy_params_fn` before it evaluates the same parameters, so
`save_params` writes the parameters when they come and `finish` writes
`checkpoint.json` when the evaluation's return has come (`progress_fn`). A
checkpoint is complete once its `checkpoint.json` exists (written through a
temporary file; orbax writes the parameters through a temporary folder):
an interrupted write leaves no checkpoint that `latest` picks up. `finish`
then keeps two checkpoints, the latest and the best by evaluation return,
and deletes the rest.

Orbax is called directly, with this process as the only one taking part:
Brax's `save` and `load` synchronize every `jax.distributed` process
through a collective, while Brax calls `policy_params_fn` in process 0
alone after the first epoch, so a run of several processes waited there
until the collective timed out.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import shutil
from typing import Any

import jax
import numpy as np

from mjx_composer.training import run_folder

INFO = 'checkpoint.json'
_NAME = re.compile(r'^\d{12}$')


@dataclasses.dataclass
class Checkpoint:
  """One saved state of a run (`params`: None until loaded).

  Attributes:
    step: environment steps trained so far.
    evaluations: evaluations after training so far (Brax's step-0
      evaluation not counted).
    steps_per_evaluation: environment steps between two evaluations.
    task: the task trained.
    observation_size: `{group: shape}` the networks were built for.
    action_size: the number of actions.
    eval_return: the evaluation's mean return at `step`.
    params: `(normalizer, policy, value)` as `ppo.train` hands them out.
  """

  step: int
  evaluations: int
  steps_per_evaluation: int
  task: str
  observation_size: dict
  action_size: int
  eval_return: float = math.nan
  params: Any = None


def path_for(run: run_folder.RunFolder, step: int) -> str:
  return os.path.join(run.checkpoint_dir, f'{int(step):012d}')


def _checkpointer():
  import orbax.checkpoint as ocp  # pylint: disable=g-import-not-at-top

  alone = ocp.options.MultiprocessingOptions(
      primary_host=jax.process_index(), active_processes={jax.process_index()}
  )
  return ocp.Checkpointer(
      ocp.PyTreeCheckpointHandler(multiprocessing_options=alone),
      multiprocessing_options=alone,
  )


def save_params(run: run_folder.RunFolder, step: int, params) -> None:
  """Writes the parameters of `step` (`finish` completes the checkpoint)."""
  import orbax.checkpoint as ocp  # pylint: disable=g-import-not-at-top

  path = path_for(run, step)
  shutil.rmtree(path, ignore_errors=True)
  normalizer, policy, value = jax.tree.map(np.asarray, params)
  # Brax's step count makes its halves JAX arrays: as numpy, orbax needs no
  # sharding to read them back.
  count = {k: np.asarray(getattr(normalizer.count, k)) for k in ('hi', 'lo')}
  params = (normalizer.replace(count=count), policy, value)
  _checkpointer().save(path, args=ocp.args.PyTreeSave(params))


def finish(run: run_folder.RunFolder, checkpoint: Checkpoint) -> None:
  """Completes `checkpoint` (its parameters saved), keeps the latest and best."""
  info = dataclasses.asdict(checkpoint)
  del info['params']
  run_folder.write_json(
      os.path.join(path_for(run, checkpoint.step), INFO), info
  )
  best = checkpoint
  for path in paths(run):
    try:
      other = read(path)
    except run_folder.RunFolderError:
      continue  # unreadable: deleted below
    if other.eval_return > best.eval_return or math.isnan(best.eval_return):
      best = other
  keep = {path_for(run, c.step) for c in (best, checkpoint)}
  for name in os.listdir(run.checkpoint_dir):
    path = os.path.join(run.checkpoint_dir, name)
    if path not in keep:
      shutil.rmtree(path, ignore_errors=True)


def paths(run: run_folder.RunFolder) -> list[str]:
  """The run's complete checkpoints, oldest (fewest steps) first."""
  if not os.path.isdir(run.checkpoint_dir):
    return []
  return [
      os.path.join(run.checkpoint_dir, name)
      for name in sorted(os.listdir(run.checkpoint_dir))
      if _NAME.match(name)
      and os.path.isfile(os.path.join(run.checkpoint_dir, name, INFO))
  ]


def read(path: str, params: bool = False) -> Checkpoint:
  """The checkpoint at `path`; its parameters too when `params`.

  Raises:
    RunFolderError: for a checkpoint that is unreadable or truncated.
  """
  try:
    with open(os.path.join(path, INFO)) as f:
      checkpoint = Checkpoint(**json.load(f))
    if params:
      checkpoint.params = _restore(path)
  except Exception as e:  # json, orbax or a file missing: all mean corrupted
    raise run_folder.RunFolderError(
        f'The checkpoint {path!r} is corrupted and cannot be read '
        f'({type(e).__name__}: {e}). Delete it to resume from the one '
        'before, or start a new run.'
    ) from e
  checkpoint.observation_size = {
      k: tuple(v) for k, v in checkpoint.observation_size.items()
  }
  return checkpoint


def _restore(path: str):
  """The parameters at `path`, numpy arrays, as Brax's `load` gives them."""
  # pylint: disable=g-import-not-at-top
  import orbax.checkpoint as ocp
  from brax.training import types as brax_types
  from brax.training.acme import running_statistics

  # pylint: enable=g-import-not-at-top
  checkpointer = _checkpointer()
  as_numpy = jax.tree.map(
      lambda _: ocp.RestoreArgs(restore_type=np.ndarray),
      checkpointer.metadata(path).item_metadata,
  )
  normalizer, policy, value = checkpointer.restore(
      path, args=ocp.args.PyTreeRestore(restore_args=as_numpy)
  )
  normalizer['count'] = brax_types.UInt64(**normalizer['count'])
  normalizer = running_statistics.RunningStatisticsState(**normalizer)
  return normalizer, policy, value


def latest(run: run_folder.RunFolder) -> Checkpoint:
  """The run's newest checkpoint, its parameters loaded.

  Raises:
    RunFolderError: if the run has none (it stopped before its first
      evaluation) or the newest is corrupted.
  """
  found = paths(run)
  if not found:
    raise run_folder.RunFolderError(
        f'The run folder {run.path!r} has no checkpoint in '
        f'{run_folder.CHECKPOINTS}/: it stopped before its first evaluation. '
        f'Train it again from step 0 with --resume {run.path}.'
    )
  return read(found[-1], params=True)


def check_compatible(
    checkpoint: Checkpoint, task: str, observation_size, action_size: int
) -> None:
  """Raises RunFolderError unless the networks fit the environment now."""
  observation_size = {k: tuple(v) for k, v in dict(observation_size).items()}
  saved = {k: tuple(v) for k, v in dict(checkpoint.observation_size).items()}
  if checkpoint.task != task:
    raise run_folder.RunFolderError(
        f'The checkpoint was trained on task {checkpoint.task!r}, not '
        f'{task!r}: resume it with its own task, or start a new run.'
    )
  if saved != observation_size or checkpoint.action_size != action_size:
    raise run_folder.RunFolderError(
        f'The run is incompatible with task {task!r} as it is now: its '
        f'networks take observations {saved} and {checkpoint.action_size} '
        f'actions, the task gives {observation_size} and {action_size}. '
        'Start a new run (the task changed since the run was trained).'
    )
