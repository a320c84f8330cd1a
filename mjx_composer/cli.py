"""The `mjx-composer` command line: `mjx-composer demo|list|train|play|export`.

`demo` builds a registered task (`mjx_composer.suite.tasks.registry`: the
bundled ones, or yours), runs N worlds for T control steps on the default
JAX device (the CPU unless a GPU build of JAX is installed) with a random
policy, shows progress, and prints throughput and episode statistics.
`list` prints the registered tasks, one a line. `train`, `play` and
`export` train a registered task with Brax's PPO into a run folder, watch
the trained policy and export it as ONNX (`mjx_composer.training`; `pip
install 'mjx-composer[train]'`).

Every command takes `--import MODULE` (repeatable): modules that register
your own tasks, imported (the current directory on the path) before the
command runs; `train` records them in the run folder, so that `play`,
`export` and `train --resume` import them again. `main` returns the exit
status; a command that fails prints one line, `error: ...`, on stderr.

Compiled programs are kept in JAX's persistent compilation cache
(`mjx_composer.platform.compilation_cache`), so a second run with the same
options skips most of the compilation; `--no-compilation-cache` or
`MJX_COMPOSER_COMPILATION_CACHE=0` turns that off.
"""

import argparse
import os
import sys
import time

import jax
import jax.numpy as jnp
import tqdm

from mjx_composer import platform
from mjx_composer.suite.tasks import registry

_COMMANDS = ('demo', 'list', 'train', 'play', 'export')


def make_rollout(env, num_worlds, chunk, metrics=()):
  """A jitted function running `chunk` steps of a random policy.

  `rollout(states, key, totals) -> (states, key, totals)` adds up, over the
  episodes that end, their returns, lengths, initialization failures and
  the final values of the `State.metrics` entries named in `metrics`
  (`totals['metrics'][name]`), and counts diverged worlds.
  """
  spec = env.action_spec()
  low, high = jnp.asarray(spec.minimum), jnp.asarray(spec.maximum)
  step = jax.vmap(env.step)

  def one_step(carry, _):
    states, key, totals = carry
    key, action_key = jax.random.split(key)
    actions = jax.random.uniform(
        action_key, (num_worlds,) + spec.shape, minval=low, maxval=high
    )
    states = step(states, actions)
    ended = states.last()
    missing = sorted(set(metrics) - set(states.metrics))
    if missing:
      raise ValueError(
          f'The task reports no metrics {missing} (its registry entry names '
          f'them); it reports {sorted(states.metrics)}.'
      )
    totals = {
        'episodes': totals['episodes'] + jnp.sum(ended),
        'return': totals['return']
        + jnp.sum(jnp.where(ended, states.metrics['episode_return'], 0.0)),
        'length': totals['length']
        + jnp.sum(jnp.where(ended, states.metrics['episode_length'], 0)),
        'metrics': {
            name: totals['metrics'][name]
            + jnp.sum(jnp.where(ended, _per_world(states.metrics, name), 0.0))
            for name in metrics
        },
        'diverged': totals['diverged'] + jnp.sum(states.metrics['diverged']),
        'init_failures': totals['init_failures']
        + jnp.sum(jnp.where(ended, states.metrics['init_failures'], 0.0)),
    }
    return (states, key, totals), None

  @jax.jit
  def rollout(states, key, totals):
    (states, key, totals), _ = jax.lax.scan(
        one_step, (states, key, totals), None, length=chunk
    )
    return states, key, totals

  return rollout


def _per_world(metrics, name):
  value = metrics[name]
  if value.ndim != 1:
    raise ValueError(
        f'The metric {name!r} has shape {value.shape[1:]} per world; the '
        'demo averages metrics of one value per world.'
    )
  return value


def _add_import_flag(parser):
  parser.add_argument(
      '--import',
      dest='imports',
      action='append',
      default=[],
      metavar='MODULE',
      help='a module that registers tasks, imported first (repeatable)',
  )


def _import_modules(modules):
  """Imports `modules` (`--import`), with the current directory on the path.

  An installed `mjx-composer` script, unlike `python -m`, starts without the
  current directory on `sys.path`; a module beside the user is found there
  (after the installed packages).
  """
  modules = tuple(modules)
  if modules and '' not in sys.path and os.getcwd() not in sys.path:
    sys.path.append(os.getcwd())
  registry.import_modules(modules)
  return modules


