"""XLA's own Cholesky factorization on the CPU, as our scripts switch it on.

On the CPU, JAX lowers a batched Cholesky factorization (MJX's Newton solver
factorizes with `jax.scipy.linalg.cho_factor` in every forward pass) to a
LAPACK kernel of jaxlib that splits the batch into tasks on XLA's CPU thread
pool and blocks until they finish. When as many such factorizations run at
once as the pool has threads, every thread waits for tasks that no thread is
left to run, and the program never finishes (jaxlib 0.10; on a 2-core
machine two are enough). That hung the walk task's randomized reset in 3 of
3 runs of `benchmarks/repro_cpu_hang.py`, a 64-world rollout at stop 32 and
a test of this suite at stop 34 (`benchmarks/results/stop34_cpu/`).

`enable()` lowers the factorization on the CPU to XLA's `cholesky`
instruction instead, which XLA expands into plain loops: no LAPACK call, no
thread pool, the same factor to float rounding (`tests/
test_cpu_linalg.py`). GPU programs are unchanged. The command line, the
examples, the benchmarks, the notebooks and the test suite call it next to
`prng_lowering.enable()`; call it yourself before compiling on a CPU.

Off: `MJX_COMPOSER_XLA_CHOLESKY=0` in the environment, or
`enable(enabled=False)` (which restores JAX's LAPACK lowering).

A library import never calls `enable()`: importing `mjx_composer` leaves
JAX's lowering rules as they are.
"""

import os

# JAX has no public switch for this: its lowering rules are registered in
# jax._src, and `enable` re-registers the two it already has for this
# primitive (the platform-independent one for the CPU, or back).
from jax._src.interpreters import mlir
from jax._src.lax import linalg

SWITCH_ENV = 'MJX_COMPOSER_XLA_CHOLESKY'

_OFF_VALUES = ('0', 'false', 'no', 'off')


def enable(*, enabled: bool | None = None) -> bool:
  """Lowers Cholesky on the CPU to XLA's instruction, unless told otherwise.

  Call it before the first compilation it should apply to (programs
  compiled before keep their lowering; JAX's compilation cache keys on the
  lowered program, so cached programs do not mix).

  Args:
    enabled: True or False to decide here; None (the default): on unless
      `MJX_COMPOSER_XLA_CHOLESKY` is 0, false, no or off.

  Returns:
    Whether XLA's Cholesky is the CPU lowering after the call.
  """
  if enabled is None:
    value = os.environ.get(SWITCH_ENV, '').strip().lower()
    enabled = value not in _OFF_VALUES
  rule = (
      linalg._cholesky_lowering  # pylint: disable=protected-access
      if enabled
      else linalg._cholesky_cpu_lowering  # pylint: disable=protected-access
  )
  mlir.register_lowering(linalg.cholesky_p, rule, platform='cpu')
  return bool(enabled)
