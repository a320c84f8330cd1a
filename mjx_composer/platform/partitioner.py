"""Which XLA partitioner compiles programs for several GPUs.

JAX compiles a program over several devices (`jax.shard_map`, `jax.pmap`,
`jax.jit` with shardings) through a partitioner: Shardy, JAX's default, or
GSPMD, the one before it. With JAX 0.11.2 on two GPUs, compiling MJX's step
under `shard_map` (this package's `sharding.per_device`) or under Brax's
`pmap` crashed the process: a segmentation fault in Shardy's canonicalizer
(`ManualComputationUnusedInputsPattern`), while trivial `shard_map` programs
compiled. The same programs compiled and ran with GSPMD (JAX's
`jax_use_shardy_partitioner=False`).

So programs that this package compiles for a mesh of several GPUs are
compiled with GSPMD: `scope(devices)` selects it for what is traced and
compiled inside it. JAX keys its compiled programs on the choice, so a
program called under the scope never reuses one compiled without it. On a
CPU (where Shardy compiles these programs), on one device, or on a JAX that
no longer has GSPMD, the scope changes nothing.

`MJX_COMPOSER_PARTITIONER` overrides the choice: `shardy` or `gspmd` for
every mesh, `auto` (or unset) as above. GSPMD prints a deprecation warning
when it runs; the workaround goes once Shardy compiles these programs
(`MJX_COMPOSER_PARTITIONER=shardy` tries it).
"""

from __future__ import annotations

import contextlib
import os
from typing import Iterable, Iterator

import jax

from mjx_composer.platform import internals_jax

PARTITIONER_ENV = 'MJX_COMPOSER_PARTITIONER'
_CHOICES = ('auto', 'shardy', 'gspmd')


def requested() -> str:
  """`MJX_COMPOSER_PARTITIONER`, checked: 'auto', 'shardy' or 'gspmd'."""
  value = os.environ.get(PARTITIONER_ENV, '').strip().lower() or 'auto'
  if value not in _CHOICES:
    raise ValueError(
        f'{PARTITIONER_ENV}={value!r} is not a partitioner: set it to one of '
        f'{", ".join(_CHOICES)}, or unset it.'
    )
  return value


def name_for(devices: Iterable[jax.Device]) -> str:
  """'gspmd' or 'shardy': the partitioner for a program over `devices`."""
  choice = requested()
  if choice == 'auto':
    devices = list(devices)
    several_gpus = len(devices) > 1 and any(
        d.platform == 'gpu' for d in devices
    )
    choice = 'gspmd' if several_gpus else 'shardy'
  if choice == 'gspmd' and internals_jax.shardy_partitioner_state() is None:
    return 'shardy'  # This JAX has no other partitioner.
  return choice


@contextlib.contextmanager
def scope(devices: Iterable[jax.Device]) -> Iterator[str]:
  """Traces and compiles what runs inside with `name_for(devices)`.

  Args:
    devices: the devices the programs run on (a mesh's `devices.flat`, or
      Brax's training devices).

  Yields:
    The partitioner's name, 'gspmd' or 'shardy'.
  """
  name = name_for(devices)
  state = internals_jax.shardy_partitioner_state()
  if state is None:
    yield name
    return
  with state(name == 'shardy'):
    yield name
