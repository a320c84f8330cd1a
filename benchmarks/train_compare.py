"""Brax PPO on Playground's HumanoidWalk and on our walk task, several seeds.

Trains Brax's PPO (`brax.training.agents.ppo.train`) with MuJoCo
Playground's hyper-parameters for `HumanoidWalk` on each environment of
`--envs`, for each seed of `--seeds`, one run after the other, and records
every evaluation: env steps, wall-clock seconds since the start of
`ppo.train` (compilation included), Brax's evaluation return (mean and std
over `--eval-envs` episodes) and Brax's own training and evaluation times.

    python benchmarks/train_compare.py --out runs/compare          # 3 seeds x 2
    python benchmarks/train_compare.py --out runs/compare --envs ours --seeds 1
    python benchmarks/train_compare.py --out runs/compare --gpus 0,1,2,3,4,5
    python benchmarks/train_compare.py --out runs/compare --plot

Environments (`--envs`):

* playground: `mujoco_playground.registry.load('HumanoidWalk')` with the
  config overrides `{'impl': --playground-impl}` (default 'jax', MJX's JAX
  implementation, like ours; Playground's training script takes `--impl`
  too), trained the way Playground's `learning/train_jax_ppo.py` does: its
  PPO config as `ppo.train`'s arguments, Brax's default PPO networks, a
  second instance as `eval_env`, `wrap_env_fn=wrapper.wrap_for_brax_training`;
* ours: `--task walk` as `examples/train_ppo.py` builds it
  (`train_ppo.make_brax_env`, its networks and `ppo.train` arguments),
  through `mjx_composer.adapters.brax`: the walk task as shipped (policy
  noise, latency and history, per-episode randomization, pushes, falls end
  episodes), the policy and critic both seeing the 'policy' group;
* ours_off: the walk task with those additions off
  (`walk.PLAYGROUND_EQUIVALENT`, the 'policy' group only: HumanoidWalk's
  observation, reward and episodes), otherwise as `ours`;
* only_<feature>[+<feature>...]: ours_off with those of ours' additions
  switched back on, named as in `playground_compare.py` (noise, delay,
  history, randomize, push, fall; e.g. only_noise+delay+history+randomize:
  the shipped task without pushes and fall terminations, so its episodes,
  and returns, are HumanoidWalk's), otherwise as `ours_off`; with the
  suffix `_shared` (as in `playground_compare.py`), with
  `share_reset_forward=True` whatever `--share-reset-forward` says.

Hyper-parameters: `mujoco_playground.config.dm_control_suite_params.
brax_ppo_config('HumanoidWalk')` read at run time when Playground imports
(otherwise `train_ppo.TASK_DEFAULTS['walk']`, a copy of it, plus
`FALLBACK_EXTRA`), the same for every environment. The flags below override
single entries (for smoke runs). Evaluation follows Playground's script:
`--eval-envs` 128, stochastic policy (`--deterministic-eval` to change).
Brax runs `(num_evals - 1) x max(num_resets_per_eval, 1) x
ceil(num_timesteps / ((num_evals - 1) x max(num_resets_per_eval, 1) x
batch_size x unroll_length x num_minibatches))` training steps of
`batch_size x unroll_length x num_minibatches` env steps each; with
Playground's config that is 90 x 983,040 = 88.5 M env steps (not 60 M),
resetting every world after each training step. `--num-evals 31
--num-resets-per-eval 3` keeps that schedule with three times as many
evaluations. The script prints the env steps Brax will run.

Playground's training script also sets `XLA_PYTHON_CLIENT_PREALLOCATE=false`
and adds `--xla_gpu_triton_gemm_any=True` to `XLA_FLAGS`; this script does
the same for every environment (`--no-playground-xla-flags` to not).
JAX's persistent compilation cache is off (cold-start times) unless
`--compilation-cache`.

Outputs, in `--out` (runs of several invocations merge there; a run of an
(env, seed) already there is replaced):

* `runs/<env>_seed<seed>.json` and `.csv`: one run, rewritten (JSON) or
  appended to (CSV) after every evaluation, so a run cut off keeps its
  evaluations; its `status` is running, finished, stopped (by
  `--max-wall-s`) or failed;
* `results.json` and `results.csv`: every run of `runs/`, regenerated after
  every evaluation;
* `runs/<env>_seed<seed>_policy.pkl`: the policy of the latest evaluation
  (for ours, `examples/train_ppo.py --task walk --render-from` renders
  it).

`--gpus 0,1,...` runs each (env, seed) in its own process pinned to one GPU
(`CUDA_VISIBLE_DEVICES`), as many at a time as GPUs are listed, with logs in
`logs/`, then prints the table. With `--devices 2 --gpus 0+1,2+3` each run
trains on two GPUs (Brax's `pmap`, the world batch split between them),
two runs at a time.

`--max-wall-s` stops a run after the evaluation from which the next one
would end past that many seconds (for a job's time limit); its status is
then 'stopped' (a run whose last evaluation is done is 'finished', whatever
the time). `--resume` continues each (env, seed) whose run in `--out` was
stopped for the evaluations it has left, in a new process (a segment):

* the policy, value and observation-normalizer parameters carry over
  (Brax's `ppo.train(restore_params=..., restore_value_fn=True)`), from
  `runs/<env>_seed<seed>_policy.pkl`;
* so does the schedule: the next segment trains the evaluation intervals
  left, each of the same training steps, so the evaluations fall on the
  same env steps as in one run (`remaining_schedule`);
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
`resume_compile_s`), and the table and plot time a run as if it had trained
in one process (`train_results.one_process_wall`). The run's
`segment_starts` keep that evaluation's return beside the one the policy
earned when it was saved (equal but for the evaluation's own randomness,
when the restore took).

`--plot` trains nothing: it reads `runs/` and draws `returns.png` (return
against wall-clock time: a colour per environment, a thin line per seed,
their mean in bold), prints a table and writes it to `table.md` and
`summary.json`: per environment, the final return (mean ± std over seeds),
each seed's wall-clock time to the reference return (the first evaluation
at or above it) and its total time. The reference return is the mean over
seeds of `--reference`'s (default playground) final returns, or
`--threshold`.

Dependencies: `pip install -e '.[brax]'` and `pip install playground`
(the runs in `benchmarks/results/` used Brax 0.14.2 and Playground 0.2.0).
Playground's full schedule takes about 20 minutes per run on one
data-centre GPU (`docs/performance.md`).

A CPU smoke run (a few minutes for two environments):

    python benchmarks/train_compare.py --out /tmp/cmp --seeds 0 \\
        --num-timesteps 2000 --num-envs 8 --batch-size 8 \\
        --num-minibatches 2 --unroll-length 5 --num-evals 2 --eval-envs 4 \\
        --num-resets-per-eval 1 --episode-length 50
"""

