"""Throughput of the physics implementations, impl='jax' against impl='warp'.

For each bundled task, implementation (`ExecutionOptions(impl=...)`) and number
of worlds, on the task's compiled model:

* raw:      `scan` over `vmap(mjx.step)`, sub-steps in a `fori_loop`, from
            the composed environment's reset states (raw MJX on the same
            physics states, with the shared compiled model);
* composed: `vmap(env.step)` in a `scan`, episodes of `--time-limit`
            seconds with same-step auto-reset, every observable on.

Reported per program: control steps per second, physics steps per second
(control steps x sub-steps), median of `--repeats` calls of `--steps`
control steps, and the first call's seconds (tracing, compiling XLA's
program and, on 'warp', MuJoCo Warp's kernels unless its kernel cache
holds them). Both implementations run with `share_reset_forward=False`
(the restart separate from the sub-steps), the only choice on 'warp'.

On 'warp' the contact buffer holds `--contacts-per-world` contacts per
world (`naconmax`) and `--njmax` constraint rows per world (default:
`backend.default_njmax`); after the runs the row records MuJoCo Warp's
overflow flags (`backend.overflow`: a nonzero count means contacts or
constraints were dropped and the sizes must grow) and the most contacts in
use. A task
that 'warp' refuses (e.g. a per-world height field) records the refusal.

    python benchmarks/backends.py --worlds 8192 32768
    JAX_PLATFORMS=cpu python benchmarks/backends.py --tasks reach \\
        --worlds 4 --steps 2 --repeats 1

Results are written to `--out` after every row; a table is printed last.
"""

import time
import traceback

import jax
import jax.numpy as jnp

import common  # benchmarks/common.py
from mjx_composer.platform import backend


def _first_then_median(fn, args, repeats):
  """(first-call seconds, median seconds of later calls) of a rollout."""
  t0 = time.perf_counter()
  out = jax.block_until_ready(fn(*args))
  first = time.perf_counter() - t0
  return first, common.time_fn(fn, out, repeats), out


def _measure(task, impl, worlds, args):
  """One row: raw and composed throughput of `task` on `impl`."""
  kwargs = {'impl': impl, 'share_reset_forward': False}
  if impl == 'warp':
    kwargs['naconmax'] = args.contacts_per_world * worlds
    kwargs['njmax'] = args.njmax
  row = {'task': task, 'impl': impl, 'worlds': worlds}
  t0 = time.perf_counter()
  try:
    env = common.make_env(task, time_limit=args.time_limit, **kwargs)
  except (NotImplementedError, ValueError, ImportError) as e:
    row['refused'] = f'{type(e).__name__}: {e}'
    return row
  row['build_s'] = time.perf_counter() - t0
  n = env.n_sub_steps
  row['sub_steps'] = n
  keys = jax.random.split(jax.random.key(0), worlds)
  actions = common.random_actions(env, worlds)
  t0 = time.perf_counter()
  states = jax.block_until_ready(jax.jit(jax.vmap(env.reset))(keys))
  row['reset_first_call_s'] = time.perf_counter() - t0

  def rates(seconds):
    control = worlds * args.steps / seconds
    return {'control_steps_per_s': control, 'physics_steps_per_s': control * n}

  raw = common.raw_rollout(env.mjx_model, n, args.steps)
  first, seconds, (data, _) = _first_then_median(
      raw, (states.data, actions), args.repeats
  )
  row['raw'] = {'first_call_s': first, **rates(seconds)}
  composed = common.env_rollout(env, args.steps)
  first, seconds, (states, _) = _first_then_median(
      composed, (states, actions), args.repeats
  )
  row['composed'] = {'first_call_s': first, **rates(seconds)}
  if impl == 'warp':
    row['naconmax'] = backend.naconmax(states.data)
    row['njmax'] = backend.njmax(states.data)
    row['overflowed_worlds'] = {
        'raw': int(jnp.sum(backend.overflow(data) != 0)),
        'composed': int(jnp.sum(backend.overflow(states.data) != 0)),
    }
    row['contacts_in_use'] = {
        'raw': int(backend.contacts_in_use(data)),
        'composed': int(backend.contacts_in_use(states.data)),
    }
  return row


def _table(results):
  """The results as text: one line per task, implementation and worlds."""
  lines = [
      f'{"task":<10}{"impl":<6}{"worlds":>8}{"raw ctl/s":>13}'
      f'{"raw phys/s":>13}{"comp ctl/s":>13}{"comp phys/s":>13}'
      f'{"raw 1st s":>11}{"comp 1st s":>11}  note'
  ]
  for row in results:
    head = f'{row["task"]:<10}{row["impl"]:<6}{row["worlds"]:>8}'
    if 'refused' in row or 'error' in row:
      note = row.get('refused', row.get('error', ''))
      lines.append(f'{head}  {note.splitlines()[0][:100]}')
      continue
    raw, comp = row['raw'], row['composed']
    note = ''
    if 'overflowed_worlds' in row and any(row['overflowed_worlds'].values()):
      note = f'OVERFLOW {row["overflowed_worlds"]}'
    lines.append(
        f'{head}{raw["control_steps_per_s"]:>13.4g}'
        f'{raw["physics_steps_per_s"]:>13.4g}'
        f'{comp["control_steps_per_s"]:>13.4g}'
        f'{comp["physics_steps_per_s"]:>13.4g}'
        f'{raw["first_call_s"]:>11.1f}{comp["first_call_s"]:>11.1f}  {note}'
    )
  return '\n'.join(lines)


def main():
  parser = common.make_parser(__doc__, worlds=[8192, 32768])
  parser.add_argument(
      '--tasks', nargs='+', default=list(common.TASKS), choices=common.TASKS
  )
  parser.add_argument(
      '--impls', nargs='+', default=['jax', 'warp'], choices=backend.IMPLS
  )
  parser.add_argument(
      '--steps', type=int, default=50, help='control steps per timed call'
  )
  parser.add_argument(
      '--time-limit', type=float, default=2.0, help='episode seconds'
  )
  parser.add_argument(
      '--contacts-per-world',
      type=int,
      default=backend.DEFAULT_CONTACTS_PER_WORLD,
      help="'warp': naconmax = this x worlds",
  )
  parser.add_argument(
      '--njmax',
      type=int,
      default=None,
      help="'warp': constraint rows per world (default: backend.default_njmax)",
  )
  common.add_repeats_arg(parser, 3)
  common.add_out_arg(parser, 'backends.json')
  args = parser.parse_args()

  device = common.print_device()
  print(f'MuJoCo Warp installed: {backend.warp_installed()}')
  results = []
  for task in args.tasks:
    for worlds in args.worlds:
      for impl in args.impls:
        print(f'{task}, {impl}, {worlds} worlds ...', flush=True)
        try:
          row = _measure(task, impl, worlds, args)
        except Exception as e:  # pylint: disable=broad-except
          # One failing configuration (e.g. out of memory) keeps the rest.
          row = {
              'task': task,
              'impl': impl,
              'worlds': worlds,
              'error': f'{type(e).__name__}: {e}',
              'traceback': traceback.format_exc(),
          }
        print(_table([row]).splitlines()[1], flush=True)
        results.append(row)
        common.write_results(
            args.out,
            device,
            results,
            steps=args.steps,
            repeats=args.repeats,
            time_limit=args.time_limit,
            contacts_per_world=args.contacts_per_world,
            njmax=args.njmax,
            warp_installed=backend.warp_installed(),
        )
        jax.clear_caches()
  print()
  print(_table(results))
  print(f'written to {args.out}')


if __name__ == '__main__':
  main()
