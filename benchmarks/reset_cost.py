"""What a batched reset with `PropPlacer` costs, against resets without it.

The bundled push task (the arm, 5 free boxes, a target zone, walls) is built
four times, differing only in how the boxes start an episode:

* placer:     `PropPlacer` rejection sampling, no box starts in collision;
* ring:       the built ring of boxes turned by a random angle, random
              headings: random and collision-free by construction, no
              placer. This is the baseline: same work per world otherwise;
* unchecked:  the placer's distributions, first sample taken, boxes may
              overlap (`ignore_collisions=True`); the forward pass then
              solves for the overlapping boxes' contacts, which costs more
              than placing them properly;
* fixed:      the built ring in every world. Its worlds are identical, so
              XLA computes most of the reset once for all of them: a lower
              bound, not a fair baseline.

For each number of worlds it times `jax.jit(jax.vmap(env.reset))` (median of
`--repeats` calls, each with fresh keys, after a warm-up call), and the
placer on its own (`jax.vmap(placer)` from one reset state, i.e. without the
forward passes every reset makes).

    python benchmarks/reset_cost.py --worlds 8192

Results go to stdout as a table and, as JSON, to `--out` (default
`$OUT/reset_cost.json`, or `./reset_cost.json` when `OUT` is unset).
"""

import jax
import jax.numpy as jnp

import common  # benchmarks/common.py

_PLACEMENTS = ('placer', 'ring', 'unchecked', 'fixed')


def build(placement, max_reset_attempts):
  return common.make_env(
      'push',
      time_limit=2.0,
      max_reset_attempts=max_reset_attempts,
      num_boxes=5,
      placement=placement,
  )


def main():
  parser = common.make_parser(__doc__, worlds=[8192], repeats=5)
  parser.add_argument(
      '--max-reset-attempts',
      type=int,
      default=1,
      help='Environment(max_reset_attempts=...); above 1 the '
      'reset also holds the retry loop (compiled twice)',
  )
  parser.add_argument(
      '--placements',
      nargs='+',
      default=list(_PLACEMENTS),
      choices=_PLACEMENTS,
      help='which variants to time (default: all)',
  )
  common.add_out_arg(parser, 'reset_cost.json')
  args = parser.parse_args()

  device = common.print_device()
  envs = {
      name: build(name, args.max_reset_attempts) for name in args.placements
  }
  resets = {name: jax.jit(jax.vmap(env.reset)) for name, env in envs.items()}
  results = []
  for worlds in args.worlds:
    row, placer_states = {'worlds': worlds}, None

    def keys(i, worlds=worlds):
      return (jax.random.split(jax.random.key(1000 + i), worlds),)

    for name in args.placements:
      compile_s, seconds = common.time_calls(resets[name], keys, args.repeats)
      row[f'{name}_s'] = seconds
      row[f'{name}_first_call_s'] = compile_s
      if name == 'placer':
        states = placer_states = resets[name](keys(0)[0])
        row['init_failures_mean'] = float(
            jnp.mean(states.metrics['init_failures'])
        )
        row['init_failed'] = int(jnp.sum(states.metrics['init_failed']))
      print(
          f'{worlds:>7} worlds: reset {name:<9} {seconds * 1e3:9.2f} ms '
          f'(first call {compile_s:.1f} s)',
          flush=True,
      )

    results.append(row)
    if 'placer' not in envs:
      continue
    # The placer alone, from one world's reset state (public API only).
    env = envs['placer']
    physics = env.physics(jax.tree.map(lambda x: x[0], placer_states))
    placer = env.task.placer
    place = jax.jit(jax.vmap(lambda k: placer(physics, k).data.qpos))
    compile_s, seconds = common.time_calls(place, keys, args.repeats)
    row['placer_only_s'] = seconds
    row['placer_only_first_call_s'] = compile_s
    print(
        f'{worlds:>7} worlds: placer alone  {seconds * 1e3:9.2f} ms '
        f'(first call {compile_s:.1f} s)',
        flush=True,
    )

  common.write_json(
      args.out,
      {
          'device': device.device_kind,
          'platform': device.platform,
          'jax': jax.__version__,
          'props': 5,
          'max_reset_attempts': args.max_reset_attempts,
          'repeats': args.repeats,
          'results': results,
      },
  )

  def ms(row, name):
    return f'{row[name] * 1e3:.1f} ms' if name in row else '-'

  print(
      '\n| worlds | reset, PropPlacer (5 props) | reset, ring (baseline) | '
      'placer / ring | placer alone | unchecked | fixed | failed '
      'initializations |'
  )
  print('|---|---|---|---|---|---|---|---|')
  for r in results:
    ratio = (
        f'{r["placer_s"] / r["ring_s"]:.2f}'
        if 'placer_s' in r and 'ring_s' in r
        else '-'
    )
    failures = (
        f'{r["init_failures_mean"]:.2g} per world'
        if 'init_failures_mean' in r
        else '-'
    )
    print(
        f'| {r["worlds"]:,} | {ms(r, "placer_s")} | {ms(r, "ring_s")} | '
        f'{ratio} | {ms(r, "placer_only_s")} | {ms(r, "unchecked_s")} | '
        f'{ms(r, "fixed_s")} | {failures} |'
    )
  print(f'\nJSON: {args.out}')


if __name__ == '__main__':
  main()
