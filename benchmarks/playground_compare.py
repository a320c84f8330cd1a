"""The walk task against MuJoCo Playground's HumanoidWalk and raw MJX.

In one process, for each number of worlds, four programs step the same
humanoid (dm_control's suite humanoid, the XML Playground's HumanoidWalk
loads) for `--steps` control steps of 5 physics steps, held actions:

* ours_on:    `vmap(env.step)` of the bundled walk task as shipped: policy
              noise, latency and history, policy/critic groups, per-episode
              randomization (densities, gears, friction), pushes, falls
              ending episodes (same-step auto-reset, 1000-step episodes);
* ours_off:   the same task with all of that off
              (`walk.PLAYGROUND_EQUIVALENT`), observing only the 'policy'
              group, which is then HumanoidWalk's observation;
* playground: `vmap(env.step)` of `registry.load('HumanoidWalk')` from
              playground 0.2.0 with `impl='jax'` (skipped, with the reason,
              when `mujoco_playground` cannot be imported);
* playground_trained: on request, that environment as Brax trains it
              (`mujoco_playground.wrapper.wrap_for_brax_training`: episode
              counter, time limit and auto-reset to a stored first state,
              1000-step episodes): the step Playground's PPO runs, with the
              episode bookkeeping every one of ours does in its step;
* raw:        `vmap(mjx.step)` on ours_off's compiled model, the sub-steps in
              a `fori_loop` (`common.raw_rollout`), from `qpos0` plus noise,
              the same actions as controls;
* only_<f>:   on request (`--programs`), ours_off with one of ours_on's
              features switched back on, to find what each costs: noise,
              delay, history, randomize, push, fall (`FEATURES`), or groups
              (the critic group observed too); `only_<f>+<g>+...` switches
              on several (e.g. only_fall+randomize);
* <ours>_chunk<K>: on request, any of ours with `auto_reset_batch=K`
              (e.g. ours_on_chunk512): the worlds whose episodes end are
              reset K at a time, so the step program's restart holds K
              worlds' temporaries (the default, 'auto', resets an eighth of
              a batch of 1,024 worlds or more); `_chunkall` with
              `auto_reset_batch=None`, the whole batch's reset.

For each: control steps per second (median of `--repeats` calls), the first
call's seconds (trace, lower and XLA compile of the rollout, and of the
reset), and memory per world: the bytes of one world's state, and the step
program's arguments + outputs + temporaries (XLA's memory analysis of the
compiled rollout) over the number of worlds. On a GPU the device's peak
bytes in use after each program are recorded too (a running maximum: JAX
cannot reset it). Ratios: ours/raw and ours/playground per world count.

Every program compiles as our scripts and command line compile
(`platform.configure`: threefry lowered as JAX's GPU kernel, whose effect
on the first calls docs/performance.md gives; `MJX_COMPOSER_THREEFRY_KERNEL=0`
measures without), Playground's and raw MJX's too, and never from JAX's
persistent compilation cache.

The process compiles a trivial function before the first program, so that
the backend's start-up is in no program's first call. Later programs can
still profit from the earlier ones' compiles (XLA's autotuning results, JAX's
caches), so with `--isolated` each program at each number of worlds runs in
a fresh process of this script instead: first calls are then each program's
own, and so is the peak memory; the ratios divide figures from different
processes. A host's compile times drift between processes (by a quarter on
the GPU machines), so `--processes K` measures each program in K processes,
the programs taking turns (one process of each, then the next round), and
records each figure's median, the first calls' samples and, per reference,
the ratio of the first calls' medians (`<ours>/<other> first calls`: reset
compile plus the rollout's first call).

    python benchmarks/playground_compare.py --worlds 1024 8192 32768
    python benchmarks/playground_compare.py --worlds 4 --steps 2   # smoke
    python benchmarks/playground_compare.py --worlds 8192 --isolated \
        --programs ours_off playground raw

Playground 0.2.0's imports need, besides this project's dependencies,
`playground==0.2.0` and `lxml` (see the module's `PLAYGROUND_NEEDS`).
"""

import argparse
import importlib.metadata
import json
import os
import re
import subprocess
import sys
import tempfile
import time

import jax
import numpy as np

from mjx_composer import platform
from mjx_composer.platform import prng_lowering

import common  # benchmarks/common.py

