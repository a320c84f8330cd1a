"""A stopped-and-resumed training run against uninterrupted runs of the task.

`mjx-composer train --resume RUN` restores the step count, the schedule and
the parameters (networks and normalizer) but not Adam's moments, which Brax's
public API does not hand out (docs/training.md, "Resume"). This script shows
what that costs: the return of the resumed run after its resume against the
spread of uninterrupted runs at the same env steps.

The runs are `mjx-composer train` run folders (`config.json`,
`metrics.csv`, and `summary.json` for a finished run). Make them with the
command itself, e.g. on one GPU:

    mjx-composer train joystick --num-timesteps 30000000 --seed S \\
        --run-dir runs/seedS                        # S = 0, 1, 2
    mjx-composer train joystick --num-timesteps 30000000 --seed 0 \\
        --run-dir runs/stopped  # stopped (SIGTERM) after some evaluations
    mjx-composer train --resume runs/stopped

then

    python benchmarks/resume_compare.py runs/stopped --baselines \\
        runs/seed0 runs/seed1 runs/seed2 --out resume.json --plot resume.png

The resumed run's resume step is `summary.json`'s `resumed_from_step`
(`--resumed-from` when its summary is gone). Uninterrupted runs may be cut
short; each evaluation step compares against the runs that reached it.
"""

import argparse
import json
import os

import numpy as np

from mjx_composer.training import run_folder
from mjx_composer.training import trainer


def read_run(path):
  """{'path', 'config', 'summary', 'rows'} of a run folder."""
  run = run_folder.RunFolder(path)
  with open(run.config_path) as f:
    config = json.load(f)
  summary = None
  if os.path.exists(run.summary_path):
    with open(run.summary_path) as f:
      summary = json.load(f)
  rows = [
      {k: r[k] for k in ('step', 'eval_return', 'eval_return_std')}
      for r in trainer.read_csv(run.metrics_csv)
  ]
  return {'path': path, 'config': config, 'summary': summary, 'rows': rows}


def compare(resumed, baselines, resumed_from):
  """One row per evaluation of `resumed` after `resumed_from`: its return
  and the uninterrupted runs' at the same step (mean, min, max, count)."""
  table = []
  for row in resumed['rows']:
    if row['step'] <= resumed_from:
      continue
    others = [
        r['eval_return']
        for run in baselines
        for r in run['rows']
        if r['step'] == row['step']
    ]
    table.append(
        {
            'step': row['step'],
            'resumed_return': row['eval_return'],
            'baseline_mean': float(np.mean(others)) if others else None,
            'baseline_min': min(others, default=None),
            'baseline_max': max(others, default=None),
            'baseline_runs': len(others),
            'inside_range': bool(others)
            and (min(others) <= row['eval_return'] <= max(others)),
        }
    )
  return table


def plot(path, resumed, baselines, resumed_from, title):
  """Draws every run's return against env steps to `path` (PNG)."""
  # pylint: disable=g-import-not-at-top
  import matplotlib

  matplotlib.use('Agg')
  import matplotlib.pyplot as plt
  # pylint: enable=g-import-not-at-top

  fig, ax = plt.subplots(figsize=(7, 4))
  for i, run in enumerate(baselines):
    steps = [r['step'] / 1e6 for r in run['rows']]
    ax.plot(
        steps,
        [r['eval_return'] for r in run['rows']],
        color='0.55',
        linewidth=1,
        marker='.',
        label='uninterrupted runs' if i == 0 else None,
    )
  steps = np.array([r['step'] for r in resumed['rows']]) / 1e6
  returns = np.array([r['eval_return'] for r in resumed['rows']])
  before = steps <= resumed_from / 1e6
  ax.plot(steps[before], returns[before], color='C0', marker='o',
          label='stopped run')  # fmt: skip
  after = np.flatnonzero(~before)
  if after.size:
    joined = np.r_[after[0] - 1, after] if before.any() else after
    ax.plot(steps[joined], returns[joined], color='C1', marker='o',
            label='resumed (fresh Adam)')  # fmt: skip
  ax.axvline(resumed_from / 1e6, color='k', linestyle=':', linewidth=1)
  ax.set_xlabel('env steps (millions)')
  ax.set_ylabel('evaluation return')
  ax.set_title(title)
  ax.legend(loc='lower right')
  fig.tight_layout()
  fig.savefig(path, dpi=110)
  plt.close(fig)


def main(argv=None):
  parser = argparse.ArgumentParser(
      description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
  )
  parser.add_argument('resumed', help='the stopped-and-resumed run folder')
  parser.add_argument('--baselines', nargs='+', required=True)
  parser.add_argument('--resumed-from', type=int)
  parser.add_argument('--device', help='recorded in the JSON, e.g. "H200"')
  parser.add_argument('--note', help='recorded in the JSON')
  parser.add_argument('--out', required=True, help='JSON record')
  parser.add_argument('--plot', help='PNG of the curves')
  args = parser.parse_args(argv)
  resumed = read_run(args.resumed)
  baselines = [read_run(p) for p in args.baselines]
  resumed_from = args.resumed_from
  if resumed_from is None:
    resumed_from = (resumed['summary'] or {}).get('resumed_from_step')
  if resumed_from is None:
    parser.error(
        f'{args.resumed} has no summary.json naming the step it resumed '
        'from: pass --resumed-from STEP.'
    )
  task = resumed['config']['task']
  for run in baselines:
    if run['config']['task'] != task:
      parser.error(f'{run["path"]} trained {run["config"]["task"]!r}, not '
                   f'{task!r}.')  # fmt: skip
  table = compare(resumed, baselines, resumed_from)
  record = {
      'task': task,
      'device': args.device,
      'note': args.note,
      'resumed_from_step': resumed_from,
      'comparison': table,
      'runs': {
          'resumed': resumed,
          'baselines': baselines,
      },
  }
  with open(args.out, 'w') as f:
    json.dump(record, f, indent=1)
  if args.plot:
    title = f'{task}: resumed at {resumed_from:,} steps'
    plot(args.plot, resumed, baselines, resumed_from, title)
  print(f'{"step":>12} {"resumed":>8} {"mean":>8} {"min":>8} {"max":>8}  n')
  for r in table:
    if r['baseline_runs']:
      print(
          f'{r["step"]:>12,} {r["resumed_return"]:8.2f} '
          f'{r["baseline_mean"]:8.2f} {r["baseline_min"]:8.2f} '
          f'{r["baseline_max"]:8.2f}  {r["baseline_runs"]}'
      )
  inside = sum(r['inside_range'] for r in table)
  print(f'{inside} of {len(table)} evaluations after the resume lie within '
        'the uninterrupted runs\' range.')  # fmt: skip


if __name__ == '__main__':
  main()
