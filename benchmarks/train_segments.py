"""A `train_compare.py` run's schedule, its time limit, and its segments.

Brax's `ppo.train` evaluates on a fixed schedule of env steps
(`interval_steps`, `brax_env_steps`). A run may be stopped after an
evaluation so that it fits a time limit (`next_eval_too_late`, raising
`StopTraining` from the `progress_fn`; `CompileClock` times the compiles
the estimate leaves out), and continued later in a new process, a segment,
for the evaluations it has left (`--resume`):

* the policy, value and observation-normalizer parameters carry over
  (Brax's `ppo.train(restore_params=..., restore_value_fn=True)`), from
  `runs/<env>_seed<seed>_policy.pkl` (`save_params`, `load_stopped_run`);
* so does the schedule: the next segment trains the evaluation intervals
  left, each of the same training steps, so the evaluations fall on the
  same env steps as in one run (`remaining_schedule`, `segment_to_train`);
* the optimizer's state does not: Brax restores parameters only, so Adam's
  moment estimates start again from zero at each segment;
* the environments' states do not either; with `num_resets_per_eval > 0`
  (Playground's settings) Brax resets every world after each training step
  anyway;
* segment k trains with Brax seed `segment_seed(seed, k)`, so no segment
  replays another's keys.

Each segment compiles its programs again and evaluates the restored policy
once before training; the run's rows record that time as
`resume_overhead_s` (and the compile seconds within it as
`resume_compile_s`; `train_results.continued_row`), and the table and plot
time a run as if it had trained in one process
(`train_results.one_process_wall`). The run's `segment_starts` keep that
evaluation's return beside the one the policy earned when it was saved
(equal but for the evaluation's own randomness, when the restore took).
"""

import json
import math
import os
import pickle
import sys

import jax

import train_results

# Brax seeds of later segments: far from any seed a user passes.
_SEGMENT_SEED_STRIDE = 1_000_003


class CompileClock:
  """Seconds this process has spent lowering and compiling since creation.

  Sums JAX's lowering and XLA compile events (`jax.monitoring`); tracing is
  left out because nested traces report inside their callers' (it would
  count twice), so the figure is a lower bound. One listener per process
  feeds every clock.
  """

  _EVENTS = (
      '/jax/core/compile/jaxpr_to_mlir_module_duration',
      '/jax/core/compile/backend_compile_duration',
  )
  _total = 0.0  # seconds since the listener was registered
  _listening = False

  def __init__(self):
    if not CompileClock._listening:
      jax.monitoring.register_event_duration_secs_listener(CompileClock._record)
      CompileClock._listening = True
    self._start = CompileClock._total

  @staticmethod
  def _record(event, duration, **kwargs):
    del kwargs
    if event in CompileClock._EVENTS:
      CompileClock._total += duration

  @property
  def seconds(self) -> float:
    return CompileClock._total - self._start


class StopTraining(Exception):
  """Raised by a `progress_fn` to end `ppo.train` after an evaluation."""


def next_eval_too_late(rows, max_wall_s, planned_steps=None):
  """Whether the evaluation after `rows[-1]` would end after `max_wall_s`.

  The next evaluation is expected as long after the last as the last was
  after the one before it (after the start, for the first), less the time
  that interval spent compiling (`compile_s`): the first training update
  compiles the training program, and the updates after it do not. (A
  program that compiles again later, like Brax's evaluator on Playground's
  environments, makes the estimate short by that compile.) False when
  `max_wall_s` is None, and after the last evaluation (`rows[-1]`'s step
  reaches `planned_steps`, where given): a run that has trained all its
  steps is finished, not stopped.
  """
  if max_wall_s is None or not rows:
    return False
  if planned_steps is not None and rows[-1]['step'] >= planned_steps:
    return False
  last = rows[-1]
  before = rows[-2] if len(rows) > 1 else {'wall_s': 0.0, 'compile_s': 0.0}
  interval = (last['wall_s'] - before['wall_s']) - (
      last.get('compile_s', 0.0) - before.get('compile_s', 0.0)
  )
  return last['wall_s'] + max(interval, 0.0) > max_wall_s


def _env_steps_per_training_step(config):
  return (
      config['batch_size']
      * config['unroll_length']
      * config['num_minibatches']
      * config.get('action_repeat', 1)
  )


def interval_steps(config):
  """Env steps between two evaluations of `ppo.train` under `config`."""
  per_step = _env_steps_per_training_step(config)
  resets = max(config.get('num_resets_per_eval', 0), 1)
  intervals = max(config['num_evals'] - 1, 1)
  steps_per_epoch = math.ceil(
      config['num_timesteps'] / (intervals * resets * per_step)
  )
  return steps_per_epoch * resets * per_step


def brax_env_steps(config):
  """The env steps `ppo.train` runs for `config` (its `ppo.train` kwargs)."""
  return max(config['num_evals'] - 1, 1) * interval_steps(config)


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


def save_params(path, params, config):
  """Writes `{'params': params (numpy leaves), 'config': config}`."""
  with open(path, 'wb') as f:
    pickle.dump({'params': jax.device_get(params), 'config': config}, f)


def load_stopped_run(json_path, policy_path):
  """`(run record, saved params)` of a run to continue, or None.

  None when there is no record, or it has no evaluation after training (a
  run stopped at its first evaluation trained nothing: start it again).

  Raises:
    FileNotFoundError: the record has trained evaluations but the
      parameters file (`save_params`') is missing.
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


def check_something_to_resume(out, envs, seeds):
  """Refuses `--resume` where `out` holds none of the requested runs.

  A run without a record starts from its first step, so `--resume` over
  an empty `--out` (say, a job on a fresh machine that did not bring the
  previous job's runs) would quietly train every run's first segment
  again.

  Raises:
    SystemExit: no requested (env, seed) has a record in `out/runs/`.
  """
  wanted = [
      os.path.join(out, 'runs', train_results.run_name(env, seed) + '.json')
      for seed in seeds
      for env in envs
  ]
  if not any(os.path.exists(path) for path in wanted):
    sys.exit(
        f'--resume: {os.path.join(out, "runs")} holds no record of '
        f'{", ".join(envs)} with seeds {seeds}. Bring the earlier '
        "call's runs (records and *_policy.pkl) into --out (on a device, "
        'with carry), or leave out --resume to start these runs.'
    )


def segment_to_train(run, config, name):
  """`(segment index, its config)` to continue `run`, or None if done.

  Raises:
    ValueError: `run` was trained with other hyper-parameters.
  """
  if run['hyperparameters'] != config:
    raise ValueError(
        f'{name}: --resume with other hyper-parameters than the stored run '
        f'({run["hyperparameters"]} there, {config} now): pass the same '
        'overrides, or leave out --resume to start again.'
    )
  left = (
      None
      if run['status'] == 'finished'
      else remaining_schedule(config, run['rows'][-1]['step'])
  )
  if left is None:
    return None
  segment_config = dict(config)
  segment_config['num_timesteps'], segment_config['num_evals'] = left
  return run.get('segments', 1), segment_config
