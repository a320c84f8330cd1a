"""A run's checkpoints: the latest and the best, each resumable by Brax.

`checkpoints/<step, 12 digits>/` holds the parameters that Brax's `ppo.train`
hands its `policy_params_fn`, in the layout of Brax's `ppo.checkpoint.save`
(`save_params`; orbax of this process alone: Brax's `save` synchronizes every
process), and `checkpoint.json`, written last (`finish`): complete once it is.
"""

from __future__ import annotations

import contextlib
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
  """One saved state of a run; `params` (None until loaded) as Brax's."""

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


def _orbax():
  """Orbax and a checkpointer of this process alone."""
  import orbax.checkpoint as ocp  # pylint: disable=g-import-not-at-top

  me = jax.process_index()
  alone = ocp.options.MultiprocessingOptions(me, active_processes={me})
  handler = ocp.PyTreeCheckpointHandler(multiprocessing_options=alone)
  return ocp, ocp.Checkpointer(handler, multiprocessing_options=alone)


def save_params(run: run_folder.RunFolder, step: int, params) -> None:
  """Writes the parameters of `step` (`finish` completes the checkpoint)."""
  path = path_for(run, step)
  shutil.rmtree(path, ignore_errors=True)
  normalizer, policy, value = jax.tree.map(np.asarray, params)
  # Brax's step count makes its halves JAX arrays: as numpy, orbax needs no
  # sharding to read them back.
  count = {k: np.asarray(getattr(normalizer.count, k)) for k in ('hi', 'lo')}
  params = (normalizer.replace(count=count), policy, value)
  ocp, checkpointer = _orbax()
  checkpointer.save(path, args=ocp.args.PyTreeSave(params))


def finish(run: run_folder.RunFolder, checkpoint: Checkpoint) -> None:
  """Completes `checkpoint` (its parameters saved); keeps latest and best."""
  info = {k: v for k, v in vars(checkpoint).items() if k != 'params'}
  run_folder.write_json(
      os.path.join(path_for(run, checkpoint.step), INFO), info
  )
  best = checkpoint
  for path in paths(run):
    with contextlib.suppress(run_folder.RunFolderError):  # else deleted below
      other = read(path)
      if other.eval_return > best.eval_return or math.isnan(best.eval_return):
        best = other
  keep = {f'{int(c.step):012d}' for c in (best, checkpoint)}
  for name in set(os.listdir(run.checkpoint_dir)) - keep:
    shutil.rmtree(os.path.join(run.checkpoint_dir, name), ignore_errors=True)


def paths(run: run_folder.RunFolder) -> list[str]:
  """The run's complete checkpoints, oldest (fewest steps) first."""
  folder = run.checkpoint_dir
  found = sorted(os.listdir(folder)) if os.path.isdir(folder) else []
  found = [os.path.join(folder, name) for name in found if _NAME.match(name)]
  return [path for path in found if os.path.isfile(os.path.join(path, INFO))]


def read(path: str, params: bool = False) -> Checkpoint:
  """The checkpoint at `path` (its parameters too); RunFolderError if bad."""
  try:
    with open(os.path.join(path, INFO)) as f:
      checkpoint = Checkpoint(**json.load(f))
    checkpoint.observation_size = {
        k: tuple(v) for k, v in checkpoint.observation_size.items()
    }
    if params:  # numpy arrays, as Brax's `load` gives them
      # pylint: disable=g-import-not-at-top
      from brax.training import types as brax_types
      from brax.training.acme import running_statistics
      # pylint: enable=g-import-not-at-top

      ocp, checkpointer = _orbax()
      as_numpy = jax.tree.map(
          lambda _: ocp.RestoreArgs(restore_type=np.ndarray),
          checkpointer.metadata(path).item_metadata,
      )
      normalizer, policy, value = checkpointer.restore(
          path, args=ocp.args.PyTreeRestore(restore_args=as_numpy)
      )
      normalizer['count'] = brax_types.UInt64(**normalizer['count'])
      normalizer = running_statistics.RunningStatisticsState(**normalizer)
      checkpoint.params = (normalizer, policy, value)
  except Exception as e:  # json, orbax or a file missing: all mean corrupted
    raise run_folder.RunFolderError(
        f'The checkpoint {path!r} is corrupted and cannot be read '
        f'({type(e).__name__}: {e}). Delete it to resume from the one '
        'before, or start a new run.'
    ) from e
  return checkpoint


def latest(run: run_folder.RunFolder) -> Checkpoint:
  """The run's newest checkpoint, its parameters loaded (or RunFolderError)."""
  found = paths(run)
  if not found:
    raise run_folder.RunFolderError(
        f'The run folder {run.path!r} has no checkpoint in '
        'checkpoints/: it stopped before its first evaluation. '
        f'Train it again from step 0 with --resume {run.path}.'
    )
  return read(found[-1], params=True)


def check_compatible(checkpoint: Checkpoint, task: str, brax_env) -> None:
  """Raises RunFolderError unless the networks fit `brax_env` of `task`."""
  size = {k: tuple(v) for k, v in brax_env.observation_size.items()}
  saved = (checkpoint.observation_size, checkpoint.action_size)
  if (checkpoint.task, *saved) != (task, size, brax_env.action_size):
    raise run_folder.RunFolderError(
        f'The run is incompatible with task {task!r} as it is now: its '
        f'networks, trained on {checkpoint.task!r}, take observations '
        f'{saved[0]} and {saved[1]} actions, the task gives {size} and '
        f'{brax_env.action_size}. Start a new run.'
    )