# What `import mujoco_playground` + `registry.load('HumanoidWalk')` needs
# beyond this project's own environment (checked with playground 0.2.0).
PLAYGROUND_NEEDS = ('playground==0.2.0', 'lxml')


def _tree_bytes(tree):
  return sum(
      int(np.prod(x.shape)) * x.dtype.itemsize
      for x in jax.tree.leaves(tree)
      if hasattr(x, 'dtype')
      and not jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)
  )


def _program_bytes(compiled):
  """Arguments + outputs + temporaries of a compiled program (or None)."""
  try:
    analysis = compiled.memory_analysis()
  except Exception:  # pylint: disable=broad-except
    return None
  if analysis is None:
    return None
  return int(
      analysis.argument_size_in_bytes
      + analysis.output_size_in_bytes
      + analysis.temp_size_in_bytes
      - analysis.alias_size_in_bytes
  )


def _peak_bytes(device):
  stats = device.memory_stats() if hasattr(device, 'memory_stats') else None
  return None if not stats else stats.get('peak_bytes_in_use')


def measure(reset, rollout, keys, actions, repeats, device):
  """Times one variant: `reset(keys) -> state`, `rollout(state, a)`."""
  t0 = time.perf_counter()
  reset_compiled = jax.jit(reset).lower(keys).compile()
  reset_compile_s = time.perf_counter() - t0
  state = jax.block_until_ready(reset_compiled(keys))
  t0 = time.perf_counter()
  compiled = jax.jit(rollout).lower(state, actions).compile()
  compile_s = time.perf_counter() - t0
  t0 = time.perf_counter()
  out = jax.block_until_ready(compiled(state, actions))
  first_run_s = time.perf_counter() - t0
  seconds = common.time_fn(compiled, out, repeats)
  worlds = actions.shape[0]
  program = _program_bytes(compiled)
  return {
      'seconds_per_call': seconds,
      'reset_compile_s': reset_compile_s,
      'rollout_compile_s': compile_s,
      'first_call_s': compile_s + first_run_s,
      'state_bytes_per_world': _tree_bytes(state) / worlds,
      'program_bytes_per_world': None if program is None else program / worlds,
      'peak_bytes_in_use': _peak_bytes(device),
  }


# The features `walk.PLAYGROUND_EQUIVALENT` switches off, by program name:
# `only_<name>` is ours_off with that one switched back on (its default),
# `only_<name>+<name>...` with those; 'groups' observes the critic group too.
FEATURES = {
    'noise': 'noise_level',
    'delay': 'observation_delay',
    'history': 'history',
    'randomize': 'randomize',
    'push': 'push_interval',
    'fall': 'terminate_on_fall',
}


SHARED = '_shared'
ALL_SENSORS = '_all_sensors'
NO_STORE = '_nostore'
CONDITIONALS = '_cond'
LOOPS = '_loop'
# Suffixes of ours' programs, each an `Environment` argument.
SUFFIXES = {
    SHARED: dict(share_reset_forward=True),
    ALL_SENSORS: dict(substep_sensors='all'),
    NO_STORE: dict(stored_restart='never'),
    CONDITIONALS: dict(branches='cond'),
    LOOPS: dict(branches='loop'),
}
# `_chunk<K>`: `auto_reset_batch=K`; `_chunkall`: None (the whole batch).
_CHUNK = re.compile(r'_chunk([1-9][0-9]*|all)$')


def split_suffixes(name):
  """(base, `Environment` kwargs) of a program name of ours."""
  kwargs = {}
  stripped = True
  while stripped:
    stripped = False
    for suffix, suffix_kwargs in SUFFIXES.items():
      if name.endswith(suffix):
        name = name[: -len(suffix)]
        kwargs.update(suffix_kwargs)
        stripped = True
    chunk = _CHUNK.search(name)
    if chunk:
      name = name[: chunk.start()]
      size = chunk.group(1)
      kwargs['auto_reset_batch'] = None if size == 'all' else int(size)
      stripped = True
  return name, kwargs