def _import_flagged(argv):
  """Imports the modules of `argv`'s `--import` flags; returns their names."""
  parser = argparse.ArgumentParser(add_help=False)
  _add_import_flag(parser)
  return _import_modules(parser.parse_known_args(argv)[0].imports)


def _import_recorded(run_path, extra=()):
  """Imports the modules a run recorded (`TrainConfig.imports`) and `extra`.

  Raises:
    RunFolderError: for a path that is not a readable run folder.
  """
  from mjx_composer.training import run_folder  # pylint: disable=g-import-not-at-top

  recorded = run_folder.open_run(run_path).read_config().imports
  _import_modules(dict.fromkeys((*recorded, *extra)))


def demo_parser():
  """The `mjx-composer demo` argument parser."""
  parser = argparse.ArgumentParser(
      prog='mjx-composer demo',
      description=(
          'Run a bundled composed task for N worlds and T control steps.'
      ),
  )
  parser.add_argument(
      '--task',
      default='reach',
      help=f'a registered task: {", ".join(registry.names())}',
  )
  _add_import_flag(parser)
  parser.add_argument('--worlds', type=int, default=64)
  parser.add_argument(
      '--steps', type=int, default=200, help='control steps per world'
  )
  parser.add_argument(
      '--chunk',
      type=int,
      default=25,
      help='control steps per jitted call (progress granularity)',
  )
  parser.add_argument(
      '--time-limit', type=float, default=1.0, help='episode length in seconds'
  )
  parser.add_argument('--seed', type=int, default=0)
  parser.add_argument(
      '--impl',
      choices=('jax', 'warp'),
      default=None,
      help="physics implementation: MJX's JAX one or MuJoCo Warp "
      "(pip install 'mjx-composer[warp]'); default: Environment's (warp on "
      'a CUDA GPU where it is installed and runs the task, else jax)',
  )
  parser.add_argument(
      '--no-compilation-cache',
      action='store_true',
      help="don't read or write JAX's persistent compilation cache "
      '(default: on, in $MJX_COMPOSER_CACHE_DIR or '
      '~/.cache/mjx_composer/jax)',
  )
  return parser


