"""Scaling over devices: one device against all local devices.

For `--worlds` worlds (default 65,536), first on one device and then on all
N local devices, the world axis split over them with
`mjx_composer.platform.sharding` (each device steps its own worlds, with no
communication between devices), it times (`--scaling strong`, the default:
the same worlds on N devices; `weak`: N x the worlds on N devices, the same
worlds per device as the one device had; both: both):

* raw:      raw MJX on the reach model: per control step, `ctrl` set and
            `jax.vmap(mjx.step)` run n sub-steps in a `lax.fori_loop`
            (`common.raw_rollout`), `--steps` control steps per call, from
            `qpos0`;
* composed: the bundled reach task (per-episode domain randomization, its
            10 observables and policy/critic groups, episodes of
            `--time-limit` s with same-step auto-reset), `jax.lax.scan` over
            `jax.vmap(env.step)` (`common.env_rollout`), `--steps` per call;
* gspmd:    (N devices only, `--gspmd`) the composed rollout jitted with
            `jax.jit` and `NamedSharding` inputs and outputs instead, so XLA
            partitions one batched program: its loop predicates (MJX's
            solver, auto-reset) become all-reduces across the devices;
* ppo:      Brax's `ppo.train` on the same task (networks as
            `mjx-composer train reach`'s defaults: the policy group for
            policy and critic, 64x64 / 256x256 networks),
            `max_devices_per_host=1` against N: Brax `pmap`s the training
            over its devices, each with worlds / N worlds. One unroll of
            `--ppo-unroll` steps per world per training step, no
            evaluation; Brax's env steps per second of each epoch after the
            first (which compiles), median;
* train:    the training command, `mjx-composer train TASK` (`--train-task`,
            default joystick, with its registered settings), each run in its
            own process, `--devices 1` against `--devices N`: the task's
            `num_envs` worlds (weak scaling: N x its `num_envs` and
            `batch_size`), `--train-intervals` evaluations apart of
            `--train-updates` training steps each; the training env steps
            per second of `metrics.csv` between evaluations after the first
            (which compiles), median. It runs before the other parts, while
            this process holds no device memory.

On several GPUs the per-device programs and Brax's `pmap` compile with
GSPMD (`mjx_composer.platform.partitioner` says why).

It reports physics steps per second (raw, composed, gspmd: control steps x
n sub-steps; ppo: Brax's env steps x n sub-steps; train: env steps, which
are control steps), the median of
`--repeats` calls after two warm-up calls (compilation excluded), and the
scaling efficiency, N-device steps/s over N x 1-device steps/s (1.0: linear).
It also counts the collective operations (all-reduce, all-gather, ...) in
the compiled raw and composed programs. Results go to stdout and to `--out` as JSON.

With `--profile`, one more call of each raw and composed program runs under
`jax.profiler`, and each device's row of the trace gives where the devices'
time goes (`device_busy`): per device, the microseconds its kernels ran
(the union of their intervals over its streams), the kernels, and the span
from its first kernel's start to its last one's end; with the unprofiled
call's wall-clock time (`seconds_per_call`), `busy_fraction` = busy time
over wall-clock time. A device that idles between kernels more on N
devices than on one shows a lower fraction there; a device that is slower
per kernel shows more busy time for the same work.

    python benchmarks/scaling.py                     # 65,536 worlds
    python benchmarks/scaling.py --parts raw composed --worlds 32768
    python benchmarks/scaling.py --parts train --scaling strong weak
    python benchmarks/scaling.py --parts raw composed --no-gspmd \
        --scaling weak --profile           # where the devices' time goes

On CPU, forced host devices make a quick check of the script:

    XLA_FLAGS=--xla_force_host_platform_device_count=2 \\
        python benchmarks/scaling.py --worlds 8 --steps 2
"""

import argparse
import collections
import functools
import os
import statistics
import subprocess
import sys
import tempfile
import time

import jax

import common  # benchmarks/common.py
from mjx_composer import platform
from mjx_composer.platform import partitioner
from mjx_composer.platform import sharding

PARTS = ('raw', 'composed', 'ppo', 'train')
SCALINGS = ('strong', 'weak')
_COLLECTIVES = (
    'all-reduce',
    'all-gather',
    'all-to-all',
    'collective-permute',
    'reduce-scatter',
)


