"""A Brax PPO run continued across processes, for time-limited device calls.

Playground's HumanoidWalk schedule (88.5 M env steps) takes longer than one
10-minute device call on one GPU (README, Locomotion). `train_compare.py
--resume` trains such a run in segments: a segment stops after an evaluation
(`--max-wall-s`), its run record and policy stay in `--out`, and the next
invocation continues from them.

What carries over, and what does not:

* the policy, value and observation-normalizer parameters (Brax's
  `ppo.train(restore_params=..., restore_value_fn=True)`);
* the schedule: the next segment trains the evaluation intervals left, each
  of the same training steps, so the evaluations fall on the same env steps
  as in one run (`remaining_schedule`);
* not the optimizer's state: Brax restores parameters only, so Adam's moment
  estimates start again from zero at each segment;
* not the environments' states: with `num_resets_per_eval > 0` (Playground's
  settings) Brax resets every world after each training step anyway;
* not the random stream: segment k trains with Brax seed `segment_seed(seed,
  k)`, so no segment replays another's keys.

Each segment compiles its programs again and evaluates the restored policy
once before training; the run's rows record that time as
`resume_overhead_s` (and the compile seconds within it as
`resume_compile_s`), so wall-clock times can be read with and without it
(`train_results.one_process_wall`),
and the run's `segment_starts` keep that evaluation's return beside the one
the policy earned when it was saved (equal but for the evaluation's own
randomness, when the restore took).
"""

import json
import math
import os
import pickle

# Brax seeds of later segments: far from any seed a user passes.
_SEGMENT_SEED_STRIDE = 1_000_003


def interval_steps(config):
  """Env steps between two evaluations of `ppo.train` under `config`."""
  per_step = (
      config['batch_size']
      * config['unroll_length']
      * config['num_minibatches']
      * config.get('action_repeat', 1)
  )
  resets = max(config.get('num_resets_per_eval', 0), 1)
  intervals = max(config['num_evals'] - 1, 1)
  steps_per_epoch = math.ceil(
      config['num_timesteps'] / (intervals * resets * per_step)
  )
  return steps_per_epoch * resets * per_step


def remaining_schedule(config, steps_done):
  """`(num_timesteps, num_evals)` that train what is left after `steps_done`.

  Args:
    config: the whole run's `ppo.train` hyper-parameters.
    steps_done: env steps at the evaluation the run stopped after.

  Returns:
    The overrides for the next segment, or None when nothing is left.

  Raises:
    ValueError: `steps_done` is not at an evaluation of `config`'s schedule.
  """
  interval = interval_steps(config)
  intervals = max(config['num_evals'] - 1, 1)
  done, rest = divmod(int(steps_done), interval)
  if rest:
    raise ValueError(
        f'{steps_done:,} env steps is not at an evaluation of this schedule '
        f'(every {interval:,}): was the run trained with other settings?'
    )
  left = intervals - done
  if left <= 0:
    return None
  return left * interval, left + 1


def segment_seed(seed, segment):
  """Brax's seed for segment `segment` (0 is the first) of seed `seed`."""
  return seed + _SEGMENT_SEED_STRIDE * segment


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


def load(json_path, policy_path):
  """`(run record, saved params)` of a run to continue, or None.

  None when there is no record, or it has no evaluation after training (a
  run stopped at its first evaluation trained nothing: start it again).

  Raises:
    FileNotFoundError: the record has trained evaluations but the
      parameters file is missing.
  """
  if not os.path.exists(json_path):
    return None
  with open(json_path) as f:
    run = json.load(f)
  if not run.get('rows') or run['rows'][-1]['step'] == 0:
    return None
  if not os.path.exists(policy_path):
    raise FileNotFoundError(
        f'{json_path} records {run["rows"][-1]["step"]:,} env steps but '
        f'{policy_path}, their parameters, is missing: bring it with the '
        'record, or leave out --resume to start the run again.'
    )
  with open(policy_path, 'rb') as f:
    params = pickle.load(f)['params']
  return run, params