def program_name(name):
  """`--programs`' type: a known program, or only_ with known features.

  Ours' programs may end in `_shared`: the same environment with
  `share_reset_forward=True` (the restart of ended episodes fused into the
  sub-step loop), e.g. `ours_on_shared`; and in `_all_sensors`: with
  `substep_sensors='all'` (every sub-step computes the sensors, as
  `mjx.step` does), e.g. `ours_off_all_sensors`; and in `_nostore`: with
  `stored_restart='never'` (the step program runs the reset where it would
  restore a copy of the first state), e.g. `ours_off_nostore`; and in
  `_cond` or `_loop`: with `branches='cond'` or `'loop'` (what runs at some
  steps only is a conditional, or a loop run once or never), e.g.
  `ours_on_shared_cond`; and in `_chunk<K>`: with
  `auto_reset_batch=K` (not with `_shared`), e.g. `ours_on_chunk512`, or
  `_chunkall`: with `auto_reset_batch=None` (the whole batch's reset).
  """
  if name.startswith(('playground', 'raw')):
    if name in ('playground', 'playground_trained', 'raw'):
      return name
    raise argparse.ArgumentTypeError(f'unknown program {name!r}')
  base, kwargs = split_suffixes(name)
  if kwargs.get('share_reset_forward') and kwargs.get('auto_reset_batch'):
    raise argparse.ArgumentTypeError(
        f'{name!r}: auto_reset_batch needs the separate restart'
    )
  features = base[len('only_') :].split('+')
  if base in ('ours_on', 'ours_off') or (
      base.startswith('only_')
      and all(f in FEATURES or f == 'groups' for f in features)
  ):
    return name
  raise argparse.ArgumentTypeError(
      f'unknown program {name!r}: ours_on, ours_off, playground, '
      'playground_trained, raw, '
      "or only_ followed by features joined by '+' from "
      f'{", ".join((*FEATURES, "groups"))}; ours\' may end in '
      f'{", ".join(SUFFIXES)} and _chunk<K> or _chunkall'
  )


def env_variants(names, **env_kwargs):
  """The environments (walk task) of the programs `names` that are ours.

  `env_kwargs` go to every `Environment` (e.g. `share_reset_forward`).
  """
  # pylint: disable=g-import-not-at-top
  from mjx_composer import environment
  from mjx_composer.suite.tasks import walk

  # pylint: enable=g-import-not-at-top
  envs = {}
  for name in names:
    base, suffix_kwargs = split_suffixes(name)
    if suffix_kwargs:
      kwargs = dict(env_kwargs, **suffix_kwargs)
      envs[name] = env_variants([base], **kwargs)[base]
    elif name == 'ours_on':
      envs[name] = common.make_env(
          'walk', time_limit=walk.EPISODE_SECONDS, **env_kwargs
      )
    elif name == 'ours_off':
      envs[name] = common.make_walk_like_playground(
          walk.EPISODE_SECONDS, **env_kwargs
      )
    elif name.startswith('only_'):
      features = name[len('only_') :].split('+')
      kwargs = dict(walk.PLAYGROUND_EQUIVALENT)
      for feature in features:
        if feature != 'groups':
          del kwargs[FEATURES[feature]]
      task = walk.Walk(**kwargs)
      groups = task.observation_groups()
      if 'groups' not in features:
        policy_only = {'policy': groups['policy']}
        task.observation_groups = lambda groups=policy_only: groups
      envs[name] = environment.Environment(
          task,
          time_limit=walk.EPISODE_SECONDS,
          options=environment.ExecutionOptions(
              auto_reset='same_step', **env_kwargs
          ),
      )
  return envs


def _playground_env():
  """(HumanoidWalk with impl='jax', None) or (None, why it is skipped)."""
  try:
    # pylint: disable=g-import-not-at-top
    import mujoco_playground
    from mujoco_playground import registry
    # pylint: enable=g-import-not-at-top
  except Exception as e:  # pylint: disable=broad-except
    return None, f'mujoco_playground cannot be imported: {e!r}'
  env = registry.load('HumanoidWalk', config_overrides={'impl': 'jax'})
  try:
    version = importlib.metadata.version('playground')
  except importlib.metadata.PackageNotFoundError:
    version = getattr(mujoco_playground, '__version__', 'unknown')
  return env, f'playground {version}'


def _playground_trained(env, episode_length):
  """`env` wrapped as Playground's PPO trains it (batched reset and step)."""
  from mujoco_playground import wrapper  # pylint: disable=g-import-not-at-top

  return wrapper.wrap_for_brax_training(
      env, episode_length=episode_length, action_repeat=1
  )


def _scan_rollout(step, steps, batched=False):
  """`rollout(state, actions)`: `steps` of `vmap(step)`, actions held.

  With `batched`, `step` already takes a batch (not vmapped again).
  """
  batched = step if batched else jax.vmap(step)

  def rollout(state, actions):
    def body(s, _):
      return batched(s, actions), None

    return jax.lax.scan(body, state, None, length=steps)[0], actions

  return rollout


