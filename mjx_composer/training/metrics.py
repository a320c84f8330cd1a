"""A run's metrics: a CSV row per evaluation, TensorBoard, Weights & Biases.

`MetricsWriter.write(step, metrics)` takes Brax's `progress_fn` metrics
(`eval/episode_reward`, `training/sps`, ...) at environment step `step` and

* appends a row to `metrics.csv` (`eval_row`: the step, wall-clock seconds,
  the evaluation return, its spread, the episode length and the training
  throughput); a resumed run appends to the same file;
* writes every scalar to TensorBoard event files in `events/`
  (tensorboardX), when asked;
* logs every scalar to Weights & Biases, when asked and installed (a
  missing wandb is an error naming the fix).
"""

from __future__ import annotations

import csv
import numbers
import os

import numpy as np

CSV_FIELDS = (
    'step',
    'wall_s',
    'eval_return',
    'eval_return_std',
    'eval_episode_length',
    'env_steps_per_s',
    'train_walltime_s',
)


def eval_row(step, metrics, wall_s, previous=None, walltime_offset=0.0):
  """One evaluation's CSV row from Brax's `progress_fn(step, metrics)`.

  `env_steps_per_s` is the training throughput since `previous` (the row
  before): environment steps over Brax's training time (`training/walltime`,
  which leaves out evaluations), 0 for the first row. Brax's own
  `training/sps` overstates it by `num_resets_per_eval` and is not used.
  `walltime_offset` is added to Brax's training time (a resumed run's time
  before it).
  """
  train_walltime = float(metrics.get('training/walltime', 0.0)) + float(
      walltime_offset
  )
  rate = 0.0
  if previous is not None:
    seconds = train_walltime - float(previous['train_walltime_s'])
    if seconds > 0:
      rate = (int(step) - int(previous['step'])) / seconds
  return {
      'step': int(step),
      'wall_s': float(wall_s),
      'eval_return': float(metrics.get('eval/episode_reward', np.nan)),
      'eval_return_std': float(metrics.get('eval/episode_reward_std', np.nan)),
      'eval_episode_length': float(
          metrics.get('eval/avg_episode_length', np.nan)
      ),
      'env_steps_per_s': rate,
      'train_walltime_s': train_walltime,
  }


def read_csv(path: str) -> list[dict]:
  """The rows of a `metrics.csv` (numbers as floats, `step` as int)."""
  if not os.path.exists(path):
    return []
  with open(path, newline='') as f:
    rows = list(csv.DictReader(f))
  return [
      {k: int(v) if k == 'step' else float(v) for k, v in row.items()}
      for row in rows
  ]


class MetricsWriter:
  """Writes evaluations to a run's CSV, TensorBoard and W&B."""

  def __init__(
      self,
      csv_path: str,
      events_dir: str | None = None,
      wandb_config: dict | None = None,
      wandb_run_name: str | None = None,
  ):
    """Opens the writers.

    Args:
      csv_path: `metrics.csv` (appended to; the header is written once).
      events_dir: TensorBoard's folder, or None for no event files.
      wandb_config: log to Weights & Biases with this config; None: don't.
      wandb_run_name: the W&B run's name (and id, so a resumed run logs
        into the same W&B run).
    """
    self._csv_path = csv_path
    self.rows = read_csv(csv_path)
    self._tb = None
    if events_dir is not None:
      try:
        import tensorboardX  # pylint: disable=g-import-not-at-top
      except ImportError as e:
        raise ImportError(
            'TensorBoard event files need tensorboardX: pip install '
            "'mjx-composer[train]', or pass --no-tensorboard."
        ) from e
      self._tb = tensorboardX.SummaryWriter(events_dir)
    self._wandb = None
    if wandb_config is not None:
      try:
        import wandb  # pylint: disable=g-import-not-at-top
      except ImportError as e:
        raise ImportError(
            'Weights & Biases logging needs wandb: pip install wandb, or '
            'leave out --wandb.'
        ) from e
      self._wandb = wandb.init(
          project='mjx_composer',
          name=wandb_run_name,
          id=wandb_run_name,
          resume='allow',
          config=wandb_config,
      )

  def write(self, row: dict, metrics: dict) -> None:
    """Appends `row` (an `eval_row`) and logs every scalar of `metrics`."""
    new_file = not os.path.exists(self._csv_path)
    with open(self._csv_path, 'a', newline='') as f:
      writer = csv.DictWriter(f, fieldnames=list(CSV_FIELDS))
      if new_file:
        writer.writeheader()
      writer.writerow({k: row[k] for k in CSV_FIELDS})
    self.rows.append(row)
    scalars = {
        name: float(np.asarray(value))
        for name, value in metrics.items()
        if isinstance(value, numbers.Number) or np.ndim(value) == 0
    }
    scalars['eval/env_steps_per_s'] = row['env_steps_per_s']
    step = row['step']
    if self._tb is not None:
      for name, value in scalars.items():
        self._tb.add_scalar(name, value, step)
      self._tb.flush()
    if self._wandb is not None:
      self._wandb.log(scalars, step=step)

  def close(self) -> None:
    if self._tb is not None:
      self._tb.close()
    if self._wandb is not None:
      self._wandb.finish()
