"""Checkpoints that resume a Brax PPO run exactly where it stopped.

A checkpoint holds what Brax's `TrainingState` holds: the step count, the
normalizer, policy and value parameters, and the optimizer state (Adam's
moments and count), plus what the networks were built for (task,
observation sizes, action size). It is a pickle of numpy arrays, written
through a temporary file, so an interrupted write never leaves half a
checkpoint.

Brax 0.14's `ppo.train` restores the parameters (`restore_params`) but not
the optimizer state, and saves no optimizer state (`save_checkpoint_path`
writes the parameters and the network config only). Without changing
Brax, this module

* reads the full `TrainingState` in `policy_params_fn`, which `ppo.train`
  calls from its own frame after each training epoch
  (`training_state_of_caller`), and
* restores the optimizer state by handing `ppo.train` an Adam whose `init`
  returns the saved state (`restoring_optimizer`), checked against the
  structure and shapes that a fresh Adam's `init` gives.

Both depend on Brax's `train` function as of 0.14; a Brax without them
fails here with an error that says so, not with wrong results.
"""

from __future__ import annotations

import contextlib
import dataclasses
import glob
import os
import pickle
import re
import sys
import types
from typing import Any

import jax
import numpy as np

from mjx_composer.training import run_folder

FORMAT = 1
_NAME = re.compile(r'step_(\d+)\.pkl$')


@dataclasses.dataclass
class Checkpoint:
  """One saved training state (numpy leaves).

  Attributes:
    step: environment steps trained so far.
    evaluations: evaluations after training so far (Brax's step-0
      evaluation not counted).
    params: `(normalizer, policy, value)` as `ppo.train` returns them.
    optimizer_state: the optimizer's state (optax), or None.
    task: the task trained.
    observation_size: `{group: shape}` the networks were built for.
    action_size: the number of actions.
    steps_per_evaluation: environment steps between two evaluations.
  """

  step: int
  evaluations: int
  params: Any
  optimizer_state: Any
  task: str
  observation_size: dict
  action_size: int
  steps_per_evaluation: int


def path_for(run: run_folder.RunFolder, step: int) -> str:
  return os.path.join(run.checkpoint_dir, f'step_{step:012d}.pkl')


def save(run: run_folder.RunFolder, checkpoint: Checkpoint) -> str:
  """Writes `checkpoint` into the run's checkpoints; returns its path."""
  os.makedirs(run.checkpoint_dir, exist_ok=True)
  path = path_for(run, checkpoint.step)
  payload = {
      f.name: jax.device_get(getattr(checkpoint, f.name))
      for f in dataclasses.fields(checkpoint)
  }
  payload['format'] = FORMAT
  tmp = f'{path}.tmp'
  with open(tmp, 'wb') as f:
    pickle.dump(payload, f)
  os.replace(tmp, path)
  return path


def paths(run: run_folder.RunFolder) -> list[str]:
  """The run's checkpoint files, oldest (fewest steps) first."""
  found = glob.glob(os.path.join(run.checkpoint_dir, 'step_*.pkl'))
  return sorted(f for f in found if _NAME.search(f))


def load(path: str) -> Checkpoint:
  """Reads a checkpoint file.

  Raises:
    RunFolderError: for a file that is unreadable, truncated or not a
      checkpoint of this format.
  """
  try:
    with open(path, 'rb') as f:
      payload = pickle.load(f)
  except (
      OSError,
      EOFError,
      pickle.UnpicklingError,
      AttributeError,
      ImportError,
      IndexError,
      TypeError,
      ValueError,
  ) as e:
    raise run_folder.RunFolderError(
        f'The checkpoint {path!r} is corrupted and cannot be read '
        f'({type(e).__name__}: {e}). Delete it to resume from the one '
        'before, or start a new run.'
    ) from e
  if not isinstance(payload, dict) or payload.get('format') != FORMAT:
    raise run_folder.RunFolderError(
        f'{path!r} is not a checkpoint of this version (format {FORMAT}); '
        'start a new run.'
    )
  payload.pop('format')
  try:
    return Checkpoint(**payload)
  except TypeError as e:
    raise run_folder.RunFolderError(
        f'The checkpoint {path!r} is corrupted ({e}); start a new run.'
    ) from e