def _ratios(row, ours):
  """Adds `<ours>/<other>` throughput ratios for what `row` holds."""
  for name in ours:
    for other in ('raw', 'playground', 'playground_trained'):
      if name in row and other in row:
        row[f'{name}/{other}'] = (
            row[name]['control_steps_per_s'] / row[other]['control_steps_per_s']
        )


def _isolated_row(args, worlds, name):
  """One program at `worlds` measured by this script in a fresh process."""
  with tempfile.TemporaryDirectory() as tmp:
    out = os.path.join(tmp, 'row.json')
    cmd = [
        sys.executable,
        os.path.abspath(__file__),
        '--worlds',
        str(worlds),
        '--programs',
        name,
        '--steps',
        str(args.steps),
        '--repeats',
        str(args.repeats),
        '--out',
        out,
    ]
    if args.share_reset_forward is not None:
      cmd += ['--share-reset-forward', args.share_reset_forward]
    if subprocess.run(cmd, check=False).returncode:
      return None, None
    with open(out) as f:
      payload = json.load(f)
  return payload['results'][0].get(name), payload


def _main_isolated(args, names):
  """`--isolated`: every (worlds, program) in its own process, or in
  `args.processes` of them, the programs taking turns (`_merged`).

  This process never starts JAX's backend: on a GPU it would hold the
  memory the workers need.
  """
  processes = args.processes
  ours = [n for n in names if n not in _OTHERS]
  results, settings = [], {}
  for worlds in args.worlds:
    row = {'worlds': worlds}
    results.append(row)
    samples = {}
    for _ in range(processes):
      for name in names:
        measured, payload = _isolated_row(args, worlds, name)
        if measured is None:
          print(f'{worlds:>6} worlds: {name} failed (its output says why)')
          continue
        samples.setdefault(name, []).append(measured)
        row[name] = _merged(samples[name]) if processes > 1 else measured
        settings = {k: v for k, v in payload.items() if k != 'results'}
        _ratios(row, ours)
        if processes > 1:
          _first_call_ratios(row, ours)
        common.write_json(
            args.out,
            {
                **settings,
                'isolated': True,
                'processes': processes,
                'results': results,
            },
        )
    print(
        '        '
        + ', '.join(f'{k} {v:.3f}' for k, v in row.items() if '/' in k)
    )
  print(f'Wrote {args.out}')


# The first call's figures: a program's own (reset compile) and its
# rollout's (compile and first run).
_FIRST_CALLS = ('reset_compile_s', 'rollout_compile_s', 'first_call_s')


def _merged(rows):
  """One program's rows from several processes as one: each numeric
  figure's median, `processes`, and the first calls' samples
  (`first_calls_s`: reset compile plus the rollout's first call)."""
  merged = {}
  for key, value in rows[0].items():
    values = [r.get(key) for r in rows]
    numeric = all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in values
    )
    merged[key] = float(np.median(values)) if numeric else value
  merged['processes'] = len(rows)
  merged['samples'] = {
      key: [r[key] for r in rows] for key in _FIRST_CALLS if key in rows[0]
  }
  merged['samples']['first_calls_s'] = [
      r['reset_compile_s'] + r['first_call_s'] for r in rows
  ]
  merged['first_calls_s'] = float(np.median(merged['samples']['first_calls_s']))
  return merged


def _first_call_ratios(row, ours):
  """Adds `<ours>/<other> first calls`: the ratios of the first calls'
  medians (`_merged`)."""
  for name in ours:
    for other in _OTHERS:
      if name in row and other in row:
        row[f'{name}/{other} first calls'] = (
            row[name]['first_calls_s'] / row[other]['first_calls_s']
        )


# Programs that are not ours: the references ours' ratios divide by.
_OTHERS = ('playground', 'playground_trained', 'raw')


