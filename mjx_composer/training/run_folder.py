"""A training run's folder: what it holds, creating it, opening it again.

`RUN/` holds `config.json`, `metrics.csv`, `events/` (TensorBoard),
`checkpoints/`, `videos/`, `summary.json` and `policy.onnx`. Opening a folder
checks it is one: `RunFolderError` says what is wrong and how to fix it.
"""

from __future__ import annotations

import dataclasses
import json
import os

from mjx_composer.training import config as config_lib

CONFIG = 'config.json'


class RunFolderError(ValueError):
  """A run folder that is missing, corrupted or does not fit the request."""


@dataclasses.dataclass(frozen=True)
class RunFolder:
  """Paths of a run folder rooted at `path`."""

  path: str

  def join(self, *parts: str) -> str:
    return os.path.join(self.path, *parts)

  config_path = property(lambda self: self.join(CONFIG))
  metrics_csv = property(lambda self: self.join('metrics.csv'))
  events_dir = property(lambda self: self.join('events'))
  checkpoint_dir = property(lambda self: self.join('checkpoints'))
  video_dir = property(lambda self: self.join('videos'))
  summary_path = property(lambda self: self.join('summary.json'))

  def read_config(self) -> config_lib.TrainConfig:
    """The run's resolved config; RunFolderError if missing or unreadable."""
    if not os.path.isfile(self.config_path):
      raise RunFolderError(
          f'{self.path!r} is not a run folder: it has no {CONFIG}. Pass the '
          'folder that `mjx-composer train` created (its --run-dir).'
      )
    try:
      with open(self.config_path) as f:
        return config_lib.from_dict(json.load(f), where=self.config_path)
    except (json.JSONDecodeError, UnicodeDecodeError, ValueError) as e:
      raise RunFolderError(
          f'The run folder {self.path!r} is corrupted: {CONFIG} could not be '
          f'read ({e}). Restore it, or start a new run.'
      ) from e

  def write_config(self, config: config_lib.TrainConfig) -> None:
    write_json(self.config_path, config_lib.to_dict(config))


def write_json(path: str, payload) -> None:
  """Writes `payload` as JSON through a temporary file (never half a file)."""
  with open(f'{path}.tmp', 'w') as f:
    json.dump(payload, f, indent=1, default=str)
  os.replace(f'{path}.tmp', path)


def create(path: str, config: config_lib.TrainConfig) -> RunFolder:
  """A new run folder at `path` holding `config`; RunFolderError if taken."""
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
  """The run folder at `path`, its config checked; else RunFolderError."""
  if not os.path.isdir(path):
    raise RunFolderError(
        f'No run folder at {path!r}. Pass the folder that `mjx-composer '
        'train` created (its --run-dir).'
    )
  run = RunFolder(path)
  run.read_config()
  return run
