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

import argparse
import json
import os
import statistics
import time

import jax
import jax.numpy as jnp
from mujoco import mjx

from mjx_composer import environment
from mjx_composer.tasks import reach
import throughput  # benchmarks/throughput.py: timing and rollout helpers


def build(randomize: bool, episode_steps: int):
  task = reach.Reach(randomize=randomize)
  return environment.Environment(
      task,
      time_limit=episode_steps * task.control_timestep,
      auto_reset='same_step',
      observation_groups=reach.Reach.observation_groups(),
  )


def time_reset(reset, keys, repeats):
  """Median seconds of one batched reset (after compiling it)."""
  jax.block_until_ready(reset(keys))
  times = []
  for _ in range(repeats):
    t0 = time.perf_counter()
    jax.block_until_ready(reset(keys))
    times.append(time.perf_counter() - t0)
  return statistics.median(times)


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--worlds', type=int, nargs='+', default=[8192])
  parser.add_argument('--episode-steps', type=int, default=100)
  parser.add_argument(
      '--steps', type=int, default=300, help='control steps per timed call'
  )
  parser.add_argument('--repeats', type=int, default=3)
  parser.add_argument(
      '--out',
      default=os.path.join(os.environ.get('OUT', '.'), 'variation_cost.json'),
  )
  args = parser.parse_args()

  device = jax.devices()[0]
  print(f'JAX {jax.__version__}, {device.platform}: {device.device_kind}')
  envs = {
      'randomized': build(True, args.episode_steps),
      'fixed': build(False, args.episode_steps),
  }
  base = envs['fixed']
  n = base.n_sub_steps
  spec = base.action_spec()
  results = []
  for worlds in args.worlds:
    row = {'worlds': worlds}
    keys = jax.random.split(jax.random.key(0), worlds)
    actions = jax.random.uniform(
        jax.random.key(1), (worlds,) + spec.shape, minval=-1.0, maxval=1.0
    )
    data = jax.vmap(lambda _: mjx.make_data(base.mjx_model))(jnp.arange(worlds))
    seconds = throughput.time_fn(
        throughput.raw_rollout(base.mjx_model, n, args.steps),
        (data, actions),
        args.repeats,
    )
    row['raw'] = worlds * args.steps * n / seconds
    for name, env in envs.items():
      reset = jax.jit(jax.vmap(env.reset))
      row[f'{name}_reset_s'] = time_reset(reset, keys, args.repeats)
      states = reset(keys)
      seconds = throughput.time_fn(
          throughput.env_rollout(env, args.steps),
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

  with open(args.out, 'w') as f:
    json.dump(
        {
            'device': device.device_kind,
            'jax': jax.__version__,
            'n_sub_steps': n,
            'episode_steps': args.episode_steps,
            'steps_per_call': args.steps,
            'results': results,
        },
        f,
        indent=2,
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