def latest(run: run_folder.RunFolder) -> Checkpoint:
  """The run's newest checkpoint.

  Raises:
    RunFolderError: if the run has none (it stopped before its first
      evaluation) or the newest is corrupted.
  """
  found = paths(run)
  if not found:
    raise run_folder.RunFolderError(
        f'The run folder {run.path!r} has no checkpoint in '
        f'{run_folder.CHECKPOINTS}/: it stopped before its first evaluation. '
        'Start a new run.'
    )
  return load(found[-1])


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


# -- Brax's training state ---------------------------------------------------


def training_state_of_caller(depth: int = 2):
  """The `TrainingState` of the `ppo.train` call `depth` frames up.

  Call it from a `policy_params_fn`: Brax's `ppo.train` calls that from its
  own frame, whose local `training_state` is the state after the epoch
  (replicated over devices: the first copy is returned).

  Raises:
    RuntimeError: if the calling frame has no `training_state` (a Brax
      version whose `train` differs from 0.14's).
  """
  frame = sys._getframe(depth)  # pylint: disable=protected-access
  state = frame.f_locals.get('training_state')
  if state is None or not hasattr(state, 'optimizer_state'):
    raise RuntimeError(
        'Could not read the optimizer state of ppo.train: this Brax version '
        "calls policy_params_fn from elsewhere than 0.14's train(). Pin "
        'brax 0.14, or resume without the optimizer state.'
    )
  return jax.tree.map(lambda x: np.asarray(x[0]), state)


@contextlib.contextmanager
def restoring_optimizer(adam_state):
  """Within: Brax's `ppo.train` starts Adam from `adam_state`.

  Brax builds `optax.adam(learning_rate)` (chained after gradient clipping
  when `max_grad_norm` is set) and calls its `init` once; this hands
  `ppo.train` an Adam whose `init` returns `adam_state` after checking it
  against the fresh state's structure, shapes and dtypes.

  Args:
    adam_state: Adam's saved state (the optimizer state itself, or its
      second element when it was chained after clipping); None: no change.
  """
  if adam_state is None:
    yield
    return
  from brax.training.agents.ppo import train as ppo_train  # pylint: disable=g-import-not-at-top
  import optax  # pylint: disable=g-import-not-at-top

  if getattr(ppo_train, 'optax', None) is not optax:
    raise RuntimeError(
        'brax.training.agents.ppo.train no longer builds its optimizer with '
        'optax.adam: the optimizer state cannot be restored with this Brax.'
    )

  def adam(*args, **kwargs):
    fresh = optax.adam(*args, **kwargs)

    def init(params):
      want = fresh.init(params)
      got = jax.tree.map(np.asarray, adam_state)
      same = jax.tree.structure(want) == jax.tree.structure(got) and all(
          np.shape(a) == np.shape(b)
          for a, b in zip(jax.tree.leaves(want), jax.tree.leaves(got))
      )
      if not same:
        raise run_folder.RunFolderError(
            "The checkpoint's optimizer state does not fit the networks "
            '(different layer sizes?): start a new run.'
        )
      return jax.tree.map(
          lambda w, g: jax.numpy.asarray(g, dtype=w.dtype), want, got
      )

    return optax.GradientTransformation(init, fresh.update)

  proxy = types.SimpleNamespace(
      **{k: getattr(optax, k) for k in dir(optax) if not k.startswith('__')}
  )
  proxy.adam = adam
  ppo_train.optax = proxy
  try:
    yield
  finally:
    ppo_train.optax = optax
