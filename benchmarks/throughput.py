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


def build(observables: bool):
  task = reach.Reach(randomize=False)  # variation_cost.py measures DR
  if not observables:
    for obs in task.observables.values():
      obs.enabled = False
  return environment.Environment(
      task,
      time_limit=2.0,
      auto_reset='same_step',
      observation_groups=reach.Reach.observation_groups()
      if observables
      else None,
  )


def time_fn(fn, args, repeats):
  out = jax.block_until_ready(fn(*args))  # compile + warm up
  out = jax.block_until_ready(fn(*out))  # outputs may retrace once (dtypes)
  times = []
  for _ in range(repeats):
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*out))
    times.append(time.perf_counter() - t0)
  return statistics.median(times)


def raw_rollout(model, n_sub_steps, steps):
  step = jax.vmap(lambda d: mjx.step(model, d))

  @jax.jit
  def rollout(data, ctrl):
    def control_step(d, _):
      d = d.replace(ctrl=ctrl)
      d = jax.lax.fori_loop(0, n_sub_steps, lambda _, x: step(x), d)
      return d, None

    return jax.lax.scan(control_step, data, None, length=steps)[0], ctrl

  return rollout


def env_rollout(env, steps):
  vstep = jax.vmap(env.step)

  @jax.jit
  def rollout(states, actions):
    def control_step(s, _):
      return vstep(s, actions), None

    return jax.lax.scan(control_step, states, None, length=steps)[0], actions

  return rollout


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--worlds', type=int, nargs='+', default=[1024])
  parser.add_argument(
      '--steps', type=int, default=100, help='control steps per timed call'
  )
  parser.add_argument('--repeats', type=int, default=3)
  parser.add_argument(
      '--out',
      default=os.path.join(os.environ.get('OUT', '.'), 'throughput.json'),
  )
  args = parser.parse_args()

  device = jax.devices()[0]
  print(f'JAX {jax.__version__}, {device.platform}: {device.device_kind}')
  envs = {'composed': build(True), 'no_obs': build(False)}
  base = envs['composed']
  n = base.n_sub_steps
  spec = base.action_spec()
  results = []
  for worlds in args.worlds:
    row = {'worlds': worlds}
    actions = jax.random.uniform(
        jax.random.key(1), (worlds,) + spec.shape, minval=-1.0, maxval=1.0
    )
    data = jax.vmap(lambda _: mjx.make_data(base.mjx_model))(jnp.arange(worlds))
    data = jax.jit(jax.vmap(lambda d: mjx.forward(base.mjx_model, d)))(data)
    seconds = time_fn(
        raw_rollout(base.mjx_model, n, args.steps),
        (data, actions),
        args.repeats,
    )
    row['raw'] = worlds * args.steps * n / seconds
    for name, env in envs.items():
      states = jax.jit(jax.vmap(env.reset))(
          jax.random.split(jax.random.key(0), worlds)
      )
      seconds = time_fn(
          env_rollout(env, args.steps), (states, actions), args.repeats
      )
      row[name] = worlds * args.steps * n / seconds
    results.append(row)
    print(
        f'{worlds:>7} worlds: raw {row["raw"]:,.0f}  composed '
        f'{row["composed"]:,.0f}  no_obs {row["no_obs"]:,.0f} physics '
        'steps/s',
        flush=True,
    )

  with open(args.out, 'w') as f:
    json.dump(
        {
            'device': device.device_kind,
            'jax': jax.__version__,
            'n_sub_steps': n,
            'steps_per_call': args.steps,
            'results': results,
        },
        f,
        indent=2,
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
