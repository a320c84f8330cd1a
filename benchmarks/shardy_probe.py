"""Does Shardy still crash compiling MJX for several devices?

`mjx_composer.partitioner` compiles programs over several GPUs with GSPMD
because Shardy, JAX's default partitioner, crashed the process (a
segmentation fault in `ManualComputationUnusedInputsPattern`) compiling
MJX's step under `jax.shard_map` and `jax.pmap` on two H200s with JAX
0.11.2, while simple programs compiled. This script tells when the
workaround can go: each case runs in a fresh process (a crash kills only
that one) with the partitioner forced, on the first two devices, and the
table says which compiled and ran.

Cases:

* trivial: `x * 2` under `shard_map`;
* while:   a per-device data-dependent `lax.while_loop` under `shard_map`;
* mjx:     raw MJX's rollout of the reach model (2 control steps of
           `vmap(mjx.step)`, `common.raw_rollout`) under `shard_map`;
* pmap:    the same rollout under `jax.pmap`.

    python benchmarks/shardy_probe.py            # a GPU machine, 2+ GPUs
    XLA_FLAGS=--xla_force_host_platform_device_count=2 JAX_PLATFORMS=cpu \\
        python benchmarks/shardy_probe.py        # a check of the script
"""

import argparse
import subprocess
import sys

CASES = ('trivial', 'while', 'mjx', 'pmap')
PARTITIONERS = ('shardy', 'gspmd')


def run_case(case, partitioner):
  """Compiles and runs `case` in this process (the worker's side)."""
  # pylint: disable=g-import-not-at-top
  import jax
  import jax.numpy as jnp
  from jax.sharding import Mesh
  from jax.sharding import PartitionSpec as P

  import common  # benchmarks/common.py
  # pylint: enable=g-import-not-at-top

  jax.config.update('jax_use_shardy_partitioner', partitioner == 'shardy')
  devices = jax.devices()[:2]
  if len(devices) < 2:
    raise SystemExit(f'needs 2 devices, found {len(devices)}')
  mesh = Mesh(devices, ('w',))

  def per_device(fn):
    return jax.jit(
        jax.shard_map(
            fn, mesh=mesh, in_specs=P('w'), out_specs=P('w'), check_vma=False
        )
    )

  x = jnp.arange(16.0)
  if case == 'trivial':
    out = per_device(lambda x: x * 2)(x)
  elif case == 'while':
    out = per_device(
        lambda x: jax.lax.while_loop(
            lambda c: jnp.any(c < 100.0), lambda c: c * 1.5 + 1, x
        )
    )(x)
  else:
    env = common.make_env('reach')
    worlds = 16
    # On the host, so that the programs place them on their devices.
    data = jax.device_get(common.raw_data(env.mjx_model, worlds))
    actions = jax.device_get(common.random_actions(env, worlds))
    rollout = common.raw_rollout(env.mjx_model, env.n_sub_steps, 2, jit=False)
    if case == 'mjx':
      out = per_device(rollout)(data, actions)
    else:
      split = lambda tree: jax.tree.map(
          lambda a: a.reshape((2, a.shape[0] // 2) + a.shape[1:]), tree
      )
      out = jax.pmap(rollout, devices=devices)(split(data), split(actions))
  jax.block_until_ready(out)


def main():
  parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
  parser.add_argument('--cases', nargs='+', choices=CASES, default=CASES)
  parser.add_argument(
      '--partitioners', nargs='+', choices=PARTITIONERS, default=PARTITIONERS
  )
  parser.add_argument('--timeout', type=float, default=300.0)
  parser.add_argument('--worker', nargs=2, help=argparse.SUPPRESS)
  args = parser.parse_args()
  if args.worker:
    run_case(*args.worker)
    return

  rows = []
  for partitioner in args.partitioners:
    for case in args.cases:
      try:
        done = subprocess.run(
            [sys.executable, __file__, '--worker', case, partitioner],
            capture_output=True,
            text=True,
            timeout=args.timeout,
            check=False,
        )
        code = done.returncode
        result = 'ok' if code == 0 else f'exit {code}'
        if code < 0:
          result = f'killed by signal {-code}'  # -11: segmentation fault
        if code != 0:
          print(done.stderr[-2000:], file=sys.stderr)
      except subprocess.TimeoutExpired:
        result = f'timeout {args.timeout:g} s'
      rows.append((partitioner, case, result))
      print(f'{partitioner:>7} {case:>8}: {result}', flush=True)
  print('\n| partitioner | case | result |\n|---|---|---|')
  for row in rows:
    print('| {} | {} | {} |'.format(*row))


if __name__ == '__main__':
  main()