def main():
  parser = common.make_parser(
      __doc__,
      worlds=[1024, 8192, 32768],
      repeats=3,
      out='playground_compare.json',
  )
  parser.add_argument(
      '--steps', type=int, default=100, help='control steps per timed call'
  )
  parser.add_argument(
      '--programs',
      nargs='+',
      default=None,
      type=program_name,
      help='measure only these (default: ours_on, ours_off, playground, '
      'raw); only_<feature>[+<feature>...] is ours_off with those features '
      'of ours_on: ' + ', '.join((*FEATURES, 'groups')),
  )
  parser.add_argument(
      '--isolated',
      action='store_true',
      help='measure each program at each number of worlds in a fresh '
      'process (fair first calls: no program profits from compiles before '
      'it; the ratios then divide numbers from different processes)',
  )
  parser.add_argument(
      '--processes',
      type=int,
      default=1,
      metavar='K',
      help='with --isolated: measure each program in K fresh processes, '
      'the programs taking turns, and record the medians and the first '
      "calls' samples",
  )
  common.add_share_reset_forward_arg(parser)  # ours_on_chunk<K> needs off
  args = parser.parse_args()
  names = args.programs or ('ours_on', 'ours_off', 'playground', 'raw')
  if args.processes < 1:
    parser.error('--processes must be at least 1')
  if args.processes > 1 and not args.isolated:
    parser.error('--processes needs --isolated (one process each)')
  if args.isolated:
    return _main_isolated(args, names)

  # As our scripts compile (see the module docstring), before compiling.
  platform.configure(compilation_cache=False)
  device = common.print_device()
  # The backend's one-time start-up, so the first program measured does not
  # pay it in its first call.
  jax.block_until_ready(jax.jit(lambda x: x + 1)(np.float32(0)))
  envs = env_variants(
      [*names, 'ours_off'],
      share_reset_forward=common.share_reset_forward(args),
  )
  n = envs['ours_off'].n_sub_steps
  playground, playground_info = _playground_env()
  if playground is None:
    print(f'Skipping the playground column: {playground_info}')
  else:
    print(f'{playground_info}: HumanoidWalk, impl=jax')
  raw_model = envs['ours_off'].mjx_model

  results = []
  for worlds in args.worlds:
    keys = jax.random.split(jax.random.key(0), worlds)
    actions = common.random_actions(envs['ours_off'], worlds)
    row = {'worlds': worlds}
    results.append(row)
    programs = {
        name: (jax.vmap(env.reset), _scan_rollout(env.step, args.steps), keys)
        for name, env in envs.items()
    }
    if playground is not None:
      programs['playground'] = (
          jax.vmap(playground.reset),
          _scan_rollout(playground.step, args.steps),
          jax.random.split(jax.random.PRNGKey(0), worlds),
      )
      trained = _playground_trained(playground, envs['ours_off'].step_limit)
      programs['playground_trained'] = (
          trained.reset,
          _scan_rollout(trained.step, args.steps, batched=True),
          jax.random.split(jax.random.PRNGKey(0), worlds),
      )
    programs['raw'] = (
        common.raw_reset(raw_model, jit=False),
        common.raw_rollout(raw_model, n, args.steps, jit=False),
        keys,
    )
    programs = {k: v for k, v in programs.items() if k in names}
    for name, (reset, rollout, reset_keys) in programs.items():
      row[name] = measure(
          reset, rollout, reset_keys, actions, args.repeats, device
      )
      row[name]['control_steps_per_s'] = (
          worlds * args.steps / row[name]['seconds_per_call']
      )
      if name in envs:  # whether its restart restores the first state
        row[name]['stored_restart'] = envs[name].stored_restart
      print(
          f'{worlds:>6} worlds: {name} '
          f'{row[name]["control_steps_per_s"]:,.0f} control steps/s, '
          f'first call {row[name]["first_call_s"]:.1f} s',
          flush=True,
      )
      _ratios(row, envs)
      # Written after every program: a run cut short keeps what it measured
      # (each program compiles for tens of seconds on a GPU).
      common.write_results(
          args.out,
          device,
          results,
          task='walk',
          steps_per_call=args.steps,
          sub_steps=n,
          repeats=args.repeats,
          playground=playground_info,
          share_reset_forward=envs['ours_off'].share_reset_forward,
          threefry_gpu_kernel=prng_lowering.is_enabled(),
          note=(
              'Every variant holds one random action per world. ours_on '
              'resets worlds whose humanoid falls (head below 0.8 m), with '
              'randomization; the others never reset within a call.'
          ),
      )
    print(
        '        '
        + ', '.join(f'{k} {v:.3f}' for k, v in row.items() if '/' in k)
    )

  print(f'Wrote {args.out}')


if __name__ == '__main__':
  main()