def collectives(compiled):
  """Counts of cross-device operations in a compiled program's HLO."""
  text = compiled.as_text()
  return {
      op: text.count(f' {op}(') + text.count(f' {op}-start(')
      for op in _COLLECTIVES
  }


def device_busy(events):
  """Each device's kernel time in a Perfetto trace's `events`.

  Returns `{device name: {'busy_us', 'kernels', 'span_us'}}` for every
  process row of the trace that is a device ('/device:GPU:0'): the
  microseconds in which at least one of its kernels ran (the union of their
  intervals over all its streams, so overlapping kernels count once), how
  many kernels ran, and the microseconds from the first kernel's start to
  the last one's end. Empty where the trace has no device rows (a CPU).
  """
  process = common.metadata_names(events, 'process_name')
  devices = {pid: name for pid, name in process.items() if '/device:' in name}
  intervals = collections.defaultdict(list)
  for e in events:
    if e.get('ph') == 'X' and e.get('pid') in devices:
      start = float(e.get('ts', 0))
      intervals[e['pid']].append((start, start + float(e.get('dur', 0))))
  busy = {}
  for pid, spans in intervals.items():
    spans.sort()
    total, end = 0.0, -float('inf')
    for start, stop in spans:
      if start > end:
        total += stop - start
      elif stop > end:
        total += stop - end
      end = max(end, stop)
    busy[devices[pid]] = {
        'busy_us': total,
        'kernels': len(spans),
        'span_us': end - spans[0][0],
    }
  return dict(sorted(busy.items()))


def profile_call(program, args, seconds):
  """`device_busy` of one call of `program(*args)` under `jax.profiler`,
  with each device's busy time over `seconds`, the unprofiled call's
  wall-clock time (`busy_fraction`)."""
  with tempfile.TemporaryDirectory() as trace_dir:
    with jax.profiler.trace(trace_dir, create_perfetto_trace=True):
      jax.block_until_ready(program(*args))
    busy = device_busy(common.perfetto_events(trace_dir))
  for row in busy.values():
    row['busy_fraction'] = row['busy_us'] / (seconds * 1e6)
  return {'seconds_per_call': seconds, 'devices': busy}


def _timed(program, args, repeats, profile):
  """`(seconds per call, profile or None)` of a rollout `program`."""
  seconds = common.time_fn(program, args, repeats)
  return seconds, profile_call(program, args, seconds) if profile else None


def time_raw(env, mesh, worlds, steps, repeats, profile=False):
  """Raw MJX physics steps/s on `mesh` (with `profile`, `profile_call`)."""
  n = env.n_sub_steps
  rollout = sharding.per_device(
      common.raw_rollout(env.mjx_model, n, steps, jit=False), mesh
  )
  data = sharding.put_worlds(common.raw_data(env.mjx_model, worlds), mesh)
  actions = sharding.put_worlds(common.random_actions(env, worlds), mesh)
  counts = collectives(rollout.lower(data, actions).compile())
  seconds, profiled = _timed(rollout, (data, actions), repeats, profile)
  return {
      'steps_per_s': worlds * steps * n / seconds,
      'collectives': counts,
      **({'profile': profiled} if profiled else {}),
  }


def time_composed(
    env, mesh, worlds, steps, repeats, gspmd=False, profile=False
):
  """Composed physics steps/s on `mesh`, and the program's collectives
  (with `profile`, `profile_call`)."""
  rollout = common.env_rollout(env, steps, jit=False)
  if gspmd:
    world = sharding.world_sharding(mesh)
    program = jax.jit(rollout, in_shardings=world, out_shardings=world)
  else:
    program = sharding.per_device(rollout, mesh)
  states = sharding.batched_reset(env, mesh)(
      sharding.world_keys(jax.random.key(0), worlds, mesh)
  )
  if gspmd:
    # shard_map leaves empty arrays (e.g. `act` of a model without
    # activations) replicated; jax.jit's in_shardings wants every argument
    # as declared.
    states = sharding.put_worlds(states, mesh)
  actions = sharding.put_worlds(common.random_actions(env, worlds), mesh)
  # The same executable the timed calls use (jit reuses it: no recompile).
  counts = collectives(program.lower(states, actions).compile())
  seconds, profiled = _timed(program, (states, actions), repeats, profile)
  return {
      'steps_per_s': worlds * steps * env.n_sub_steps / seconds,
      'collectives': counts,
      **({'profile': profiled} if profiled else {}),
  }


