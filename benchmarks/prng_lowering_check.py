"""Threefry's GPU kernel lowering: same states, shorter compile.

Builds a bundled task's environment (per-episode randomization, every
observable, same-step auto-reset) and runs `jax.vmap(env.reset)` and
`--steps` control steps of `jax.vmap(env.step)`, once with JAX's
`jax_threefry_gpu_kernel_lowering` off and once on (`prng_lowering`), each in
a fresh process with the persistent compilation cache off. It reports each
run's compile seconds of the reset and step programs and whether every leaf
of every state (observations, rewards, physics, per-world model fields, keys)
is bitwise the same. On a CPU the setting does nothing.

    python benchmarks/prng_lowering_check.py --task reach --worlds 1024
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np


def _run(task, worlds, steps, out):
  """One process's run: compile times, and the states saved to `out`."""
  import jax  # pylint: disable=g-import-not-at-top

  import common  # pylint: disable=g-import-not-at-top

  jax.config.update('jax_enable_compilation_cache', False)
  env = common.make_env(task)
  keys = jax.random.split(jax.random.key(0), worlds)
  actions = common.random_actions(env, worlds)
  reset, step = jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))
  timings = {}
  t0 = time.perf_counter()
  reset = reset.lower(keys).compile()
  timings['reset_compile_s'] = time.perf_counter() - t0
  states = [reset(keys)]
  t0 = time.perf_counter()
  step = step.lower(states[0], actions).compile()
  timings['step_compile_s'] = time.perf_counter() - t0
  for _ in range(steps):
    states.append(step(states[-1], actions))
  leaves = {}
  for i, state in enumerate(states):
    state = state.replace(key=jax.random.key_data(state.key))
    for path, leaf in jax.tree_util.tree_leaves_with_path(state):
      leaves[f'{i}{jax.tree_util.keystr(path)}'] = np.asarray(leaf)
  np.savez(out, **leaves)
  timings['flag'] = bool(jax.config.jax_threefry_gpu_kernel_lowering)
  timings['device'] = jax.devices()[0].device_kind
  return timings


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--task', default='reach')
  parser.add_argument('--worlds', type=int, default=1024)
  parser.add_argument('--steps', type=int, default=5)
  parser.add_argument(
      '--out',
      default=os.path.join(os.environ.get('OUT', '.'), 'prng_lowering.json'),
  )
  parser.add_argument('--worker', help=argparse.SUPPRESS)
  args = parser.parse_args()
  if args.worker:
    print(json.dumps(_run(args.task, args.worlds, args.steps, args.worker)))
    return

  rows, arrays = {}, {}
  with tempfile.TemporaryDirectory() as tmp:
    for flag in ('0', '1'):
      path = os.path.join(tmp, f'states_{flag}.npz')
      env = dict(os.environ, JAX_THREEFRY_GPU_KERNEL_LOWERING=flag)
      result = subprocess.run(
          [sys.executable, __file__, '--task', args.task, '--worlds',
           str(args.worlds), '--steps', str(args.steps), '--worker', path],
          env=env, capture_output=True, text=True, check=True,
      )  # fmt: skip
      rows[flag] = json.loads(result.stdout.strip().splitlines()[-1])
      with np.load(path) as saved:
        arrays[flag] = dict(saved)
  off, on = arrays['0'], arrays['1']
  differing = sorted(
      name for name in off if not np.array_equal(off[name], on[name])
  )
  report = {
      'task': args.task,
      'worlds': args.worlds,
      'steps': args.steps,
      'kernel_off': rows['0'],
      'kernel_on': rows['1'],
      'leaves_compared': len(off),
      'leaves_differing': differing,
      'bitwise_equal': not differing and off.keys() == on.keys(),
  }
  with open(args.out, 'w') as f:
    json.dump(report, f, indent=1)
  for flag, label in (('0', 'off'), ('1', 'on')):
    print(
        f'threefry kernel {label}: reset compile'
        f' {rows[flag]["reset_compile_s"]:.1f} s, step compile'
        f' {rows[flag]["step_compile_s"]:.1f} s ({rows[flag]["device"]})'
    )
  print(
      f'{len(off)} state leaves over {args.steps + 1} states:'
      f' {"bitwise equal" if report["bitwise_equal"] else differing[:10]}'
  )


if __name__ == '__main__':
  main()
