"""Checks a CPU deadlock in jaxlib's batched LAPACK calls stays avoided (stop 34).

On this project's 2-core machine, calling the walk task's reset with issue
14's features on, vmapped over 64 worlds, hung within a few calls:

    python benchmarks/repro_cpu_hang.py --calls 200

Every thread then slept. Both threads of XLA's intra-op pool sat in
`lapack_spotrf_ffi` -> `jax::CholeskyFactorization::Kernel` ->
`jax::ParallelBatchMap` -> `BlockingCounter::Wait`: each factorization
split its batch into tasks on the same pool it runs on and waited for them,
and no thread was left to run them (`benchmarks/results/stop34_cpu/
cpu_hang_lapack_potrf_gdb.log`, from `gdb -p PID -batch -ex "thread apply
all bt"`). One was MJX's forward pass (its Newton solver), the other the
randomized model's `mj_setConst` (`compiler/set_const.py` inverted the mass
matrix at qpos0 with `cho_factor` / `cho_solve`). `XLA_FLAGS=
--xla_cpu_multi_thread_eigen=false` did not avoid it. JAX 0.10.2; the same
hang stopped a 64-world walk rollout at stop 32 (README, Locomotion).

Since stop 34 `set_const` inverts with plain XLA loops on the CPU (no LAPACK
call beside MJX's). Before: 3 of 3 runs hung (`timeout 300`, rc 124); after:
3 of 3 finished (200, 500 and 500 calls). MJX's own LAPACK calls run one
after the other within a forward pass; two forward passes side by side in
one program could still meet this. Two batched `jnp.linalg.cholesky` calls
in one program, 3,000 times over 64 or 512 matrices, did not hang, so the
deadlock is not reduced to JAX alone yet.

Prints the number of calls done every 20 calls, and 'ok' at the end.
"""

import argparse
import time

import jax

import playground_compare  # benchmarks/playground_compare.py

PROGRAM = 'only_noise+delay+history+randomize+groups'


def main():
  parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
  parser.add_argument('--calls', type=int, default=200)
  parser.add_argument('--worlds', type=int, default=64)
  parser.add_argument('--program', default=PROGRAM)
  args = parser.parse_args()
  env = playground_compare.env_variants([args.program])[args.program]
  reset = jax.jit(jax.vmap(env.reset))
  keys = jax.random.split(jax.random.key(0), args.worlds)
  jax.block_until_ready(reset(keys))
  start = time.perf_counter()
  for i in range(args.calls):
    keys = jax.random.split(keys[0], args.worlds)
    jax.block_until_ready(reset(keys))
    if i % 20 == 0:
      print(f'{i} calls, {time.perf_counter() - start:.1f} s', flush=True)
  print(f'ok: {args.calls} calls', flush=True)


if __name__ == '__main__':
  main()
