"""A training run's folder: what it holds, creating it, opening it again.

    RUN/
      config.json         the resolved TrainConfig (config.to_dict)
      metrics.csv         one row per evaluation (metrics.MetricsWriter)
      events/             TensorBoard event files (tensorboardX)
      checkpoints/<STEP>/ the latest and the best checkpoint (checkpoints)
      videos/             eval_step_<STEP>.mp4, play_*.mp4 (video.write_mp4)
      summary.json        written when training ends
      policy.onnx         written by `mjx-composer export RUN`

Opening a folder checks it is one (`RunFolderError` says what is wrong and
how to fix it): a folder that does not exist, has no or an unreadable
`config.json`, or (`require_checkpoint`) no checkpoint.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time

from mjx_composer.training import config as config_lib

CONFIG = 'config.json'
METRICS_CSV = 'metrics.csv'
EVENTS = 'events'
CHECKPOINTS = 'checkpoints'
VIDEOS = 'videos'
SUMMARY = 'summary.json'


class RunFolderError(ValueError):
  """A run folder that is missing, corrupted or does not fit the request."""


@dataclasses.dataclass(frozen=True)
class RunFolder:
  """Paths of a run folder rooted at `path`."""

  path: str

  def join(self, *parts: str) -> str:
    return os.path.join(self.path, *parts)

  @property
  def config_path(self) -> str:
    return self.join(CONFIG)

  @property
  def metrics_csv(self) -> str:
    return self.join(METRICS_CSV)

  @property
  def events_dir(self) -> str:
    return self.join(EVENTS)

  @property
  def checkpoint_dir(self) -> str:
    return self.join(CHECKPOINTS)

  @property
  def video_dir(self) -> str:
    return self.join(VIDEOS)

  @property
  def summary_path(self) -> str:
    return self.join(SUMMARY)

  def read_config(self) -> config_lib.TrainConfig:
    """The run's resolved config.

    Raises:
      RunFolderError: if `config.json` is missing or unreadable.
    """
    if not os.path.isfile(self.config_path):
      raise RunFolderError(
          f'{self.path!r} is not a run folder: it has no {CONFIG}. Pass the '
          'folder that `mjx-composer train` created (its --run-dir).'
      )
    try:
      with open(self.config_path) as f:
        values = json.load(f)
      return config_lib.from_dict(values, where=self.config_path)
    except (json.JSONDecodeError, UnicodeDecodeError, ValueError) as e:
      raise RunFolderError(
          f'The run folder {self.path!r} is corrupted: {CONFIG} could not be '
          f'read ({e}). Restore it, or start a new run.'
      ) from e

  def write_config(self, config: config_lib.TrainConfig) -> None:
    write_json(self.config_path, config_lib.to_dict(config))


def write_json(path: str, payload) -> None:
  """Writes `payload` as JSON through a temporary file (never half a file)."""
  tmp = f'{path}.tmp'
  with open(tmp, 'w') as f:
    json.dump(payload, f, indent=1, default=str)
  os.replace(tmp, path)


def default_path(task: str, root: str = 'runs') -> str:
  """`root/<task>_<UTC time>`: a new run folder's default path."""
  return os.path.join(root, f'{task}_{time.strftime("%Y%m%d_%H%M%S")}')


def create(path: str, config: config_lib.TrainConfig) -> RunFolder:
  """A new run folder at `path` holding `config`.

  Raises:
    RunFolderError: if `path` already holds a run (resume it with --resume,
      or choose another folder).
  """
  run = RunFolder(path)
  if os.path.exists(run.config_path):
    raise RunFolderError(
        f'{path!r} already holds a run: continue it with --resume {path} (a '
        'run without a checkpoint trains again from step 0), or pass another '
        '--run-dir.'
    )
  for folder in (run.path, run.checkpoint_dir, run.video_dir):
    os.makedirs(folder, exist_ok=True)
  run.write_config(config)
  return run


def open_run(path: str) -> RunFolder:
  """The existing run folder at `path`, its config checked readable.

  Raises:
    RunFolderError: for a path that does not exist or is not a run folder.
  """
  if not os.path.isdir(path):
    raise RunFolderError(
        f'No run folder at {path!r}. Pass the folder that `mjx-composer '
        'train` created (its --run-dir).'
    )
  run = RunFolder(path)
  run.read_config()
  return run
