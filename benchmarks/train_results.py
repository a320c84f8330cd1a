"""The runs of `train_compare.py`: their files, summary, table and plot.

A run is one (environment, seed) of Brax PPO: a record in
`OUT/runs/<env>_seed<seed>.json` holding its settings and one row per
evaluation (`eval_row`; rows of a resumed run also carry `segment`,
`resume_overhead_s` and `resume_compile_s`, `continued_row`), and the same
rows in `OUT/runs/<env>_seed<seed>.csv`. This module writes the rows,
reads and merges the records, and turns them into what
`train_compare.py --plot` prints and draws.

Times are read on the clock of one process (`one_process_wall`). A run
continued with `--resume` pays, in each segment after the first, a resume
overhead (compiling again, evaluating the restored policy again, then
compiling the training program again) that the same run in one process
would not; its rows' `wall_s` include them. That
overhead is an artefact of the time limit the run was split by, not of
either environment (both are segmented alike), so times to the
threshold, totals and the plot leave it out, and the table says how much
was left out.
"""

import csv
import glob
import json
import os

import numpy as np

# An evaluation's row (`eval_row`), in the runs' CSV files.
ROW_FIELDS = (
    'step',
    'wall_s',
    'compile_s',
    'train_walltime_s',
    'env_steps_per_s',
    'train_sps',
    'eval_walltime_s',
    'eval_return',
    'eval_return_std',
    'eval_episode_length',
)
# The merged `results.csv`'s columns.
CSV_FIELDS = (
    'env',
    'seed',
    'step',
    'wall_s',
    'train_walltime_s',
    'env_steps_per_s',
    'train_sps',
    'eval_walltime_s',
    'eval_return',
    'eval_return_std',
    'eval_episode_length',
    'segment',
    'resume_overhead_s',
    'resume_compile_s',
)
_COLOURS = {
    'playground': 'tab:blue',
    'ours': 'tab:orange',
    'ours_off': 'tab:green',
}
# For the other environments (only_... variants), in order of appearance.
_MORE_COLOURS = ('tab:red', 'tab:purple', 'tab:brown', 'tab:pink', 'tab:cyan')


def run_name(env, seed):
  return f'{env}_seed{seed}'


def write_json(path, data):
  """Writes `data` to `path` atomically (other processes read it)."""
  tmp = f'{path}.{os.getpid()}.tmp'
  with open(tmp, 'w') as f:
    json.dump(data, f, indent=1, default=str)
  os.replace(tmp, path)


def eval_row(step, metrics, wall_s, compile_s=0.0, previous=None):
  """One evaluation's row from Brax's `progress_fn(step, metrics)`.

  `mjx_composer.training.trainer.eval_row`'s columns (step, wall_s: the
  caller's clock, seconds since the start of `ppo.train`;
  train_walltime_s: Brax's training time, without evaluating or the resets
  between epochs, its first update compiling; env_steps_per_s: the env
  steps since `previous`, the row before, over the training time since
  then, 0 for the first row; eval_return, eval_return_std and
  eval_episode_length over the evaluation episodes) and three more:
  compile_s (seconds of wall_s spent lowering and compiling, a
  `train_segments.CompileClock`'s), train_sps (Brax's 'training/sps',
  which is NOT the training throughput: Brax times one training epoch but
  counts `num_resets_per_eval` epochs' steps in it, so it overstates the
  rate by that factor, 2 or 10 with Playground's settings) and
  eval_walltime_s (Brax's total time spent evaluating so far, this
  evaluation included). In `ROW_FIELDS`' order.
  """
  from mjx_composer.training import trainer  # pylint: disable=g-import-not-at-top

  row = trainer.eval_row(step, metrics, wall_s, previous=previous)
  row.update(
      compile_s=float(compile_s),
      train_sps=float(metrics.get('training/sps', 0.0)),
      eval_walltime_s=float(metrics.get('eval/walltime', 0.0)),
  )
  return {name: row[name] for name in ROW_FIELDS}


def continued_row(row, previous_rows, segment, overhead_s, overhead_compile_s):
  """`row` of a resumed segment, placed after the run's `previous_rows`.

  Steps, wall-clock, compile seconds and Brax's training time continue from
  the last previous row; `segment`, `resume_overhead_s` (the seconds this
  segment spent before its first training step: building, compiling and
  the restored policy's evaluation) and `resume_compile_s` (the compile
  seconds of those) are recorded with it.
  """
  last = previous_rows[-1]
  out = dict(row)
  out['step'] = last['step'] + row['step']
  out['wall_s'] = last['wall_s'] + row['wall_s']
  out['compile_s'] = last.get('compile_s', 0.0) + row['compile_s']
  out['train_walltime_s'] = last['train_walltime_s'] + row['train_walltime_s']
  out['eval_walltime_s'] = last['eval_walltime_s'] + row['eval_walltime_s']
  out['segment'] = segment
  out['resume_overhead_s'] = overhead_s
  out['resume_compile_s'] = overhead_compile_s
  return out