def demo(argv=None):
  """`mjx-composer demo`: runs a registered task with a random policy."""
  from mjx_composer import environment  # pylint: disable=g-import-not-at-top

  _import_flagged(argv)
  parser = demo_parser()
  args = parser.parse_args(argv)
  if args.worlds < 1 or args.steps < 1 or args.chunk < 1:
    parser.error('--worlds, --steps and --chunk must be positive.')
  metrics = registry.entry(args.task).metrics
  cache_dir = platform.configure(
      compilation_cache=False if args.no_compilation_cache else None
  )

  print(
      f'JAX {jax.__version__} on {jax.devices()[0].platform}: '
      f'{jax.devices()[0].device_kind}; compilation cache: '
      f'{cache_dir or "off"}'
  )
  t0 = time.perf_counter()
  env = registry.make_environment(
      args.task,
      time_limit=args.time_limit,
      options=environment.ExecutionOptions(
          auto_reset='same_step', impl=args.impl
      ),
  )
  print(
      f'Task {args.task!r}: {env.mj_model.nbody} bodies, '
      f'{env.mj_model.nu} actuators, {env.n_sub_steps} sub-steps per '
      f'control step, physics on impl={env.impl!r}, built in '
      f'{time.perf_counter() - t0:.1f}s.'
  )
  for group, spec in env.observation_spec().items():
    print(f'  observation group {group!r}: {spec.shape}')

  chunk = min(args.chunk, args.steps)
  num_chunks = -(-args.steps // chunk)
  key = jax.random.key(args.seed)
  key, reset_key = jax.random.split(key)
  reset = jax.jit(jax.vmap(env.reset))
  rollout = make_rollout(env, args.worlds, chunk, tuple(metrics))
  totals = {
      'episodes': jnp.zeros((), jnp.int32),
      'return': jnp.zeros(()),
      'length': jnp.zeros((), jnp.int32),
      'metrics': {name: jnp.zeros(()) for name in metrics},
      'diverged': jnp.zeros(()),
      'init_failures': jnp.zeros(()),
  }

  # A cold compile takes minutes on a CPU: say what runs before it does.
  t0 = time.perf_counter()
  print(
      f'Compiling the reset of {args.worlds} worlds and a {chunk}-step '
      f'rollout (seconds on a GPU, minutes on a CPU; later runs load them '
      f'from the compilation cache: {cache_dir or "off"})...',
      flush=True,
  )
  states = reset(jax.random.split(reset_key, args.worlds))
  states, key, totals = jax.block_until_ready(rollout(states, key, totals))
  print(
      f'Compiled reset and a {chunk}-step rollout in '
      f'{time.perf_counter() - t0:.1f}s.'
  )
  totals = jax.tree.map(jnp.zeros_like, totals)  # don't count warm-up
  t0 = time.perf_counter()
  with tqdm.tqdm(
      total=num_chunks * chunk * args.worlds,
      unit='step',
      unit_scale=True,
      desc='stepping',
      file=sys.stdout,
  ) as bar:
    for _ in range(num_chunks):
      states, key, totals = jax.block_until_ready(rollout(states, key, totals))
      bar.update(chunk * args.worlds)
  elapsed = time.perf_counter() - t0
  totals = jax.device_get(totals)
  steps = num_chunks * chunk * args.worlds
  print(
      f'\n{steps:,} control steps ({steps * env.n_sub_steps:,} physics '
      f'steps) in {elapsed:.2f}s: {steps / elapsed:,.0f} control steps/s, '
      f'{steps * env.n_sub_steps / elapsed:,.0f} physics steps/s.'
  )
  episodes = int(totals['episodes'])
  if episodes:
    print(
        f'Episodes finished: {episodes:,}; mean return '
        f'{float(totals["return"]) / episodes:.3f}, mean length '
        f'{int(totals["length"]) / episodes:.1f} steps.'
    )
    if metrics:
      print("Metrics at the episodes' ends, mean:")
      width = max(map(len, metrics))
      for name, description in metrics.items():
        mean = float(totals['metrics'][name]) / episodes
        print(f'  {name:<{width}}  {mean:9.3f}  {description}')
  else:
    print('No episode finished: raise --steps or lower --time-limit.')
  print(f'Diverged worlds: {int(totals["diverged"])}.')
  if int(totals['init_failures']):
    print(
        'Failed episode initializations (e.g. props that could not be '
        f'placed): {int(totals["init_failures"])}.'
    )
  return 0


def list_tasks(argv=None):
  """`mjx-composer list`: the registered tasks, one a line."""
  parser = argparse.ArgumentParser(
      prog='mjx-composer list',
      description=(
          'List the registered tasks (mjx_composer.suite.tasks.registry).'
      ),
  )
  _add_import_flag(parser)
  _import_modules(parser.parse_args(argv).imports)
  width = max(map(len, registry.names()), default=0)
  for name in registry.names():
    print(f'{name:<{width}}  {registry.describe(name)}'.rstrip())
  return 0


_USAGE = """\
usage: mjx-composer demo [--task NAME] [--worlds N] [--steps T] [--time-limit S]
                         [--seed K] [--impl jax|warp] [--no-compilation-cache]
       mjx-composer list                       (the task names)
       mjx-composer train TASK [--config FILE] [--run-dir DIR] [--SETTING VALUE ...]
       mjx-composer train --resume RUN [--num-timesteps N ...]
         on each host of a cluster: --distributed [--coordinator HOST:PORT
                                    --num-processes N --process-id I]
       mjx-composer play RUN [--worlds N] [--steps T] [--seed K] [--out DIR]
                             [--no-video] [--no-compilation-cache]
       mjx-composer export RUN --format onnx [--out FILE]
'train --help' lists the settings and TASK's defaults. Every command takes
--import MODULE (repeatable): a module that registers your own tasks."""


def _error(message):
  """Prints `error: message` on one line on stderr; returns the exit status."""
  print(f'error: {" ".join(str(message).split())}', file=sys.stderr)
  return 2


def resolve_train_config(argv, create=True):
  """`(config, run folder, resume)` of `mjx-composer train` arguments.

  The task's defaults (or `--resume RUN`'s config), then `--config FILE`,
  then the flags; a new run's folder is created (`--run-dir`, default
  `runs/<task>_<time>`) unless `create` is False.
  """
  # pylint: disable=g-import-not-at-top
  from mjx_composer.training import config as config_lib
  from mjx_composer.training import run_folder
  # pylint: enable=g-import-not-at-top

  task = argv[0] if argv and not argv[0].startswith('-') else None
  front = argparse.ArgumentParser(add_help=False)
  for flag in ('--config', '--run-dir', '--resume'):
    front.add_argument(flag)
  _add_import_flag(front)
  known, rest = front.parse_known_args(argv[1:] if task else argv)
  if known.resume:
    if known.run_dir:
      raise ValueError('--resume RUN continues RUN: leave out --run-dir.')
    run = run_folder.open_run(known.resume)
    base = saved = run.read_config()
    imports = _import_modules(dict.fromkeys((*saved.imports, *known.imports)))
    if task is not None and task != saved.task:
      raise run_folder.RunFolderError(
          f'The run {known.resume!r} trains task {saved.task!r}, not '
          f'{task!r}: resume it with its own task, or start a new run.'
      )
  else:
    if task is None and not {'-h', '--help'} & set(rest):
      raise ValueError(
          'mjx-composer train TASK: name a task (mjx-composer list), or '
          'continue a run with --resume RUN.'
      )
    task = task or 'reach'
    imports = _import_modules(dict.fromkeys(known.imports))
    base = config_lib.defaults(task)
  base = base.replace(imports=imports)
  if known.config:
    base = base.replace(**config_lib.load_file(known.config))
  config = config_lib.parse_flags(rest, base)
  if config.task != base.task:
    raise ValueError(
        f'The task is the first argument ({base.task!r}); --task '
        f'{config.task!r} contradicts it.'
    )
  _import_modules(config.imports)  # any given as --imports A B
  if known.resume:
    # Modules imported anew are recorded; they change nothing trained.
    old, new = config_lib.to_dict(saved), config_lib.to_dict(config)
    fixed = old.keys() - config_lib.RESUMABLE - {'imports'}
    if changed := sorted(k for k in fixed if old[k] != new[k]):
      raise run_folder.RunFolderError(
          f'A resumed run keeps its settings; {changed} differ from the run '
          f"folder's config. Only {sorted(config_lib.RESUMABLE)} may change."
      )
    if config != saved and create:
      run.write_config(config)
    return config, run, True
  path = known.run_dir or f'runs/{task}_{time.strftime("%Y%m%d_%H%M%S")}'
  if not create:
    return config, run_folder.RunFolder(path), False
  return config, run_folder.create(path, config), False


def train(argv=None):
  """`mjx-composer train`: trains a registered task into a run folder.

  `--distributed` calls `jax.distributed.initialize` before anything touches
  JAX's devices, with `--coordinator`, `--num-processes` and `--process-id`
  where given, else as JAX finds them (SLURM, Open MPI, environment).
  """
  from mjx_composer.training import trainer  # pylint: disable=g-import-not-at-top

  parser = argparse.ArgumentParser(add_help=False)
  parser.add_argument('--distributed', action='store_true')
  parser.add_argument('--coordinator')
  parser.add_argument('--num-processes', type=int)
  parser.add_argument('--process-id', type=int)
  cluster, argv = parser.parse_known_args(argv or [])
  options = (cluster.coordinator, cluster.num_processes, cluster.process_id)
  if not cluster.distributed and options != (None, None, None):
    raise ValueError(
        '--coordinator, --num-processes and --process-id join a distributed '
        'run: pass --distributed too.'
    )
  try:
    if cluster.distributed:
      jax.distributed.initialize(*options)
  except (ValueError, RuntimeError) as e:
    raise ValueError(
        f'--distributed could not join the processes ({e}). Pass a '
        "coordinator address whose port is free on process 0's host; "
        'outside SLURM and Open MPI, pass --coordinator HOST:PORT '
        '--num-processes N --process-id I on every host.'
    ) from e
  # Process 0 alone writes the run folder.
  create = not jax.distributed.is_initialized() or jax.process_index() == 0
  trainer.train(*resolve_train_config(argv, create))
  return 0


def _run_parser(command, description, out_help):
  """The parser of `play` and `export`: a run folder, --out, --import."""
  parser = argparse.ArgumentParser(f'mjx-composer {command}', None, description)
  parser.add_argument('run', help='the run folder')
  parser.add_argument('--out', help=out_help)
  _add_import_flag(parser)
  return parser


def play(argv=None):
  """`mjx-composer play RUN`: videos, episode statistics and metrics."""
  from mjx_composer.training import video  # pylint: disable=g-import-not-at-top

  parser = _run_parser(
      'play',
      "Run a run's newest policy, deterministic and sampled, and zero "
      'actions as a baseline, from the same reset; write a video of each '
      "policy run (the worlds tiled); print the episode statistics and task's "
      'metrics (mean per world and step), also written to '
      'play_step_<STEP>.json.',
      'default: RUN/videos',
  )
  parser.add_argument('--worlds', type=int, default=4)
  parser.add_argument('--steps', type=int, help='default: one episode')
  parser.add_argument('--seed', type=int, default=1)
  for flag, text in (
      ('--no-video', 'statistics and metrics only: no rendering, no OpenGL'),
      ('--no-compilation-cache', "don't use JAX's compilation cache"),
  ):
    parser.add_argument(flag, action='store_true', help=text)
  args = parser.parse_args(argv)
  off = args.no_compilation_cache
  cache = platform.configure(compilation_cache=False if off else None)
  print(f'Compilation cache: {cache or "off"}.', flush=True)
  _import_recorded(args.run, args.imports)
  result = video.play(
      args.run, args.worlds, args.steps, args.out, args.seed,
      render=not args.no_video, verbose=True,
  )  # fmt: skip
  for mode, stats in result.items():
    line = (
        f'{mode:<14} step {stats["step"]:,}: {stats["episodes"]} episodes '
        f'ended, mean reward per step {stats["mean_reward_per_step"]:.4f}'
    )
    if stats['episodes']:
      line += (
          f', mean return {stats["mean_return"]:.3f}, mean length '
          f'{stats["mean_length"]:.1f} steps'
      )
    print(line + (f'; video {stats["video"]}' if 'video' in stats else ''))
  print('Metrics (mean per world and step):')
  print(f'{"metric":<24}' + ''.join(f'{mode:>15}' for mode in result))
  for name in result['zero']['metrics']:
    values = (f'{s["metrics"][name]:>15.4g}' for s in result.values())
    print(f'{name:<24}' + ''.join(values))
  return 0


def export(argv=None):
  """`mjx-composer export RUN --format onnx`: the policy for deployment."""
  from mjx_composer.training import export as export_lib  # pylint: disable=g-import-not-at-top

  parser = _run_parser(
      'export',
      "Write a run's newest deterministic policy as ONNX, with metadata "
      '(observation names, shapes and order, action bounds, control '
      'timestep, default joint positions).',
      'default: RUN/policy.onnx',
  )
  parser.add_argument('--format', choices=('onnx',), default='onnx')
  args = parser.parse_args(argv)
  _import_recorded(args.run, args.imports)
  path, meta = export_lib.export_onnx(args.run, args.out)
  names = ', '.join(meta['observation_names'])
  print(
      f'Wrote {path}: observation {meta["observation_group"]!r} '
      f'({meta["observation_size"]} values: {names}) -> '
      f'{meta["action_size"]} actions, control timestep '
      f'{meta["control_timestep"]:g}s.'
  )
  return 0


# The modules of the `train` extra (`pip install 'mjx-composer[train]'`).
_TRAIN_EXTRA = frozenset(
    'brax tyro yaml tensorboardX imageio imageio_ffmpeg onnx '
    'onnxruntime'.split()
)


def _missing_extra(error):
  """The `train` extra's module whose absence raised `error`, or None."""
  while error is not None:
    if isinstance(error, ModuleNotFoundError):
      root = (error.name or '').partition('.')[0]
      if root in _TRAIN_EXTRA:
        return root
    error = error.__cause__ or error.__context__
  return None


def main(argv=None):
  """Runs `mjx-composer COMMAND ...`; returns the exit status.

  A command's error (an unknown task, a module of `--import` that cannot
  be imported, a missing optional dependency, a bad setting or run folder)
  is one line on stderr, `error: ...`, and exit status 2. The installed
  `mjx-composer` script exits with the status `main` returns; call it as
  `sys.exit(cli.main([...]))` from a script.
  """
  argv = list(sys.argv[1:] if argv is None else argv)
  if not argv or argv[0] not in _COMMANDS:
    print(_USAGE)
    return 2
  command = {
      'demo': demo,
      'list': list_tasks,
      'train': train,
      'play': play,
      'export': export,
  }[argv[0]]
  try:
    return command(argv[1:])
  except (registry.UnknownTaskError, registry.TaskModuleError) as e:
    return _error(e)
  except ImportError as e:
    missing = _missing_extra(e)
    if missing is None:
      raise
    return _error(
        f'mjx-composer {argv[0]} needs {missing}, which is not installed: '
        "pip install 'mjx-composer[train]'."
    )
  except ValueError as e:
    return _error(e)


if __name__ == '__main__':
  sys.exit(main())
