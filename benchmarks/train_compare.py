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

Environments (`--envs`; `train_setups.py` says how each is built and
trained): playground (Playground's `HumanoidWalk`, trained as Playground's
`learning/train_jax_ppo.py` trains it), ours (our walk task as shipped,
trained as `mjx-composer train walk` trains it), ours_off (ours with its
additions off: HumanoidWalk's observation, reward and episodes) and
only_<feature>[+<feature>...] (ours_off with some of ours' additions back
on, named as in `playground_compare.py`).

Hyper-parameters: Playground's for `HumanoidWalk`, read at run time
(`train_setups.hyperparameters`), the same for every environment; the
flags below override single entries (for smoke runs). Evaluation follows
Playground's script: `--eval-envs` 128, stochastic policy
(`--deterministic-eval` to change).
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
* `runs/<env>_seed<seed>_policy.pkl`: the parameters of the latest
  evaluation, `{'params': (normalizer, policy, value), 'config': what
  rebuilds the networks}` (numpy leaves; `--resume` starts from them,
  `--render` draws them).

`--gpus 0,1,...` runs each (env, seed) in its own process pinned to one GPU
(`CUDA_VISIBLE_DEVICES`), as many at a time as GPUs are listed, with logs in
`logs/`, then prints the table. With `--devices 2 --gpus 0+1,2+3` each run
trains on two GPUs (Brax's `pmap`, the world batch split between them),
two runs at a time.

`--max-wall-s` stops a run after the evaluation from which the next one
would end past that many seconds (for a job's time limit); its status is
then 'stopped' (a run whose last evaluation is done is 'finished', whatever
the time). `--resume` continues each (env, seed) whose run in `--out` was
stopped for the evaluations it has left, in a new process (a segment),
from its saved parameters; what carries over and what does not, and how
its time is counted, is in `train_segments.py`.

`--render` trains nothing: it runs each (env, seed)'s saved policy,
deterministic, for 200 control steps on 4 worlds of its environment (a
Playground run's on ours_off, whose 'policy' observation is HumanoidWalk's)
and writes `runs/<env>_seed<seed>_rollout.mp4` and the mean reward per
step (needs a headless OpenGL). For a look at the policies; runs of
`mjx-composer train` have `mjx-composer play`.

`--plot` trains nothing: it reads `runs/` and draws `returns.png` (return
against wall-clock time: a colour per environment, a thin line per seed,
their mean in bold), prints a table and writes it to `table.md` and
`summary.json`: per environment, the final return (mean ± std over seeds),
each seed's wall-clock time to the reference return (the first evaluation
at or above it) and its total time. The reference return is the mean over
seeds of `--reference`'s (default playground) final returns, or
`--threshold`.

Dependencies: `pip install -e '.[brax]'` (`'.[train]'` for `--render`'s
MP4) and `pip install playground` (the runs in `benchmarks/results/` used
Brax 0.14.2 and Playground 0.2.0).
Playground's full schedule takes about 20 minutes per run on one
data-centre GPU (`docs/performance.md`).

A CPU smoke run (compiling dominates: ours_off took 14 minutes on a 2-core
CPU shared with other jobs, Playground's not measured):

    python benchmarks/train_compare.py --out runs/cmp_smoke --seeds 0 \\
        --num-timesteps 2000 --num-envs 8 --batch-size 8 \\
        --num-minibatches 2 --unroll-length 5 --num-evals 2 --eval-envs 4 \\
        --num-resets-per-eval 1 --episode-length 50
"""

import argparse
import json
import os
import pickle
import subprocess
import sys
import time
import traceback

import train_results
import train_segments
import train_setups

# `--render`'s rollout.
_RENDER_WORLDS = 4
_RENDER_STEPS = 200


def env_choice(name):
  """`--envs`' type: one of `train_setups.ENVS`, or an only_... variant."""
  import playground_compare  # pylint: disable=g-import-not-at-top

  if name in train_setups.ENVS:
    return name
  if name.startswith('only_'):
    return playground_compare.program_name(name)
  raise argparse.ArgumentTypeError(
      f'unknown env {name!r}: {", ".join(train_setups.ENVS)} or '
      'only_<feature>[+...]'
  )


def parse_args(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
  parser.add_argument('--out', default='runs/train_compare')
  parser.add_argument(
      '--envs',
      nargs='+',
      type=env_choice,
      default=['playground', 'ours'],
      help=f'{", ".join(train_setups.ENVS)} or only_<feature>[+<feature>...]',
  )
  parser.add_argument('--seeds', nargs='+', type=int, default=[0, 1, 2])
  for name in train_setups.OVERRIDES:
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
      help='ours: ExecutionOptions(share_reset_forward=...); default: on a '
      'CPU only',
  )
  parser.add_argument(
      '--auto-reset-batch',
      type=int,
      default=None,
      metavar='K',
      help='ours: ExecutionOptions(auto_reset_batch=K) (worlds that end '
      "reset K at a time; impl='jax' only); default: the Environment's "
      "('auto')",
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
      '(not the optimizer state: see train_segments.py)',
  )
  parser.add_argument(
      '--render',
      action='store_true',
      help="only render each (env, seed)'s saved policy in --out",
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
      'env_steps_planned': train_segments.brax_env_steps(config),
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


def train_one(env_name, seed, config, source, args):
  """Trains one (environment, seed); returns its run record.

  With `--resume` and a stopped run of it in `--out`, trains what is left
  of that run instead (`train_segments.py`).
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
  resumed = (
      train_segments.load_stopped_run(json_path, policy_path)
      if args.resume
      else None
  )
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
    todo = train_segments.segment_to_train(run, config, name)
    if todo is None:
      print(f'{name}: finished earlier, nothing to resume', flush=True)
      return run
    segment, train_config = todo
  earlier_rows = list(run['rows'])
  earlier_s = run['total_s'] or 0.0
  t0 = time.perf_counter()
  env, kwargs, policy_config = train_setups.setup(env_name, train_config, args)
  run['build_s'] = time.perf_counter() - t0
  kwargs.update(
      seed=train_segments.segment_seed(seed, segment),
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
      f'{train_segments.brax_env_steps(train_config):,} of them; built in '
      f'{run["build_s"]:.1f}s)',
      flush=True,
  )
  rows = run['rows']
  segment_rows = []  # This segment's, with its own steps and clock.
  start = None

  def save_params(unused_step, unused_make_policy, params):
    train_segments.save_params(policy_path, params, policy_config)

  def progress(step, metrics):
    row = train_results.eval_row(
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
      row = train_results.continued_row(
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
    train_results.append_csv(csv_path, row)
    train_results.write_json(json_path, run)
    train_results.write_merged(args.out)
    print(
        f'{name}: step {row["step"]:>11,} {row["wall_s"]:8.1f}s  return '
        f'{row["eval_return"]:8.2f} ± {row["eval_return_std"]:6.2f}  '
        f'({row["env_steps_per_s"]:,.0f} env steps/s)',
        flush=True,
    )
    if train_segments.next_eval_too_late(
        segment_rows,
        args.max_wall_s,
        train_segments.brax_env_steps(train_config),
    ):
      raise train_segments.StopTraining

  start = time.perf_counter()
  clock = train_segments.CompileClock()
  try:
    # GSPMD where Brax pmaps over several GPUs (as `mjx-composer train`).
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
  except train_segments.StopTraining:
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


# -- several GPUs --------------------------------------------------------------


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


# -- rendering and reporting ---------------------------------------------------


def render(args, worlds=_RENDER_WORLDS, steps=_RENDER_STEPS):
  """The `--render` mode: each (env, seed)'s saved policy as an MP4.

  Returns:
    1 if a requested run has no saved policy, else 0.
  """
  # pylint: disable=g-import-not-at-top
  from mjx_composer.adapters import brax as brax_adapter
  from mjx_composer.training import video
  # pylint: enable=g-import-not-at-top

  missing = 0
  for seed in args.seeds:
    for env_name in args.envs:
      name = train_results.run_name(env_name, seed)
      path = os.path.join(args.out, 'runs', name + '_policy.pkl')
      if not os.path.exists(path):
        print(f'{name}: no saved policy ({path}); train it first.')
        missing = 1
        continue
      with open(path, 'rb') as f:
        saved = pickle.load(f)
      with open(os.path.join(args.out, 'runs', name + '.json')) as f:
        time_limit = train_setups.ours_config(
            json.load(f)['hyperparameters']
        ).time_limit
      ours = 'ours_off' if env_name == 'playground' else env_name
      env = train_setups.ours_environment(ours, time_limit, args)
      states, rewards, *_ = video.rollout(
          brax_adapter.BraxEnv(env),
          train_setups.saved_policy(saved['config']),
          saved['params'],
          worlds,
          steps,
          seed=1,
      )
      mp4 = video.write_mp4(
          os.path.join(args.out, 'runs', name + '_rollout.mp4'),
          video.render_rollout(env, 'walk', states),
          fps=1.0 / env.control_timestep(),
      )
      print(
          f'{name}: {mp4}; mean reward per step {rewards.mean():.4f} '
          f'({worlds} worlds x {steps} steps on {ours})'
      )
  return missing


def report(args):
  """The `--plot` mode: plot, table, summary.json, table.md."""
  runs = train_results.load_runs(args.out)
  if not runs:
    print(f'No runs in {args.out}.')
    return 1
  summary = train_results.summarize(runs, args.reference, args.threshold)
  table = train_results.format_table(summary)
  plotted = train_results.plot(
      args.out,
      runs,
      summary,
      f'Brax PPO, {train_setups.PLAYGROUND_ENV} hyper-parameters',
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


# -- main ----------------------------------------------------------------------


def main(argv=None):
  argv = sys.argv[1:] if argv is None else list(argv)
  args = parse_args(argv)
  if args.plot:
    return report(args)
  if args.resume:
    train_segments.check_something_to_resume(args.out, args.envs, args.seeds)
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
  if args.render:
    return render(args)
  config, source = train_setups.hyperparameters(args)
  print(f'Hyper-parameters ({source}): {config}')
  print(
      f'Brax will run {train_segments.brax_env_steps(config):,} env steps per '
      f'run; compilation cache: {cache or "off"}.',
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