def ppo_config(worlds, devices, args):
  """Minibatches that split the worlds evenly over `devices`."""
  minibatches = max(
      m
      for m in range(1, args.ppo_minibatches + 1)
      if worlds % (m * devices) == 0
  )
  return {
      'num_envs': worlds,
      'num_minibatches': minibatches,
      # batch_size x num_minibatches = num_envs: one unroll per world per
      # training step.
      'batch_size': worlds // minibatches,
      'unroll_length': args.ppo_unroll,
      'num_updates_per_batch': args.ppo_updates,
  }


def time_ppo(brax_env, worlds, devices, args):
  """Brax PPO physics steps/s on `devices` local devices."""
  # pylint: disable=g-import-not-at-top
  from brax.training.agents.ppo import networks as ppo_networks
  from brax.training.agents.ppo import train as ppo

  from mjx_composer.adapters import brax as brax_adapter

  # pylint: enable=g-import-not-at-top
  config = ppo_config(worlds, devices, args)
  per_training_step = worlds * config['unroll_length']
  epochs = args.ppo_epochs
  sps = []
  start = time.perf_counter()
  with partitioner.scope(jax.local_devices()[:devices]):
    ppo.train(
        environment=brax_env,
        num_timesteps=epochs * args.ppo_steps_per_epoch * per_training_step,
        num_evals=epochs + 1,  # one progress call per epoch
        run_evals=False,
        max_devices_per_host=devices,
        learning_rate=3e-3,
        entropy_cost=0.0,
        discounting=0.95,
        seed=0,
        network_factory=functools.partial(
            ppo_networks.make_ppo_networks,
            policy_obs_key='policy',
            value_obs_key='policy',
            policy_hidden_layer_sizes=(64, 64),
            value_hidden_layer_sizes=(256, 256),
            init_noise_std=0.5,
        ),
        progress_fn=lambda step, metrics: sps.append(
            float(metrics['training/sps'])
        ),
        **config,
        **brax_adapter.training_kwargs(brax_env),
    )
  total = time.perf_counter() - start
  n = brax_env.environment.n_sub_steps
  return {
      # The first epoch includes compiling the training program.
      'steps_per_s': n * statistics.median(sps[1:] or sps),
      'env_steps_per_s_per_epoch': sps,
      'total_s': total,
      **config,
  }


def train_flags(task, devices, scale, args):
  """`mjx-composer train` flags of one scaling run.

  `scale` multiplies the task's `num_envs` and `batch_size` (weak scaling:
  the number of devices), so each device trains the worlds and minibatch
  one device has at scale 1; every interval between evaluations is
  `args.train_updates` training steps.
  """
  from mjx_composer.training import config as config_lib  # pylint: disable=g-import-not-at-top

  config = config_lib.defaults(task)
  worlds, batch = config.num_envs * scale, config.batch_size * scale
  per_update = batch * config.num_minibatches * config.unroll_length
  steps = args.train_intervals * args.train_updates * per_update
  return [
      '--devices', str(devices), '--num-envs', str(worlds),
      '--batch-size', str(batch), '--num-timesteps', str(steps),
      '--num-evals', str(args.train_intervals + 1), '--no-tensorboard',
  ]  # fmt: skip


def train_rate(rows):
  """Median env steps/s of `metrics.csv` rows after the first interval.

  Row 0 is the evaluation before training; row 1's interval holds the
  training step's compile.
  """
  if len(rows) < 3:
    raise ValueError(
        f'{len(rows)} evaluations: the rate needs at least 3 (the first '
        'two intervals hold the compile); raise --train-intervals.'
    )
  return statistics.median(row['env_steps_per_s'] for row in rows[2:])


