"""Cholesky factorization in plain XLA on the CPU.

On the CPU, JAX lowers a batched Cholesky factorization (MJX's Newton solver
factorizes with `jax.scipy.linalg.cho_factor` in every forward pass) to a
LAPACK kernel of jaxlib that splits the batch into tasks on XLA's CPU thread
pool and blocks until they finish. When as many such factorizations run at
once as the pool has threads, every thread waits for tasks that no thread is
left to run, and the program never finishes (jaxlib 0.10; on a 2-core
machine two are enough: e.g. a randomized reset that factorizes the mass
matrix at `qpos0` beside the forward pass's own factorization).

`enable()` lowers the factorization on the CPU to `cholesky` below instead:
plain XLA loops, no LAPACK call, no thread pool, the same factor to float
rounding (`tests/platform/test_cpu_linalg.py`). GPU programs are unchanged.
On the CPU, a composed walk task's step runs at about 0.9 of its rate with
LAPACK's lowering; XLA's own `cholesky` instruction, the obvious
alternative, ran at about a quarter of it.

Importing `mjx_composer` calls `enable()` (`platform.safe_defaults`): a
process that imports the package compiles Cholesky this way on the CPU,
its own programs too, unless switched off. `platform.configure()` calls
it again, as the command line, the examples, the benchmarks, the notebooks
and the test suite do.

Off: `MJX_COMPOSER_XLA_CHOLESKY=0` in the environment (before the import),
or `enable(enabled=False)` (which restores JAX's LAPACK lowering for
programs lowered afterwards).
"""

import os

import jax
import jax.numpy as jnp

from mjx_composer.platform import internals_jax

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


_cholesky_loops = internals_jax.lower_fun(cholesky, multiple_results=False)


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
      _cholesky_loops if enabled else internals_jax.lapack_cholesky_cpu_lowering
  )
  internals_jax.register_cpu_lowering(internals_jax.cholesky_p, rule)
  return bool(enabled)