import argparse
import json
import math
import os
import pickle
import subprocess
import sys
import time
import traceback

# examples/train_ppo.py builds ours' environments and PPO arguments.
sys.path.insert(
    0,
    os.path.join(
        os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'examples'
    ),
)
import train_ppo  # pylint: disable=g-import-not-at-top,wrong-import-position
import train_results  # pylint: disable=g-import-not-at-top,wrong-import-position

ENVS = ('playground', 'ours', 'ours_off')
PLAYGROUND_ENV = 'HumanoidWalk'
# Playground 0.2.0's HumanoidWalk PPO config entries that
# `train_ppo.TASK_DEFAULTS['walk']` has no flag for.
FALLBACK_EXTRA = {
    'episode_length': 1000,
    'action_repeat': 1,
    'num_resets_per_eval': 10,
}
# walk.Walk's default control timestep, Playground's ctrl_dt (seconds).
_WALK_CONTROL_TIMESTEP = 0.025
# train_ppo's flag -> ppo.train's argument, for the entries both have.
_TRAIN_PPO_NAMES = {
    'num_timesteps': 'num_timesteps',
    'num_evals': 'num_evals',
    'reward_scaling': 'reward_scaling',
    'normalize': 'normalize_observations',
    'unroll_length': 'unroll_length',
    'num_minibatches': 'num_minibatches',
    'num_updates_per_batch': 'num_updates_per_batch',
    'discounting': 'discounting',
    'learning_rate': 'learning_rate',
    'entropy_cost': 'entropy_cost',
    'num_envs': 'num_envs',
    'batch_size': 'batch_size',
}
# Command-line overrides of single hyper-parameters (flag dest = ppo name).
_OVERRIDES = (
    'num_timesteps',
    'num_evals',
    'num_resets_per_eval',
    'num_envs',
    'batch_size',
    'num_minibatches',
    'unroll_length',
    'num_updates_per_batch',
    'episode_length',
)