def append_csv(path, row):
  """Appends `row` (a dict) to the CSV at `path`, with a header if new."""
  header = not os.path.exists(path)
  with open(path, 'a', newline='') as f:
    writer = csv.DictWriter(f, fieldnames=list(row))
    if header:
      writer.writeheader()
    writer.writerow(row)


def load_runs(out):
  """Every run in `out/runs/*.json` (else `out/results.json`), sorted."""
  paths = sorted(glob.glob(os.path.join(out, 'runs', '*.json')))
  runs = []
  for path in paths:
    with open(path) as f:
      runs.append(json.load(f))
  if not paths and os.path.exists(os.path.join(out, 'results.json')):
    with open(os.path.join(out, 'results.json')) as f:
      runs = json.load(f)['runs']
  return sorted(runs, key=lambda r: (r['env'], r['seed']))


def write_merged(out):
  """Regenerates `results.json` and `results.csv` from `out/runs/`."""
  runs = load_runs(out)
  write_json(os.path.join(out, 'results.json'), {'runs': runs})
  tmp = os.path.join(out, f'results.csv.{os.getpid()}.tmp')
  with open(tmp, 'w', newline='') as f:
    writer = csv.DictWriter(f, fieldnames=CSV_FIELDS, extrasaction='ignore')
    writer.writeheader()
    for run in runs:
      for row in run['rows']:
        writer.writerow({'env': run['env'], 'seed': run['seed'], **row})
  os.replace(tmp, os.path.join(out, 'results.csv'))
  return runs


def one_process_wall(rows):
  """Each row's wall-clock as if the run had been trained in one process.

  A row's `wall_s` continues the previous segment's clock, so it includes
  what resuming cost in every segment after the first up to its own: the
  segment's resume overhead (`resume_overhead_s`: building, compiling the
  evaluator again and evaluating the restored policy again, before the
  first training step), and then compiling the training program again
  (in its first interval). This subtracts both; segment 0's compiling and
  first evaluation, which one process pays too, stay.

  The second part is the segment's compile seconds up to its first row
  (`compile_s` counts on, `continued_row`) less those of the
  overhead (`resume_compile_s`). Rows written before the overhead's own
  compile seconds were recorded lack `resume_compile_s`; for them the
  larger of the overhead and the segment's compile seconds is left out,
  which leaves in the restored policy's evaluation run (seconds, not
  compiling) or less.

  Args:
    rows: a run's rows, in order; those without `segment` are segment 0.

  Returns:
    A list of seconds, one per row: `wall_s` for an unsegmented run.
  """
  out = []
  left_out = 0.0
  segment = 0
  previous = None
  for row in rows:
    if row.get('segment', 0) != segment:
      segment = row.get('segment', 0)
      if segment >= 1:
        left_out += resume_cost(row, previous)
    out.append(row['wall_s'] - left_out)
    previous = row
  return out


def resume_cost(first, before):
  """Seconds a segment spent resuming: `one_process_wall`'s left-out part.

  Args:
    first: the segment's first row (after its first training interval).
    before: the previous segment's last row.
  """
  overhead = first.get('resume_overhead_s', 0.0)
  compiled = first.get('compile_s', 0.0) - before.get('compile_s', 0.0)
  if 'resume_compile_s' in first:
    return overhead + max(compiled - first['resume_compile_s'], 0.0)
  return max(overhead, compiled)


def time_to(rows, threshold):
  """(seconds, step) of the first row with eval_return >= threshold, or None.

  The seconds are `one_process_wall`'s: without what later segments spent
  resuming.
  """
  for wall, row in zip(one_process_wall(rows), rows):
    if row['eval_return'] >= threshold:
      return wall, row['step']
  return None


