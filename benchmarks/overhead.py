"""Where the composed step's time goes, against raw MJX, in one run.

`throughput.py` gives the headline ratio; this separates its parts. For each
number of worlds it times, on the bundled reach task's compiled model with
its sub-steps (domain randomization off):

* raw:         `scan` over `vmap(mjx.step)`, sub-steps in a `fori_loop`,
               every world starting from the compiled model's `qpos0`;
* raw_reset:   the same program from the composed environment's reset
               states (the physics states a composed world steps from),
               each call continuing from the previous call's states;
* raw_episodes: the same program, each call starting afresh from new reset
               states (new keys): the physics of whole episodes, with the
               settling after every reset that `ends` holds once per call
               (the reach episodes last 100 control steps, the default
               `--steps`), without the reset's own cost;
* ends:        `vmap(env.step)`, episodes of 2 s with same-step auto-reset,
               every observable on (the configuration `throughput.py` times);
* no_ends:     the same with no time limit (no world ever resets);
* no_obs:      `no_ends` with every observable disabled;
* ends_unshared, no_ends_unshared: `ends` and `no_ends` with
               `share_reset_forward=False` (`mjx.step` in a `lax.scan`, the
               restart's forward pass separate; the default on a GPU);
* ends_shared, no_ends_shared: the same with `share_reset_forward=True`
               (the restart is an extra iteration of the sub-step loop; the
               default on a CPU).

Physics steps per second (control steps x sub-steps), median of `--repeats`
calls of `--steps` control steps, and each ratio to `raw` of the same run.

    python benchmarks/overhead.py --worlds 8192 32768
"""

import functools

import jax

import common  # benchmarks/common.py


def main():
  parser = common.make_parser(__doc__, worlds=[1024])
  parser.add_argument(
      '--steps', type=int, default=100, help='control steps per timed call'
  )
  parser.add_argument(
      '--programs',
      nargs='+',
      default=None,
      help="measure only these (and 'raw', which the ratios divide by)",
  )
  common.add_repeats_arg(parser, 3)
  common.add_out_arg(parser, 'overhead.json')
  args = parser.parse_args()

  device = common.print_device()
  endless = dict(time_limit=float('inf'))
  variants = {  # name: make_env arguments
      'ends': {},
      'no_ends': endless,
      'no_obs': dict(endless, observables=False),
  }
  # `ends` and `no_ends` with the restart outside the sub-step loop (a
  # second copy of the forward pass, `mjx.step` in a `lax.scan`), and in it.
  for suffix, share in (('unshared', False), ('shared', True)):
    for name in ('ends', 'no_ends'):
      variants[f'{name}_{suffix}'] = dict(
          variants[name], share_reset_forward=share
      )
  envs = {
      name: common.make_env('reach', randomize=False, **kwargs)
      for name, kwargs in variants.items()
      # Only the measured ones ('ends' sets the shapes and the actions).
      if name == 'ends' or not args.programs or name in args.programs
  }
  base = envs['ends']
  n = base.n_sub_steps
  results = []
  for worlds in args.worlds:
    row = {'worlds': worlds}
    actions = common.random_actions(base, worlds)
    keys = jax.random.split(jax.random.key(0), worlds)
    raw = common.raw_rollout(base.mjx_model, n, args.steps)

    def from_reset(env, rollout):
      states = jax.jit(jax.vmap(env.reset))(keys)
      return common.time_fn(rollout, (states, actions), args.repeats)

    batched_reset = jax.jit(jax.vmap(base.reset))

    def fresh_reset_data(i):
      return batched_reset(jax.random.split(jax.random.key(i + 1), worlds)).data

    programs = {
        'raw': lambda: common.time_fn(
            raw,
            (common.raw_data(base.mjx_model, worlds), actions),
            args.repeats,
        ),
        'raw_reset': lambda: common.time_fn(
            raw,
            (batched_reset(keys).data, actions),
            args.repeats,
        ),
        'raw_episodes': lambda: common.time_calls(
            raw, lambda i: (fresh_reset_data(i), actions), args.repeats
        )[1],
        **{
            name: functools.partial(
                from_reset, env, common.env_rollout(env, args.steps)
            )
            for name, env in envs.items()
        },
    }
    if args.programs:
      programs = {
          k: v for k, v in programs.items() if k == 'raw' or k in args.programs
      }
    results.append(row)
    for name, measure in programs.items():
      row[name] = worlds * args.steps * n / measure()
      print(f'{worlds:>7} worlds: {name} {row[name]:,.0f}', flush=True)
      # Written after every program: a run cut short keeps what it measured
      # (each program compiles for tens of seconds on a GPU).
      common.write_results(
          args.out, device, results, n_sub_steps=n, steps_per_call=args.steps
      )

  common.print_ratio_table(results)


if __name__ == '__main__':
  main()