def env_choice(name):
  """`--envs`' type: one of `ENVS`, or an only_<feature>[+...] variant."""
  import playground_compare  # pylint: disable=g-import-not-at-top

  if name in ENVS:
    return name
  if name.startswith('only_'):
    return playground_compare.program_name(name)
  raise argparse.ArgumentTypeError(
      f'unknown env {name!r}: {", ".join(ENVS)} or only_<feature>[+...]'
  )


def parse_args(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
  parser.add_argument('--out', default='runs/train_compare')
  parser.add_argument(
      '--envs',
      nargs='+',
      type=env_choice,
      default=['playground', 'ours'],
      help=f'{", ".join(ENVS)} or only_<feature>[+<feature>...]',
  )
  parser.add_argument('--seeds', nargs='+', type=int, default=[0, 1, 2])
  for name in _OVERRIDES:
    parser.add_argument(
        '--' + name.replace('_', '-'),
        type=int,
        default=None,
        help="override Playground's value",
    )
  parser.add_argument(
      '--eval-envs',
      type=int,
      default=128,
      help="evaluation episodes (Playground's script: 128)",
  )
  parser.add_argument(
      '--deterministic-eval',
      action='store_true',
      help="evaluate the policy's mean action (Playground: sampled)",
  )
  parser.add_argument(
      '--playground-impl',
      choices=('jax', 'warp'),
      default='jax',
      help="Playground's MJX implementation",
  )
  parser.add_argument(
      '--devices',
      type=int,
      default=1,
      help="local devices each run trains on (Brax's max_devices_per_host)",
  )
  parser.add_argument(
      '--share-reset-forward',
      action=argparse.BooleanOptionalAction,
      default=None,
      help='ours: ExecutionOptions(share_reset_forward=...); default: on a CPU only',
  )
  parser.add_argument(
      '--auto-reset-batch',
      type=int,
      default=None,
      metavar='K',
      help='ours: ExecutionOptions(auto_reset_batch=K) (worlds that end reset K '
      "at a time; impl='jax' only); default: the whole batch",
  )
  parser.add_argument(
      '--max-wall-s',
      type=float,
      default=None,
      help='stop a run after the evaluation from which the next one would '
      'end later than this many seconds after the start of ppo.train',
  )
  parser.add_argument(
      '--compilation-cache',
      action='store_true',
      help="use JAX's persistent compilation cache (default: off, cold starts)",
  )
  parser.add_argument(
      '--no-playground-xla-flags',
      action='store_true',
      help="don't set the XLA flags Playground's training script sets",
  )
  parser.add_argument(
      '--gpus',
      default=None,
      help='comma-separated GPU indices, or groups of --devices indices '
      'joined by + (0+1,2+3): one process per (env, seed), each on one '
      'entry, as many at a time as entries',
  )
  parser.add_argument(
      '--resume',
      action='store_true',
      help="continue each (env, seed)'s run stopped earlier in --out (by "
      '--max-wall-s) from its saved parameters, for the evaluations left '
      '(not the optimizer state: see the module docstring)',
  )
  parser.add_argument(
      '--plot', action='store_true', help='only plot and tabulate --out'
  )
  parser.add_argument(
      '--reference',
      default='playground',
      help='the environment whose mean final return is the threshold',
  )
  parser.add_argument(
      '--threshold',
      type=float,
      default=None,
      help='the return to time (default: from --reference)',
  )
  return parser.parse_args(argv)


# -- hyper-parameters ----------------------------------------------------------


def playground_config():
  """(Playground's HumanoidWalk PPO config as a dict, version) or (None, why)."""
  try:
    # pylint: disable=g-import-not-at-top
    import importlib.metadata
    from mujoco_playground.config import dm_control_suite_params
    # pylint: enable=g-import-not-at-top
  except Exception as e:  # pylint: disable=broad-except
    return None, f'mujoco_playground cannot be imported: {e!r}'
  config = dm_control_suite_params.brax_ppo_config(PLAYGROUND_ENV).to_dict()
  try:
    version = importlib.metadata.version('playground')
  except importlib.metadata.PackageNotFoundError:
    version = 'unknown'
  return config, f'playground {version}'


def fallback_config():
  """Playground's config as `train_ppo.TASK_DEFAULTS['walk']` copies it."""
  walk = train_ppo.TASK_DEFAULTS['walk']
  config = {ppo: walk[flag] for flag, ppo in _TRAIN_PPO_NAMES.items()}
  config.update(FALLBACK_EXTRA)
  return config


def hyperparameters(args):
  """`(config, source)`: the `ppo.train` hyper-parameters every run uses.

  Playground's config (or the fallback), less its network factory (Brax's
  defaults, as for HumanoidWalk), with the command line's overrides.
  """
  config, source = playground_config()
  if config is None:
    print(f'Hyper-parameters: train_ppo.TASK_DEFAULTS["walk"] ({source})')
    config, source = fallback_config(), 'train_ppo.TASK_DEFAULTS["walk"]'
  else:
    config.pop('network_factory', None)
    copy = fallback_config()
    differ = {
        k: (config.get(k), v) for k, v in copy.items() if config.get(k) != v
    }
    if differ:
      print(
          'Warning: train_ppo.TASK_DEFAULTS["walk"] differs from '
          f'{source} (playground, copy): {differ}'
      )
  for name in _OVERRIDES:
    value = getattr(args, name)
    if value is not None:
      config[name] = value
  return config, source


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
  """The env steps `ppo.train` runs for `config` (see the module docstring)."""
  return max(config['num_evals'] - 1, 1) * interval_steps(config)


# -- environments ----------------------------------------------------------------


def _playground_setup(config, args):
  """(env, ppo.train kwargs, policy config) for Playground's HumanoidWalk."""
  # pylint: disable=g-import-not-at-top
  from brax.training.agents.ppo import networks as ppo_networks
  from mujoco_playground import registry
  from mujoco_playground import wrapper
  from mjx_composer.adapters import brax as brax_adapter
  # pylint: enable=g-import-not-at-top

  brax_adapter.install_jax_compat()  # Brax 0.14 on JAX >= 0.10.
  overrides = {'impl': args.playground_impl}
  env = registry.load(
      PLAYGROUND_ENV,
      config=registry.get_default_config(PLAYGROUND_ENV),
      config_overrides=overrides,
  )
  eval_env = registry.load(
      PLAYGROUND_ENV,
      config=registry.get_default_config(PLAYGROUND_ENV),
      config_overrides=overrides,
  )
  kwargs = dict(config)
  kwargs.update(
      network_factory=ppo_networks.make_ppo_networks,
      wrap_env_fn=wrapper.wrap_for_brax_training,
      eval_env=eval_env,
  )
  policy = {
      'env': 'playground',
      'observation_size': env.observation_size,
      'action_size': env.action_size,
      'normalize': config['normalize_observations'],
      'network_factory': 'brax ppo_networks.make_ppo_networks defaults',
  }
  return env, kwargs, policy


def _ours_setup(name, config, args):
  """(env, ppo.train kwargs, policy config) for ours and its variants.

  `train_ppo`'s walk arguments with Playground's values, built by
  `train_ppo.make_brax_env` (ours) and trained with `train_ppo.ppo_kwargs`.
  """
  # pylint: disable=g-import-not-at-top
  from mjx_composer.adapters import brax as brax_adapter
  import playground_compare
  # pylint: enable=g-import-not-at-top

  targs = train_ppo.parse_args(['--task', 'walk'])
  for flag, ppo in _TRAIN_PPO_NAMES.items():
    setattr(targs, flag, config[ppo])
  targs.time_limit = config['episode_length'] * _WALK_CONTROL_TIMESTEP
  targs.share_reset_forward = args.share_reset_forward
  targs.auto_reset_batch = args.auto_reset_batch
  targs.num_eval_envs = args.eval_envs
  if name.startswith('only_'):
    env = playground_compare.env_variants(
        [name], share_reset_forward=args.share_reset_forward
    )[name]
    brax_env = brax_adapter.BraxEnv(env)
  else:
    # ours_off: `train_ppo.py --task walk --like-playground`, which also
    # renders its policies (`--render-from`).
    targs.like_playground = name == 'ours_off'
    env, brax_env = train_ppo.make_brax_env(targs)
  if brax_env.episode_length != config['episode_length']:
    raise ValueError(
        f'{name}: episodes of {brax_env.episode_length} steps, Playground '
        f'{config["episode_length"]}.'
    )
  kwargs = train_ppo.ppo_kwargs(targs, brax_env, args.devices)
  # What train_ppo has no flag for, as Playground trains.
  for key in ('num_resets_per_eval', 'action_repeat'):
    kwargs[key] = config[key]
  different = {
      k: (kwargs[k], v)
      for k, v in config.items()
      if k in kwargs and kwargs[k] != v
  }
  if different:
    raise AssertionError(f'{name} would train with other values: {different}')
  policy = train_ppo.policy_config(targs, brax_env)
  return brax_env, kwargs, policy


def _device_name():
  """This process's first device, as 'platform: kind'."""
  import jax  # pylint: disable=g-import-not-at-top

  device = jax.devices()[0]
  return f'{device.platform}: {device.device_kind}'


def _new_run(env_name, seed, config, source, args):
  """A fresh run record (no evaluations yet)."""
  import jax  # pylint: disable=g-import-not-at-top

  return {
      'env': env_name,
      'seed': seed,
      'status': 'building',
      'device': _device_name(),
      'devices': args.devices,
      'jax': jax.__version__,
      'hyperparameters': config,
      'hyperparameters_from': source,
      'env_steps_planned': brax_env_steps(config),
      'eval_envs': args.eval_envs,
      'deterministic_eval': args.deterministic_eval,
      'playground_impl': args.playground_impl
      if env_name == 'playground'
      else None,
      'auto_reset_batch': args.auto_reset_batch if env_name == 'ours' else None,
      'xla_flags': os.environ.get('XLA_FLAGS', ''),
      'started_at': time.strftime('%Y-%m-%d %H:%M:%S'),
      'total_s': None,
      'segments': 1,
      'rows': [],
  }


# -- resuming a stopped run -------------------------------------------------------

# Brax seeds of later segments: far from any seed a user passes.
_SEGMENT_SEED_STRIDE = 1_000_003


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


def load_stopped_run(json_path, policy_path):
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


def _segment_to_train(run, config, name):
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


def _check_something_to_resume(args):
  """Refuses `--resume` where `--out` holds none of the requested runs.

  A run without a record starts from its first step, so `--resume` over
  an empty `--out` (say, a job on a fresh machine that did not bring the
  previous job's runs) would quietly train every run's first segment
  again.

  Raises:
    SystemExit: no requested (env, seed) has a record in `--out/runs/`.
  """
  wanted = [
      os.path.join(
          args.out, 'runs', train_results.run_name(env, seed) + '.json'
      )
      for seed in args.seeds
      for env in args.envs
  ]
  if not any(os.path.exists(path) for path in wanted):
    sys.exit(
        f'--resume: {os.path.join(args.out, "runs")} holds no record of '
        f'{", ".join(args.envs)} with seeds {args.seeds}. Bring the earlier '
        "call's runs (records and *_policy.pkl) into --out (on a device, "
        'with carry), or leave out --resume to start these runs.'
    )


def train_one(env_name, seed, config, source, args):
  """Trains one (environment, seed); returns its run record.

  With `--resume` and a stopped run of it in `--out`, trains what is left
  of that run instead (`--resume` in the module docstring).
  """
  # pylint: disable=g-import-not-at-top
  import jax
  from brax.training.agents.ppo import train as ppo

  from mjx_composer.platform import partitioner
  # pylint: enable=g-import-not-at-top

  run_dir = os.path.join(args.out, 'runs')
  os.makedirs(run_dir, exist_ok=True)
  name = train_results.run_name(env_name, seed)
  json_path = os.path.join(run_dir, name + '.json')
  csv_path = os.path.join(run_dir, name + '.csv')
  policy_path = os.path.join(run_dir, name + '_policy.pkl')
  resumed = load_stopped_run(json_path, policy_path) if args.resume else None
  restore = None
  if resumed is None:
    for path in (json_path, csv_path, policy_path):
      if os.path.exists(path):
        os.remove(path)
    run = _new_run(env_name, seed, config, source, args)
    segment, train_config = 0, config
  else:
    run, restore = resumed
    run.pop('error', None)
    todo = _segment_to_train(run, config, name)
    if todo is None:
      print(f'{name}: finished earlier, nothing to resume', flush=True)
      return run
    segment, train_config = todo
  earlier_rows = list(run['rows'])
  earlier_s = run['total_s'] or 0.0
  t0 = time.perf_counter()
  if env_name == 'playground':
    env, kwargs, policy_config = _playground_setup(train_config, args)
  else:
    env, kwargs, policy_config = _ours_setup(env_name, train_config, args)
  run['build_s'] = time.perf_counter() - t0
  kwargs.update(
      seed=segment_seed(seed, segment),
      num_eval_envs=args.eval_envs,
      deterministic_eval=args.deterministic_eval,
      max_devices_per_host=args.devices,
  )
  if restore is not None:
    kwargs.update(restore_params=restore, restore_value_fn=True)
  run['status'] = 'running'
  run['segments'] = segment + 1
  train_results.write_json(json_path, run)
  print(
      f'{name}: training {run["env_steps_planned"]:,} env steps on '
      f'{run["device"]} (segment {segment}: '
      f'{brax_env_steps(train_config):,} of them; built in '
      f'{run["build_s"]:.1f}s)',
      flush=True,
  )
  rows = run['rows']
  segment_rows = []  # This segment's, with its own steps and clock.
  start = None

  def save_params(unused_step, unused_make_policy, params):
    train_ppo.save_policy(policy_path, params, policy_config)

  def progress(step, metrics):
    row = train_ppo.eval_row(
        step,
        metrics,
        time.perf_counter() - start,
        clock.seconds,
        previous=segment_rows[-1] if segment_rows else None,
    )
    segment_rows.append(row)
    if earlier_rows:
      if len(segment_rows) == 1:
        # The restored policy's evaluation: kept aside (the run's rows end
        # with this policy's), as a check that the restore took.
        run.setdefault('segment_starts', []).append(
            {
                'segment': segment,
                # A later segment may run on another kind of GPU.
                'device': _device_name(),
                'overhead_s': row['wall_s'],
                'restored_eval_return': row['eval_return'],
                'last_eval_return': earlier_rows[-1]['eval_return'],
            }
        )
        train_results.write_json(json_path, run)
        return
      row = continued_row(
          row,
          earlier_rows,
          segment,
          segment_rows[0]['wall_s'],
          segment_rows[0]['compile_s'],
      )
    else:
      # Every row has the same columns (the run's CSV has one header).
      row.update(segment=0, resume_overhead_s=0.0, resume_compile_s=0.0)
    rows.append(row)
    train_ppo.append_csv(csv_path, row, header=len(rows) == 1)
    train_results.write_json(json_path, run)
    train_results.write_merged(args.out)
    print(
        f'{name}: step {row["step"]:>11,} {row["wall_s"]:8.1f}s  return '
        f'{row["eval_return"]:8.2f} ± {row["eval_return_std"]:6.2f}  '
        f'({row["env_steps_per_s"]:,.0f} env steps/s)',
        flush=True,
    )
    if train_ppo.next_eval_too_late(
        segment_rows, args.max_wall_s, brax_env_steps(train_config)
    ):
      raise train_ppo.StopTraining

  start = time.perf_counter()
  clock = train_ppo.CompileClock()
  try:
    # As train_ppo.py: GSPMD where Brax pmaps over several GPUs.
    with partitioner.scope(
        jax.local_devices()[: kwargs['max_devices_per_host']]
    ):
      ppo.train(
          environment=env,
          progress_fn=progress,
          policy_params_fn=save_params,
          **kwargs,
      )
    run['status'] = 'finished'
  except train_ppo.StopTraining:
    run['status'] = 'stopped'
  except Exception:  # pylint: disable=broad-except
    run['status'] = 'failed'
    run['error'] = traceback.format_exc()
    print(run['error'], file=sys.stderr)
  run['total_s'] = earlier_s + time.perf_counter() - start
  train_results.write_json(json_path, run)
  train_results.write_merged(args.out)
  print(f'{name}: {run["status"]} after {run["total_s"]:.1f}s', flush=True)
  return run


# -- several GPUs ------------------------------------------------------------------


def _child_argv(argv, env, seed):
  """`argv` without `--gpus`, for one (env, seed)."""
  out, skip = [], False
  for token in argv:
    if skip:
      skip = False
      continue
    if token == '--gpus':
      skip = True
      continue
    if token.startswith('--gpus='):
      continue
    out.append(token)
  return out + ['--envs', env, '--seeds', str(seed)]


def gpu_groups(spec, devices):
  """`--gpus`'s entries as `CUDA_VISIBLE_DEVICES` values, one per process.

  Args:
    spec: comma-separated entries, each a GPU index or `devices` indices
      joined by '+' ('0+1,2+3' with `devices=2`).
    devices: `--devices`, the GPUs each run trains on.

  Raises:
    ValueError: an entry does not name `devices` distinct indices, or two
      entries share one.
  """
  groups, seen = [], set()
  for entry in (e.strip() for e in spec.split(',')):
    if not entry:
      continue
    ids = entry.split('+')
    if not all(i.isdigit() for i in ids) or len(set(ids)) != len(ids):
      raise ValueError(f'--gpus entry {entry!r}: distinct GPU indices only.')
    if len(ids) != devices:
      raise ValueError(
          f'--gpus entry {entry!r} names {len(ids)} GPU(s) but --devices is '
          f'{devices}: join {devices} indices with + per run (0+1,2+3), or '
          'pass --devices to match.'
      )
    if seen & set(ids):
      raise ValueError(f'--gpus: GPU(s) {sorted(seen & set(ids))} in two runs.')
    seen |= set(ids)
    groups.append(','.join(ids))
  if not groups:
    raise ValueError('--gpus names no GPU.')
  return groups


def run_parallel(args, argv):
  """Runs each (env, seed) in its own process, one per entry of `--gpus`."""
  gpus = gpu_groups(args.gpus, args.devices)
  jobs = [(e, s) for s in args.seeds for e in args.envs]
  log_dir = os.path.join(args.out, 'logs')
  os.makedirs(log_dir, exist_ok=True)
  running = {}  # gpu -> (Popen, name, log file)
  failed = []
  script = os.path.abspath(__file__)
  while jobs or running:
    for gpu in gpus:
      if gpu not in running and jobs:
        env, seed = jobs.pop(0)
        name = train_results.run_name(env, seed)
        log = open(os.path.join(log_dir, name + '.log'), 'w')
        child_env = dict(os.environ, CUDA_VISIBLE_DEVICES=gpu)
        proc = subprocess.Popen(
            [sys.executable, script] + _child_argv(argv, env, seed),
            stdout=log,
            stderr=subprocess.STDOUT,
            env=child_env,
        )
        running[gpu] = (proc, name, log)
        print(f'{name}: started on GPU {gpu} (pid {proc.pid})', flush=True)
    time.sleep(1.0)
    for gpu, (proc, name, log) in list(running.items()):
      if proc.poll() is not None:
        log.close()
        del running[gpu]
        print(f'{name}: exit status {proc.returncode}', flush=True)
        if proc.returncode:
          failed.append(name)
  return failed


def report(args):
  """The `--plot` mode: plot, table, summary.json, table.md."""
  runs = train_results.load_runs(args.out)
  if not runs:
    print(f'No runs in {args.out}.')
    return 1
  summary = train_results.summarize(runs, args.reference, args.threshold)
  table = train_results.format_table(summary)
  plotted = train_results.plot(
      args.out, runs, summary, f'Brax PPO, {PLAYGROUND_ENV} hyper-parameters'
  )
  train_results.write_json(os.path.join(args.out, 'summary.json'), summary)
  with open(os.path.join(args.out, 'table.md'), 'w') as f:
    f.write(table + '\n')
  threshold = summary['threshold']
  print(
      'Reference return: '
      + ('none' if threshold is None else f'{threshold:.2f}')
      + f' ({summary["threshold_from"]}); time is wall-clock since the start '
      'of ppo.train, compilation and evaluations included (for a run '
      'trained in segments, without what the later segments spent resuming: '
      'see the note under the table).'
  )
  print(table)
  if plotted:
    print(f'Wrote {os.path.join(args.out, "returns.png")}')
  return 0


# -- main --------------------------------------------------------------------------


def main(argv=None):
  argv = sys.argv[1:] if argv is None else list(argv)
  args = parse_args(argv)
  if args.plot:
    return report(args)
  if args.resume:
    _check_something_to_resume(args)
  os.makedirs(args.out, exist_ok=True)
  if args.gpus:
    failed = run_parallel(args, argv)
    report(args)
    return 1 if failed else 0
  if not args.no_playground_xla_flags:
    # As Playground's training script, before JAX starts its backend.
    os.environ['XLA_PYTHON_CLIENT_PREALLOCATE'] = 'false'
    flags = os.environ.get('XLA_FLAGS', '')
    if '--xla_gpu_triton_gemm_any' not in flags:
      os.environ['XLA_FLAGS'] = (
          flags + ' --xla_gpu_triton_gemm_any=True'
      ).strip()
  # pylint: disable=g-import-not-at-top
  from mjx_composer import platform
  # pylint: enable=g-import-not-at-top
  cache = platform.configure(compilation_cache=args.compilation_cache)
  config, source = hyperparameters(args)
  print(f'Hyper-parameters ({source}): {config}')
  print(
      f'Brax will run {brax_env_steps(config):,} env steps per run; '
      f'compilation cache: {cache or "off"}.',
      flush=True,
  )
  status = 0
  for seed in args.seeds:
    for env in args.envs:
      run = train_one(env, seed, config, source, args)
      status |= run['status'] == 'failed'
  report(args)
  return int(status)


if __name__ == '__main__':
  sys.exit(main())
