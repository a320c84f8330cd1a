"""Where a composed step program's device time goes, kernel by kernel.

For one bundled task and number of worlds, this profiles (`jax.profiler`,
a Perfetto trace) one call of `--steps` control steps of:

* raw:       raw MJX on the task's compiled model (`common.raw_rollout`),
             from the composed environment's reset states;
* composed:  `vmap(env.step)` of the task (`common.env_rollout`);
* each variant named with `--variants`: `no_ends` (no time limit),
  `no_obs` (no time limit, every observable disabled), `shared`
  (`share_reset_forward=True`), `unshared` (False), `on` (walk with every
  feature on, as `playground_compare.py`'s ours_on), `on_shared` (`on`
  with `share_reset_forward=True`), and for walk `playground_compare.py`'s
  `only_<features>` programs (e.g. `only_noise+delay+history+randomize+groups`,
  with its suffixes such as `_shared`);
* with `--reset NAME` (`composed` or a variant), that environment's batched
  reset, `vmap(env.reset)` from fresh keys (reported per call, as one
  'control step'): what the same-step auto-reset adds to a step in which
  some world's episode ends.

`--impl warp` builds every environment on MuJoCo Warp, so raw is MuJoCo
Warp's step on the same model (`base.mjx_model`, put with 'warp').

Every kernel's device time is attributed to the innermost scope of the JAX
name stack it came from that names a piece of the program (an MJX function
such as `collision` or `solve`, or one of ours such as `updater`), and the
table compares the scopes' totals per control step between each program and
raw. A kernel is traced with the HLO instruction it ran, or, where it ran in
a CUDA graph (XLA's command buffers), with the buffer: it is then found by its
own name, the instruction's (`_instruction`); kernels that no instruction
names (the graph's copies) count as '(none)'. The kernels outside every
named scope ('(none)': the graphs' copies, XLA's copies of loops' carries)
are also told apart by their names without numbers (`memcpy#_post`).
Walk defaults to `walk.PLAYGROUND_EQUIVALENT` (noise, delay, history,
randomization, pushes and fall terminations off, the 'policy' group
only), the configuration `playground_compare.py` calls ours_off.

    python benchmarks/profile_step.py --task walk --worlds 8192

Each program's unprofiled call is timed too (`wall_us_per_control_step`):
wall-clock time minus the kernels' device time is what the device spends
between kernels (launches, host round trips of data-dependent loops).

The traces are left in `--trace-dir` (open them in Perfetto); the per-scope
totals go to `--out`.
"""

import collections
import os
import re
import tempfile
import time

import jax

from mjx_composer.runtime import transitions

import common  # benchmarks/common.py


def _make_envs(task, variants, impl='jax'):
  """`{name: Environment}` for the composed programs to profile."""
  kwargs = {}
  if task == 'walk':
    from mjx_composer.suite.tasks import walk  # pylint: disable=g-import-not-at-top

    kwargs = dict(walk.PLAYGROUND_EQUIVALENT, time_limit=walk.EPISODE_SECONDS)
  elif task == 'reach':
    kwargs = dict(randomize=False)
  kwargs['impl'] = impl
  envs = {'composed': common.make_env(task, **kwargs)}
  inf = float('inf')
  for name in variants:
    if name == 'no_ends':
      envs[name] = common.make_env(task, **{**kwargs, 'time_limit': inf})
    elif name == 'no_obs':
      envs[name] = common.make_env(
          task, **{**kwargs, 'time_limit': inf}, observables=False
      )
    elif name in ('on', 'on_shared'):
      if task != 'walk':
        raise ValueError(f"The '{name}' variant is the walk task's.")
      envs[name] = common.make_env(
          task,
          impl=impl,
          time_limit=kwargs['time_limit'],
          **({'share_reset_forward': True} if name == 'on_shared' else {}),
      )
    elif name in ('shared', 'unshared'):
      envs[name] = common.make_env(
          task, **kwargs, share_reset_forward=name == 'shared'
      )
    elif name.startswith('only_') and task == 'walk':
      import playground_compare  # pylint: disable=g-import-not-at-top

      name = playground_compare.program_name(name)
      envs[name] = playground_compare.env_variants([name], impl=impl)[name]
    else:
      raise ValueError(f'Unknown variant {name!r}.')
  return envs


# Name-stack components that say nothing about which piece of the program
# ran: transformations, control flow and the benchmark's own functions.
_GENERIC = frozenset(
    (
        'jit',
        'vmap',
        'while',
        'body',
        'cond',
        'branch',
        'scan',
        'checkpoint',
        'remat',
        'pjit',
        'custom_vmap',
        'custom_jvp',
        'jvp',
        'transpose',
        'closed_call',
        'core_call',
        'rollout',
        'control_step',
        '<lambda>',
        'run',
        'one_world',
        'select',
        'fori_loop',
        'while_loop',
        'reset_program',
        'eval_jaxpr',
    )
)


