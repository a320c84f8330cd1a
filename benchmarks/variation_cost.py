"""Cost of per-episode domain randomization, against the same env without it.

Builds the bundled reach task twice, identical except for `randomize`: with
it, every reset resamples (per world) the colours of all arm links and the
ball, the arm links' densities, the ball's radius, mass and friction, the
floor's friction and the arm's motor gears, and recomputes every quantity
MuJoCo's compiler derives from them (inertias, `body_subtreemass`,
`geom_rbound`/`geom_aabb`, `mj_setConst`'s `invweight0`/`acc0`/`M0`, model
statistics). Episodes last `--episode-steps` control steps and every call
runs `--steps` control steps with same-step auto-reset, so the randomized
resets are paid inside the timed loop, as in training.

Reported per number of worlds: physics steps per second of both variants
(median of `--repeats` calls), their ratio, the time of one batched reset of
each, and raw `jax.vmap(mjx.step)` on the same model for scale.

    python benchmarks/variation_cost.py --worlds 8192
"""

import jax

import common  # benchmarks/common.py


def build(randomize: bool, episode_steps: int):
  return common.make_env(
      'reach', episode_steps=episode_steps, randomize=randomize
  )


def main():
  parser = common.make_parser(__doc__, worlds=[8192])
  parser.add_argument('--episode-steps', type=int, default=100)
  parser.add_argument(
      '--steps', type=int, default=300, help='control steps per timed call'
  )
  common.add_repeats_arg(parser, 3)
  common.add_out_arg(parser, 'variation_cost.json')
  args = parser.parse_args()

  device = common.print_device()
  envs = {
      'randomized': build(True, args.episode_steps),
      'fixed': build(False, args.episode_steps),
  }
  base = envs['fixed']
  n = base.n_sub_steps
  results = []
  for worlds in args.worlds:
    row = {'worlds': worlds}
    keys = jax.random.split(jax.random.key(0), worlds)
    actions = common.random_actions(base, worlds)
    data = common.raw_data(base.mjx_model, worlds)
    seconds = common.time_fn(
        common.raw_rollout(base.mjx_model, n, args.steps),
        (data, actions),
        args.repeats,
    )
    row['raw'] = worlds * args.steps * n / seconds
    for name, env in envs.items():
      reset = jax.jit(jax.vmap(env.reset))
      # Median of `--repeats` batched resets, after compiling it.
      _, row[f'{name}_reset_s'] = common.time_calls(
          reset, lambda _, keys=keys: (keys,), args.repeats
      )
      states = reset(keys)
      seconds = common.time_fn(
          common.env_rollout(env, args.steps),
          (states, actions),
          args.repeats,
      )
      row[name] = worlds * args.steps * n / seconds
    row['ratio'] = row['randomized'] / row['fixed']
    results.append(row)
    print(
        f'{worlds:>7} worlds: randomized {row["randomized"]:,.0f}  fixed '
        f'{row["fixed"]:,.0f} physics steps/s (ratio {row["ratio"]:.3f}); '
        f'reset {row["randomized_reset_s"] * 1e3:.1f} ms vs '
        f'{row["fixed_reset_s"] * 1e3:.1f} ms',
        flush=True,
    )

  common.write_results(
      args.out,
      device,
      results,
      n_sub_steps=n,
      episode_steps=args.episode_steps,
      steps_per_call=args.steps,
  )
  print(
      '\n| worlds | raw MJX | fixed | randomized | randomized / fixed '
      '| reset fixed | reset randomized |'
  )
  print('|---|---|---|---|---|---|---|')
  for r in results:
    print(
        f'| {r["worlds"]:,} | {r["raw"] / 1e6:.2f} M | '
        f'{r["fixed"] / 1e6:.2f} M | {r["randomized"] / 1e6:.2f} M | '
        f'{r["ratio"]:.3f} | {r["fixed_reset_s"] * 1e3:.1f} ms | '
        f'{r["randomized_reset_s"] * 1e3:.1f} ms |'
    )


if __name__ == '__main__':
  main()
