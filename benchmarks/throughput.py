"""Throughput of a composed environment against raw MJX, in one run.

For each number of worlds it times, on the same compiled model and with the
same number of physics sub-steps per control step:

* raw:       `jax.lax.scan` over `jax.vmap(mjx.step)` (n sub-steps per step);
* composed:  `jax.vmap(env.step)` of the bundled reach task (domain
             randomization off: `variation_cost.py` measures that) with its
             full observation set (10 observables, 3 with noise, 2 buffered, a
             policy/critic split, flattened) and same-step auto-reset;
* no_obs:    the same environment with every observable disabled.

Each variant runs `--steps` control steps per jitted call; the median of
`--repeats` calls is reported as physics steps per second (control steps x
n_sub_steps), and the ratio to raw. Results go to stdout as a table and to
`--out` as JSON.

    python benchmarks/throughput.py --worlds 1024 8192 32768
"""

import jax

import common  # benchmarks/common.py


def build(observables: bool):
  # Domain randomization off: variation_cost.py measures it.
  return common.make_env('reach', observables=observables, randomize=False)


def main():
  parser = common.make_parser(__doc__, worlds=[1024])
  parser.add_argument(
      '--steps', type=int, default=100, help='control steps per timed call'
  )
  common.add_repeats_arg(parser, 3)
  common.add_out_arg(parser, 'throughput.json')
  args = parser.parse_args()

  device = common.print_device()
  envs = {'composed': build(True), 'no_obs': build(False)}
  base = envs['composed']
  n = base.n_sub_steps
  results = []
  for worlds in args.worlds:
    row = {'worlds': worlds}
    actions = common.random_actions(base, worlds)
    data = common.raw_data(base.mjx_model, worlds)
    seconds = common.time_fn(
        common.raw_rollout(base.mjx_model, n, args.steps),
        (data, actions),
        args.repeats,
    )
    row['raw'] = worlds * args.steps * n / seconds
    for name, env in envs.items():
      states = jax.jit(jax.vmap(env.reset))(
          jax.random.split(jax.random.key(0), worlds)
      )
      seconds = common.time_fn(
          common.env_rollout(env, args.steps), (states, actions), args.repeats
      )
      row[name] = worlds * args.steps * n / seconds
    results.append(row)
    print(
        f'{worlds:>7} worlds: raw {row["raw"]:,.0f}  composed '
        f'{row["composed"]:,.0f}  no_obs {row["no_obs"]:,.0f} physics '
        'steps/s',
        flush=True,
    )

  common.write_results(
      args.out,
      device,
      results,
      n_sub_steps=n,
      steps_per_call=args.steps,
  )
  print(
      '\n| worlds | raw MJX (physics steps/s) | composed | composed / raw '
      '| no observables | no_obs / raw | observation cost |'
  )
  print('|---|---|---|---|---|---|---|')
  for r in results:
    print(
        f'| {r["worlds"]:,} | {r["raw"] / 1e6:.2f} M | '
        f'{r["composed"] / 1e6:.2f} M | {r["composed"] / r["raw"]:.3f} | '
        f'{r["no_obs"] / 1e6:.2f} M | {r["no_obs"] / r["raw"]:.3f} | '
        f'{1 - r["composed"] / r["no_obs"]:+.1%} |'
    )


if __name__ == '__main__':
  main()