def training_rate(rows):
  """Env steps per second of training, without each segment's first interval.

  The env steps between consecutive evaluations over Brax's training time
  between them (`train_walltime_s`: no evaluations, no resets between
  epochs), summed over every interval but the first of each segment (of
  the run, or of a part resumed with `--resume`), which holds compiling.
  None without such an interval. Unlike Brax's 'training/sps'
  (`train_sps`), it counts each step once.
  """
  steps = seconds = 0.0
  for before, after in zip(rows[1:], rows[2:]):
    if before.get('segment', 0) != after.get('segment', 0):
      continue
    steps += after['step'] - before['step']
    seconds += after['train_walltime_s'] - before['train_walltime_s']
  return steps / seconds if seconds > 0 else None


def mean_curve(runs):
  """The seeds' mean (seconds, return) at each evaluation index all reached.

  Seconds are `one_process_wall`'s.
  """
  n = min(len(r['rows']) for r in runs)
  walls = [one_process_wall(r['rows']) for r in runs]
  wall = [np.mean([w[i] for w in walls]) for i in range(n)]
  ret = [np.mean([r['rows'][i]['eval_return'] for r in runs]) for i in range(n)]
  return np.array(wall), np.array(ret)


def summarize(runs, reference='playground', threshold=None):
  """Per-environment summary of `runs` (the `--plot` table's contents).

  Returns:
    `{'threshold': float or None, 'threshold_from': str, 'envs': {env:
    {...}}}` where each environment has `seeds`, `final_return_mean`/`_std`
    (of each seed's last evaluation, over `final_return_seeds`: the seeds
    that finished where some did, else all), `final_steps` (per seed, in
    the order of `seeds`), and per
    seed (in `per_seed`): `final_return`, `time_to_threshold_s` and
    `steps_to_threshold` (None where never reached), `total_s` (the run's
    time in `ppo.train`, or its last evaluation's for a run still going),
    `env_steps_per_s` (`training_rate`), `status`, `segments` (the
    processes it was trained in, `--resume`) and `resume_s`. Times are on
    `one_process_wall`'s clock: what the segments after the first spent
    resuming, `resume_s` seconds in all, is left out of
    `time_to_threshold_s` and `total_s` (an artefact of splitting the run
    into several processes, not of the environment). The threshold, unless
    given, is `reference`'s `final_return_mean`: a run stopped early does
    not lower it where others finished.
  """
  by_env = {}
  for run in runs:
    if run['rows']:
      by_env.setdefault(run['env'], []).append(run)
  source = '--threshold'
  if threshold is None:
    ref = by_env.get(reference)
    if ref:
      threshold = float(
          np.mean([r['rows'][-1]['eval_return'] for r in _final_runs(ref)])
      )
      source = f"{reference}'s mean final return"
    else:
      source = f'no {reference} runs'
  envs = {}
  for env, env_runs in by_env.items():
    final_runs = _final_runs(env_runs)
    finals = [r['rows'][-1]['eval_return'] for r in final_runs]
    per_seed = {}
    for r in env_runs:
      hit = time_to(r['rows'], threshold) if threshold is not None else None
      last_wall = one_process_wall(r['rows'])[-1]
      left_out = r['rows'][-1]['wall_s'] - last_wall
      n_segments = max(
          r.get('segments') or 1,
          max(row.get('segment', 0) for row in r['rows']) + 1,
      )
      total = last_wall if r.get('total_s') is None else r['total_s'] - left_out
      per_seed[r['seed']] = {
          'final_return': r['rows'][-1]['eval_return'],
          'final_step': r['rows'][-1]['step'],
          'time_to_threshold_s': hit[0] if hit else None,
          'steps_to_threshold': hit[1] if hit else None,
          'total_s': total,
          'env_steps_per_s': training_rate(r['rows']),
          'status': r['status'],
          'segments': n_segments,
          'resume_s': left_out,
      }
    seeds = sorted(per_seed)
    envs[env] = {
        'seeds': seeds,
        'final_return_mean': float(np.mean(finals)),
        'final_return_std': float(np.std(finals)),
        'final_return_seeds': sorted(r['seed'] for r in final_runs),
        'final_steps': [per_seed[k]['final_step'] for k in seeds],
        'per_seed': per_seed,
    }
  return {'threshold': threshold, 'threshold_from': source, 'envs': envs}


def _final_runs(runs):
  """The runs whose last evaluation is a final return: the finished ones
  where some finished, else all."""
  finished = [r for r in runs if r['status'] == 'finished']
  return finished or runs


