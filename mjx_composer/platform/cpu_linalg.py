"""Cholesky factorization in plain XLA on the CPU, as our scripts switch it on.

On the CPU, JAX lowers a batched Cholesky factorization (MJX's Newton solver
factorizes with `jax.scipy.linalg.cho_factor` in every forward pass) to a
LAPACK kernel of jaxlib that splits the batch into tasks on XLA's CPU thread
pool and blocks until they finish. When as many such factorizations run at
once as the pool has threads, every thread waits for tasks that no thread is
left to run, and the program never finishes (jaxlib 0.10; on a 2-core
machine two are enough). That hung the walk task's randomized reset in 3 of
3 runs of `benchmarks/repro_cpu_hang.py`, a 64-world rollout at stop 32 and
a test of this suite at stop 34 (`benchmarks/results/stop34_cpu/`).

`enable()` lowers the factorization on the CPU to `cholesky` below instead:
plain XLA loops, no LAPACK call, no thread pool, the same factor to float
rounding (`tests/platform/test_cpu_linalg.py`). GPU programs are unchanged. Cost on
the CPU (`python benchmarks/playground_compare.py --worlds 64 --steps 20
--programs ours_off only_noise+delay+history+randomize+groups`, 2 cores,
`MJX_COMPOSER_XLA_CHOLESKY=0|1`): the walk task's step ran at 0.91-0.92 of
its rate with LAPACK (1,502 against 1,643 control steps/s); XLA's own
`cholesky` instruction, tried first, at 0.27. The command line, the
examples, the benchmarks, the notebooks and the test suite call it next to
`prng_lowering.enable()`; call it yourself before compiling on a CPU.

Off: `MJX_COMPOSER_XLA_CHOLESKY=0` in the environment, or
`enable(enabled=False)` (which restores JAX's LAPACK lowering).

A library import never calls `enable()`: importing `mjx_composer` leaves
JAX's lowering rules as they are.
"""

import os

import jax
import jax.numpy as jnp

# JAX has no public switch for this: its lowering rules are registered in
# jax._src, and `enable` registers `cholesky` as the CPU rule of JAX's
# Cholesky primitive (or puts JAX's LAPACK rule back).
from jax._src.interpreters import mlir
from jax._src.lax import linalg

SWITCH_ENV = 'MJX_COMPOSER_XLA_CHOLESKY'

_OFF_VALUES = ('0', 'false', 'no', 'off')


def cholesky(a):
  """The lower Cholesky factor of each matrix of `a` (`(..., n, n)`), in XLA.

  Cholesky-Crout, a column at a time for the whole batch: `n` iterations of
  one batched matrix-vector product. A matrix that is not positive definite
  gives NaN in its factor, as LAPACK's lowering does.
  """
  n = a.shape[-1]
  index = jnp.arange(n)

  def column(j, lower):
    # Columns >= j of `lower` are still zero: the product sums k < j.
    row_j = jnp.take(lower, j, axis=-2)  # (..., n)
    values = jnp.take(a, j, axis=-1) - jnp.einsum(
        '...ik,...k->...i', lower, row_j
    )
    diagonal = jnp.sqrt(jnp.take(values, j, axis=-1))[..., None]
    values = jnp.where(index > j, values / diagonal, 0.0)
    values = jnp.where(index == j, diagonal, values)
    return jax.lax.dynamic_update_index_in_dim(
        lower, values[..., None], j, axis=-1
    )

  return jax.lax.fori_loop(0, n, column, jnp.zeros_like(a))


_cholesky_loops = mlir.lower_fun(cholesky, multiple_results=False)


def enable(*, enabled: bool | None = None) -> bool:
  """Lowers Cholesky on the CPU to `cholesky`, unless told otherwise.

  Call it before the first compilation it should apply to (programs
  compiled before keep their lowering; JAX's compilation cache keys on the
  lowered program, so cached programs do not mix).

  Args:
    enabled: True or False to decide here; None (the default): on unless
      `MJX_COMPOSER_XLA_CHOLESKY` is 0, false, no or off.

  Returns:
    Whether `cholesky` is the CPU lowering after the call.
  """
  if enabled is None:
    value = os.environ.get(SWITCH_ENV, '').strip().lower()
    enabled = value not in _OFF_VALUES
  rule = (
      _cholesky_loops
      if enabled
      else linalg._cholesky_cpu_lowering  # pylint: disable=protected-access
  )
  mlir.register_lowering(linalg.cholesky_p, rule, platform='cpu')
  return bool(enabled)