def time_train(task, devices, scale, args):
  """Env steps/s of `mjx-composer train` in its own process, or None."""
  from mjx_composer.training import trainer  # pylint: disable=g-import-not-at-top

  flags = train_flags(task, devices, scale, args)
  with tempfile.TemporaryDirectory() as tmp:
    run_dir = os.path.join(tmp, 'run')
    command = [sys.executable, '-m', 'mjx_composer.cli', 'train', task]
    command += ['--run-dir', run_dir, *flags]
    print(' '.join(command[1:]), flush=True)
    start = time.perf_counter()
    if subprocess.run(command, check=False).returncode:
      return None  # its output says why
    rows = trainer.read_csv(os.path.join(run_dir, 'metrics.csv'))
  return {
      'steps_per_s': train_rate(rows),
      'env_steps_per_s_per_interval': [r['env_steps_per_s'] for r in rows[1:]],
      'final_return': rows[-1]['eval_return'],
      'total_s': time.perf_counter() - start,
      'flags': flags,
  }


def main():
  parser = common.make_parser(__doc__, repeats=3, out='scaling.json')
  parser.add_argument('--worlds', type=int, default=65_536)
  parser.add_argument(
      '--steps', type=int, default=10, help='control steps per timed call'
  )
  parser.add_argument(
      '--time-limit',
      type=float,
      default=1.0,
      help='episode length in seconds (reach: 50 control steps)',
  )
  parser.add_argument('--parts', nargs='+', choices=PARTS, default=list(PARTS))
  parser.add_argument(
      '--gspmd',
      action=argparse.BooleanOptionalAction,
      default=True,
      help='also time the composed rollout partitioned by XLA (jax.jit with '
      'shardings) on all devices',
  )
  parser.add_argument(
      '--profile',
      action='store_true',
      help='also profile one call of each raw and composed program: each '
      "device's kernel time (`device_busy`)",
  )
  parser.add_argument('--ppo-epochs', type=int, default=3)
  parser.add_argument('--ppo-steps-per-epoch', type=int, default=2)
  parser.add_argument('--ppo-unroll', type=int, default=10)
  parser.add_argument('--ppo-minibatches', type=int, default=32)
  parser.add_argument('--ppo-updates', type=int, default=8)
  parser.add_argument(
      '--scaling',
      nargs='+',
      choices=SCALINGS,
      default=['strong'],
      help='strong: the same worlds on all devices; weak: devices x worlds',
  )
  parser.add_argument(
      '--train-task', default='joystick', help="the train part's task"
  )
  parser.add_argument(
      '--train-intervals',
      type=int,
      default=4,
      help='evaluation intervals of each train run (the first compiles)',
  )
  parser.add_argument(
      '--train-updates',
      type=int,
      default=20,
      help='training steps (one unroll of every world each) per interval',
  )
  args = parser.parse_args()
  if args.ppo_epochs < 2 and 'ppo' in args.parts:
    parser.error('--ppo-epochs must be at least 2 (the first compiles).')
  if args.train_intervals < 2 and 'train' in args.parts:
    parser.error('--train-intervals must be at least 2 (the first compiles).')

  results = {}

  def record(part, key, result):
    results.setdefault(part, {})[key] = result
    rate = f'{result["steps_per_s"]:,.0f}' if result else 'failed'
    print(f'{part:>9} on {key} device(s): {rate} steps/s', flush=True)
    profiled = (result or {}).get('profile') or {}
    for name, row in profiled.get('devices', {}).items():
      print(
          f'{"":>9}   {name}: kernels busy {row["busy_fraction"]:.3f} of '
          f'the call, {row["kernels"]:,} kernels',
          flush=True,
      )

  if 'train' in args.parts:
    # Before this process takes the devices' memory: each run is a process.
    for key, (count, scale) in _runs(_local_device_count(), args).items():
      record('train', key, time_train(args.train_task, count, scale, args))

  cache_dir = platform.configure()
  device = common.print_device()
  local = jax.local_devices()
  n = len(local)
  runs = {
      key: (count, args.worlds * scale)
      for key, (count, scale) in _runs(n, args).items()
  }
  for count, worlds in runs.values():
    sharding.check_num_worlds(worlds, sharding.world_mesh(local[:count]))
  print(
      f'{args.worlds:,} worlds on 1 device, runs {runs} on {n}; compilation '
      f'cache: {cache_dir or "off"}',
      flush=True,
  )

  env = common.make_env('reach', time_limit=args.time_limit)
  for key, (count, worlds) in runs.items():
    mesh = sharding.world_mesh(local[:count])
    if 'raw' in args.parts:
      record(
          'raw',
          key,
          time_raw(env, mesh, worlds, args.steps, args.repeats, args.profile),
      )
    if 'composed' in args.parts:
      record(
          'composed',
          key,
          time_composed(
              env,
              mesh,
              worlds,
              args.steps,
              args.repeats,
              profile=args.profile,
          ),
      )
    if 'composed' in args.parts and args.gspmd and count > 1:
      # XLA's partitioning of one program; on one device it is the same
      # program as `composed`.
      results.setdefault('gspmd', {'1': results['composed']['1']})
      record(
          'gspmd',
          key,
          time_composed(
              env, mesh, worlds, args.steps, args.repeats, gspmd=True
          ),
      )
  if 'ppo' in args.parts:
    from mjx_composer.adapters import brax as brax_adapter  # pylint: disable=g-import-not-at-top

    brax_env = brax_adapter.BraxEnv(env)
    for key, (count, worlds) in runs.items():
      record('ppo', key, time_ppo(brax_env, worlds, count, args))

  summary = summarize(results, n, args.scaling)
  common.write_results(
      args.out,
      device,
      {'summary': summary, 'runs': results},
      worlds=args.worlds,
      devices=n,
      n_sub_steps=env.n_sub_steps,
      steps_per_call=args.steps,
      time_limit=args.time_limit,
      train_task=args.train_task if 'train' in args.parts else None,
  )
  print(
      f'\n{args.worlds:,} worlds on one device, {device.device_kind}; '
      f'physics steps/s (train: env steps/s); efficiency: {n}-device / '
      f'({n} x 1-device); weak: {n} x the worlds on {n}'
  )
  print(
      f'| part | scaling | 1 device | {n} devices | efficiency | '
      f'collectives on {n} |'
  )
  print('|---|---|---|---|---|---|')
  for row in summary:
    many = results[row['part']].get(_key(n, row['scaling'])) or {}
    if 'collectives' in many:
      found = {k: v for k, v in many['collectives'].items() if v}
      found = ', '.join(f'{k} x{v}' for k, v in found.items()) or 'none'
    else:
      found = '-'  # not counted (Brax's programs)
    print(
        f'| {row["part"]} | {row["scaling"]} | {row["one_device"]:,.0f} | '
        f'{row["all_devices"]:,.0f} | {row["efficiency"]:.3f} | {found} |'
    )