def _scope(op_name, depth=2):
  """The outermost and the innermost `depth` informative scopes of an op.

  `('forward', 'fwd_position/collision')` for an op of MJX's collision
  detection inside `mjx.forward`: the outermost says which piece of the
  step, the innermost which part of it.
  """
  names = []
  # The last component is the primitive itself (`add`, `dot_general`).
  for part in op_name.split('/')[:-1]:
    # `vmap(observation_update)`: a transformation around a named scope.
    for piece in re.findall(r'[^()]+', part):
      piece = piece.strip()
      if piece and piece not in _GENERIC and not piece.isdigit():
        names.append(piece)
  if not names:
    return '(none)', '(none)'
  return names[0], '/'.join(names[-depth:])


def _op_names(hlo_text):
  """`{HLO instruction name: JAX op_name}` of a compiled program's text."""
  pattern = (
      r'^\s*(?:ROOT\s+)?%?([\w.\-]+) = .*?metadata=\{[^}]*op_name="([^"]*)"'
  )
  return dict(re.findall(pattern, hlo_text, re.M))


def _instruction(event, op_names):
  """The HLO instruction a kernel event ran: its `hlo_op`, or for a kernel
  that ran in a CUDA graph (whose `hlo_op` names the command buffer,
  'command_buffer_12'), the instruction the kernel is named after
  ('loop_add_fusion_2' for 'loop_add_fusion.2'); None for an event that
  names no instruction."""
  op = event.get('args', {}).get('hlo_op')
  if op is None or op in op_names:
    return op
  name = event.get('name', '')
  for candidate in (name, re.sub(r'_(\d+)$', r'.\1', name)):
    if candidate in op_names:
      return candidate
  return op


def _kernel_kind(name):
  """A kernel's name without its numbers: 'memcpy#_post' for a CUDA
  graph's copy 'memcpy32_post', 'loop_add_fusion_#' for 'loop_add_fusion_2'."""
  return re.sub(r'\d+', '#', name)


def _kernel_times(trace_dir, op_names):
  """Device microseconds per outer and inner scope; kernels per inner scope;
  and of the kernels outside every named scope ('(none)'), microseconds and
  kernels per kind (`_kernel_kind`): e.g. the copies of loops' carries."""
  events = common.perfetto_events(trace_dir)
  process = common.metadata_names(events, 'process_name')
  # Kernels run on the accelerator's rows; on a CPU the host runs them.
  accelerator = {p for p, n in process.items() if '/device:' in n}
  rows = accelerator or set(process)
  outer, inner = collections.Counter(), collections.Counter()
  kernels = collections.Counter()
  unnamed_us, unnamed = collections.Counter(), collections.Counter()
  for e in events:
    if e.get('ph') != 'X' or e.get('pid') not in rows:
      continue
    op = _instruction(e, op_names)
    if op is None:
      continue
    first, last = _scope(op_names.get(op, op))
    outer[first] += float(e.get('dur', 0))
    inner[last] += float(e.get('dur', 0))
    kernels[last] += 1
    if first == '(none)':
      kind = _kernel_kind(e.get('name', ''))
      unnamed_us[kind] += float(e.get('dur', 0))
      unnamed[kind] += 1
  return dict(outer), dict(inner), dict(kernels), (unnamed_us, unnamed)


def _profile(fn, args, trace_dir):
  """Compiles `fn`, times its third call, then profiles its fourth.

  `fn` returns its own next arguments. Returns the kernel times by scope
  (`_kernel_times`) and the unprofiled call's wall-clock seconds: their
  difference is the time the device spends between kernels.
  """
  compiled = jax.jit(fn).lower(*args).compile()
  out = jax.block_until_ready(compiled(*args))
  out = jax.block_until_ready(compiled(*out))
  start = time.perf_counter()
  out = jax.block_until_ready(compiled(*out))
  wall = time.perf_counter() - start
  with jax.profiler.trace(trace_dir, create_perfetto_trace=True):
    jax.block_until_ready(compiled(*out))
  return (*_kernel_times(trace_dir, _op_names(compiled.as_text())), wall)


