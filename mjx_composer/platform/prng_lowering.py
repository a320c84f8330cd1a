"""JAX's GPU kernel for the threefry hash.

Every random draw of a composed environment (per-episode randomization,
initializers, observation noise, key splitting) hashes with threefry. On a
GPU, JAX lowers each call of the hash to about a hundred elementwise HLO
instructions, and a reset holds dozens of calls: the reach task's step
program (which holds a reset) had 45,132 HLO instructions. With JAX's
`jax_threefry_gpu_kernel_lowering`, each call is one custom call of a CUDA
kernel instead: the same program has 34,995 instructions and compiled in
about 0.6 of the time (`benchmarks/compile_time.py --tasks reach --programs
step`). The kernel computes the same hash, so random values do not change.
JAX's documentation warns of "a potential runtime memory cost" (the
kernel's operands are materialized instead of fused).

`enable()` turns it on; `platform.configure()` calls it, as the command line
(`mjx-composer demo`), the examples, the benchmarks, the notebooks and the
test suite do. It changes nothing on a CPU, where JAX already lowers the
hash as a loop.

Off: `MJX_COMPOSER_THREEFRY_KERNEL=0` in the environment, or
`enable(enabled=False)`. JAX's own setting wins: if
`JAX_THREEFRY_GPU_KERNEL_LOWERING` is set, `enable()` changes nothing.

A library import never calls `enable()`: importing `mjx_composer` leaves the
JAX configuration as it is.
"""

import os

import jax

FLAG = 'jax_threefry_gpu_kernel_lowering'
SWITCH_ENV = 'MJX_COMPOSER_THREEFRY_KERNEL'

_OFF_VALUES = ('0', 'false', 'no', 'off')


def enable(*, enabled: bool | None = None) -> bool:
  """Lowers threefry to JAX's GPU kernel, unless told otherwise.

  Call it before the first compilation it should apply to: the setting is
  read when a program is lowered, and is part of JAX's compilation cache key.

  Args:
    enabled: True or False to decide here; None (the default): on unless
      `MJX_COMPOSER_THREEFRY_KERNEL` is 0, false, no or off.

  Returns:
    Whether the kernel lowering is on after the call.
  """
  if FLAG.upper() in os.environ:
    return bool(getattr(jax.config, FLAG))  # the user's own setting wins
  if enabled is None:
    value = os.environ.get(SWITCH_ENV, '').strip().lower()
    enabled = value not in _OFF_VALUES
  jax.config.update(FLAG, bool(enabled))
  return bool(enabled)


def is_enabled() -> bool:
  """Whether JAX lowers threefry to its GPU kernel (JAX's setting now)."""
  return bool(getattr(jax.config, FLAG))