def format_table(summary):
  """The summary as a Markdown table (one row per environment).

  Where a seed was trained in more than one segment (`--resume`), a
  footnote after the table says that its times are one-process-equivalent
  wall-clock, and how many seconds of resuming each seed's leave out
  (`summarize`).
  """
  threshold = summary['threshold']
  label = 'n/a' if threshold is None else f'{threshold:.1f}'
  lines = [
      f'| env | seeds | env steps per seed | final return (finished seeds) | '
      f'time to {label} per seed '
      '[s] | total per seed [s] | training env steps/s per seed |',
      '|---|---|---|---|---|---|---|',
  ]
  for env, s in summary['envs'].items():
    seeds = s['per_seed']

    def fmt(seed, d=seeds):
      t = d[seed]['time_to_threshold_s']
      return '–' if t is None else f'{t:.0f}'

    hits = ', '.join(fmt(k) for k in s['seeds'])
    totals = ', '.join(
        f'{seeds[k]["total_s"]:.0f}'
        + (
            ''
            if seeds[k]['status'] == 'finished'
            else f' ({seeds[k]["status"]})'
        )
        for k in s['seeds']
    )
    steps = ', '.join(
        f'{x / 1e6:.1f} M' if x >= 100_000 else f'{x:,}'
        for x in (
            s['final_steps'][:1]
            if len(set(s['final_steps'])) == 1
            else s['final_steps']
        )
    )
    final = f'{s["final_return_mean"]:.1f} ± {s["final_return_std"]:.1f}'
    if s['final_return_seeds'] != s['seeds']:
      final += f' (seeds {", ".join(map(str, s["final_return_seeds"]))})'
    rates = ', '.join(
        '–'
        if seeds[k]['env_steps_per_s'] is None
        else f'{seeds[k]["env_steps_per_s"] / 1e3:.0f} k'
        for k in s['seeds']
    )
    lines.append(
        f'| {env} | {", ".join(map(str, s["seeds"]))} | {steps} | '
        f'{final} | {hits} | {totals} | {rates} |'
    )
  segmented = [
      f'{env} '
      + ', '.join(
          f'{s["per_seed"][k].get("resume_s", 0.0):.0f}' for k in s['seeds']
      )
      + ' s'
      for env, s in summary['envs'].items()
      if any(d.get('segments', 1) > 1 for d in s['per_seed'].values())
  ]
  if segmented:
    # A blank line first: a line right under a table would be one of its rows.
    lines += [
        '',
        'Times are one-process-equivalent wall-clock: runs trained in '
        'segments (`--resume`) leave out what the segments after the first '
        'spent resuming (compiling again, evaluating the restored policy '
        f'again; {"; ".join(segmented)} in all per seed).',
    ]
  return '\n'.join(lines)


def plot(out, runs, summary, title):
  """Draws `out/returns.png` titled `title`; False without matplotlib.

  Every run's curve, and each environment's mean over the seeds of its
  `final_return_mean` (`summarize`). Times are `one_process_wall`'s (the
  x label says so where a run was segmented).
  """
  try:
    # pylint: disable=g-import-not-at-top
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    # pylint: enable=g-import-not-at-top
  except ImportError:
    print('matplotlib is not installed: no returns.png.')
    return False
  fig, ax = plt.subplots(figsize=(7, 4.5))
  by_env = {}
  for run in runs:
    if run['rows']:
      by_env.setdefault(run['env'], []).append(run)
  others = iter(_MORE_COLOURS)
  for env, env_runs in by_env.items():
    colour = _COLOURS.get(env) or next(others, None)
    for run in env_runs:
      ax.plot(
          one_process_wall(run['rows']),
          [r['eval_return'] for r in run['rows']],
          color=colour,
          alpha=0.35,
          linewidth=1,
      )
    # The mean of the finished seeds (where some finished): a stopped run
    # would cut every seed's mean curve at its last evaluation.
    mean_runs = _final_runs(env_runs)
    wall, ret = mean_curve(mean_runs)
    ax.plot(
        wall,
        ret,
        color=colour,
        linewidth=2.5,
        marker='o',
        markersize=3,
        label=f'{env} (mean of {len(mean_runs)} seeds)',
    )
  if summary['threshold'] is not None:
    ax.axhline(
        summary['threshold'],
        color='k',
        linestyle='--',
        linewidth=1,
        label=summary['threshold_from'],
    )
  segmented = any(
      row.get('segment', 0) > 0 for run in runs for row in run['rows']
  )
  ax.set_xlabel(
      'wall-clock time since the start of ppo.train [s]'
      + (', one-process equivalent' if segmented else '')
  )
  ax.set_ylabel('evaluation episode return')
  ax.set_title(title)
  ax.legend(loc='lower right', fontsize=8)
  fig.tight_layout()
  fig.savefig(os.path.join(out, 'returns.png'), dpi=110)
  plt.close(fig)
  return True