def main():
  parser = common.make_parser(__doc__, worlds=[8192], out='profile_step.json')
  parser.add_argument('--task', default='walk', choices=common.TASKS)
  parser.add_argument('--steps', type=int, default=20)
  parser.add_argument(
      '--variants', nargs='*', default=['no_ends', 'no_obs'], help='see above'
  )
  parser.add_argument(
      '--reset',
      default=None,
      help="also profile this environment's batched reset ('composed' or a "
      'variant)',
  )
  parser.add_argument(
      '--reset-only',
      action='store_true',
      help='profile only the reset named by --reset, no step program',
  )
  parser.add_argument('--trace-dir', default=None)
  parser.add_argument(
      '--impl',
      default='jax',
      choices=('jax', 'warp'),
      help="the physics implementation of every program (raw too); 'warp' "
      "refuses the 'shared' variant",
  )
  args = parser.parse_args()
  device = common.print_device()
  trace_root = args.trace_dir or tempfile.mkdtemp(prefix='profile_step_')

  envs = _make_envs(args.task, args.variants, args.impl)
  base = envs['composed']
  worlds = args.worlds[0]
  keys = jax.random.split(jax.random.key(0), worlds)
  actions = common.random_actions(base, worlds)
  programs = {}
  if args.reset_only and args.reset is None:
    parser.error('--reset-only needs --reset')
  if not args.reset_only:
    states = jax.jit(jax.vmap(base.reset))(keys)
    programs['raw'] = (
        common.raw_rollout(
            base.mjx_model, base.n_sub_steps, args.steps, jit=False
        ),
        (states.data, actions),
    )
    for name, env in envs.items():
      states = jax.jit(jax.vmap(env.reset))(keys)
      programs[name] = (
          common.env_rollout(env, args.steps, jit=False),
          (states, actions),
      )

  if args.reset is not None:
    reset = jax.vmap(envs[args.reset].reset)

    def reset_program(keys, _):
      # The next call's keys come from the states, so that nothing of the
      # reset is left out of the program.
      states = reset(keys)
      return jax.vmap(lambda k: jax.random.split(k)[0])(states.key), states

    # The second argument only gives the program its output's shapes.
    programs['reset'] = (
        reset_program,
        (
            keys,
            jax.tree.map(
                # Zeros of each shape, PRNG keys too.
                transitions._zeros_like_shape,  # pylint: disable=protected-access
                jax.eval_shape(reset, keys),
            ),
        ),
    )

  results = {}
  for name, (fn, fn_args) in programs.items():
    outer, inner, kernels, (unnamed_us, unnamed), wall = _profile(
        fn, fn_args, os.path.join(trace_root, name)
    )
    calls = 1 if name == 'reset' else args.steps
    per_step = lambda totals, calls=calls: {
        k: v / calls for k, v in sorted(totals.items())
    }
    results[name] = {
        'kernels': sum(kernels.values()),
        'kernels_per_control_step': per_step(kernels),
        'total_us_per_control_step': sum(outer.values()) / calls,
        'wall_us_per_control_step': wall * 1e6 / calls,
        'outer_us_per_control_step': per_step(outer),
        'inner_us_per_control_step': per_step(inner),
        # The kinds of kernels outside every named scope, slowest first.
        'unnamed_us_per_control_step': {
            k: v / calls for k, v in unnamed_us.most_common()
        },
        'unnamed_kernels_per_control_step': {
            k: unnamed[k] / calls for k, _ in unnamed_us.most_common()
        },
    }
    print(
        f'{name}: {results[name]["kernels"]} kernels, '
        f'{results[name]["total_us_per_control_step"]:,.0f} us of device time '
        f'and {results[name]["wall_us_per_control_step"]:,.0f} us of wall-clock '
        'time per control step',
        flush=True,
    )
    common.write_results(
        args.out,
        device,
        [results],
        task=args.task,
        worlds=worlds,
        steps=args.steps,
        trace_dir=trace_root,
    )

  names = list(results)
  for key, rows in (
      ('kernels_per_control_step', 25),
      ('outer_us_per_control_step', 12),
      ('inner_us_per_control_step', 40),
      ('unnamed_us_per_control_step', 8),
      ('unnamed_kernels_per_control_step', 8),
  ):
    level = key.replace('_per_control_step', '').replace('_', ' ')
    scopes = sorted(
        {s for r in results.values() for s in r[key]},
        key=lambda s, key=key: -max(
            r[key].get(s, 0.0) for r in results.values()
        ),
    )
    print(f'\n| {level} (per control step) | ' + ' | '.join(names) + ' |')
    print('|---|' + '---|' * len(names))
    print(
        '| total | '
        + ' | '.join(f'{sum(results[n][key].values()):,.0f}' for n in names)
        + ' |'
    )
    for s in scopes[:rows]:
      print(
          f'| {s} | '
          + ' | '.join(f'{results[n][key].get(s, 0.0):,.0f}' for n in names)
          + ' |'
      )
  print(f'Traces in {trace_root}; wrote {args.out}')


if __name__ == '__main__':
  main()