def _key(devices, scaling):
  """The `runs` key of a run on `devices` devices."""
  return str(devices) if scaling == 'strong' else f'{devices}_{scaling}'


def _runs(n, args):
  """`{key: (devices, worlds scale)}`: one device, then `n` per scaling."""
  runs = {'1': (1, 1)}
  for scaling in args.scaling if n > 1 else ():
    runs[_key(n, scaling)] = (n, n if scaling == 'weak' else 1)
  return runs


def summarize(results, n, scalings):
  """One row per part and scaling: its rates and efficiency on `n` devices.

  A part whose runs failed (None) is left out; with one device, the
  one-device run stands for all. Where both runs were profiled, the row
  also holds the least busy device's `busy_fraction` of each.
  """
  summary = []
  for part, runs in results.items():
    for scaling in scalings:
      one = runs.get('1')
      many = runs.get(_key(n, scaling)) if n > 1 else one
      if not one or not many:
        continue
      row = {
          'part': part,
          'scaling': scaling,
          'one_device': one['steps_per_s'],
          'all_devices': many['steps_per_s'],
          'devices': n,
          'efficiency': many['steps_per_s'] / (n * one['steps_per_s']),
      }
      if 'profile' in one and 'profile' in many:
        row['busy_fraction_one_device'] = _least_busy(one['profile'])
        row['busy_fraction_all_devices'] = _least_busy(many['profile'])
      summary.append(row)
  return summary


def _least_busy(profiled):
  """The lowest `busy_fraction` of a `profile_call`'s devices, or None."""
  fractions = [r['busy_fraction'] for r in profiled['devices'].values()]
  return min(fractions) if fractions else None


def _local_device_count():
  """JAX's local device count, asked of another process.

  Starting JAX's GPU client here would reserve most of each GPU's memory
  for this process, none left for the training runs' processes.
  """
  command = [
      sys.executable,
      '-c',
      'import jax; print(jax.local_device_count())',
  ]
  return int(subprocess.check_output(command, text=True).split()[-1])


if __name__ == '__main__':
  main()
