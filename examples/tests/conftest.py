"""Tests of the example scripts and ports: their folders on the import path.

The examples are not a package: `python examples/train_ppo.py` puts
`examples/` first on `sys.path`; the dm_control ports are imported as
`corridor` (from `examples/ports/`) and as the modules `tutorial` and
`dm_control_tutorial` (from `examples/ports/tutorial/`). `.ci/run` runs
these tests in a step of their own, with the package suite's settings
(`-p tests.conftest`, see README).
"""

import os
import sys

_EXAMPLES = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
for _folder in (
    os.path.join(_EXAMPLES, 'ports', 'tutorial'),
    os.path.join(_EXAMPLES, 'ports'),
    _EXAMPLES,
):
  sys.path.insert(0, _folder)
