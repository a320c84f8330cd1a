"""MuJoCo's options (`MjSpec.option`) as the compiler and MJX see them."""

import mujoco
import numpy as np

# The class of `MjSpec.option` (not `mujoco.MjOption`, the compiled struct).
SPEC_OPTION = type(mujoco.MjSpec().option)
# MJX decides at put_model time, statically, whether fluid forces exist.
FLUID_FIELDS = ('density', 'viscosity', 'wind')


def option_has_fluid(opt) -> bool:
  """MJX's static `has_fluid_params` rule (`mjx/_src/io.py`).

  Args:
    opt: an `MjSpec.option` or a compiled `mujoco.MjOption`.
  """
  return bool(opt.density > 0 or opt.viscosity > 0 or np.any(opt.wind))
