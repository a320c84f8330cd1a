"""How often episodes end under held random actions, and what a reset costs.

The throughput benchmarks step every world with one random action held for
the whole rollout (`common.random_actions`). Where the task ends episodes
early (the walk task's falls), the batched same-step auto-reset computes the
reset of the whole batch whenever any world is done, so the fraction of
worlds that end an episode at each control step decides how often a timed
step pays for a reset. This script counts them, for one bundled task as the
benchmarks build it:

    python benchmarks/episode_ends.py --task walk --worlds 64 --steps 200

It prints the fraction of world-steps that ended an episode (all steps, and
the second half, after the synchronized start has mixed), the median step of
each world's first end, and the probability that at least one world of a
batch of `--batch` worlds ends at a given step, were worlds independent.
With `--time`, also the seconds of one batched reset (`vmap(env.reset)`, fresh
keys each call) and of one batched control step (`vmap(env.step)`), medians
of `--repeats` calls: what a step in which some world is done pays extra.
"""

import importlib

import jax
import numpy as np

import common  # benchmarks/common.py


def main():
  parser = common.make_parser(__doc__, worlds=[64], out='episode_ends.json')
  parser.add_argument('--task', default='walk', choices=common.TASKS)
  parser.add_argument('--steps', type=int, default=200)
  parser.add_argument(
      '--time-limit',
      type=float,
      default=None,
      help="episode seconds (default: the task's EPISODE_SECONDS where it "
      "has one, as playground_compare.py times walk; else throughput.py's 2)",
  )
  parser.add_argument(
      '--batch',
      type=int,
      nargs='+',
      default=[1024, 8192, 32768],
      help='batch sizes to extrapolate P(some world ends) to',
  )
  parser.add_argument(
      '--time',
      action='store_true',
      help='also time one batched reset and one batched step',
  )
  common.add_repeats_arg(parser, 5)
  args = parser.parse_args()
  device = common.print_device()
  time_limit = args.time_limit
  if time_limit is None:
    module = importlib.import_module(f'mjx_composer.tasks.{args.task}')
    time_limit = getattr(module, 'EPISODE_SECONDS', 2.0)
  env = common.make_env(args.task, time_limit=time_limit)
  results = []
  for worlds in args.worlds:
    actions = common.random_actions(env, worlds)
    states = jax.jit(jax.vmap(env.reset))(
        jax.random.split(jax.random.key(0), worlds)
    )

    def body(states, _):
      states = jax.vmap(env.step)(states, actions)
      return states, states.last()

    rollout = jax.jit(
        lambda s: jax.lax.scan(body, s, None, length=args.steps)[1]
    )
    last = np.asarray(rollout(states))
    ended = last.any(axis=0)
    second_half = float(last[args.steps // 2 :].mean())
    row = {
        'worlds': worlds,
        'ends_per_world_step': float(last.mean()),
        'ends_per_world_step_second_half': second_half,
        'median_first_end_step': (
            float(np.median(np.argmax(last[:, ended], axis=0)) + 1)
            if ended.any()
            else None
        ),
        'worlds_never_ending': int((~ended).sum()),
        'p_some_world_ends': {
            str(b): 1.0 - (1.0 - second_half) ** b for b in args.batch
        },
    }
    if args.time:
      reset = jax.jit(jax.vmap(env.reset))
      step = jax.jit(jax.vmap(env.step))
      row['reset_s'] = common.time_calls(
          reset,
          lambda i: (jax.random.split(jax.random.key(i + 1), worlds),),
          args.repeats,
      )[1]
      # Steps from the reset states, every call from the same ones: where no
      # world ends in it (`step_worlds_done`, the first fall is steps away),
      # the step without a reset.
      row['step_s'] = common.time_calls(
          step, lambda i: (states, actions), args.repeats
      )[1]
      row['step_worlds_done'] = int(step(states, actions).last().sum())
    results.append(row)
    print(row, flush=True)
  common.write_results(
      args.out,
      device,
      results,
      task=args.task,
      steps=args.steps,
      time_limit=time_limit,
  )


if __name__ == '__main__':
  main()
