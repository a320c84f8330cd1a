"""Tests of the example scripts and ports: their folders on the import path.

The examples are not a package: `python examples/train_ppo.py` puts
`examples/` first on `sys.path`; the dm_control ports are imported as
`corridor` (from `examples/ports/`) and as the modules `tutorial` and
`dm_control_tutorial` (from `examples/ports/tutorial/`). They run in the
package suite's run (`testpaths` in pyproject.toml) and with its settings:
its compile flags, compilation cache and per-module fixtures
(`tests/conftest.py`), also when run by themselves.
"""

import os
import sys

_EXAMPLES = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path[:0] = [
    os.path.join(_EXAMPLES, 'ports', 'tutorial'),
    os.path.join(_EXAMPLES, 'ports'),
    _EXAMPLES,
    os.path.dirname(_EXAMPLES),  # the suite's `tests` package
]

# pylint: disable=g-import-not-at-top,wrong-import-position,unused-import
from tests.conftest import _free_compiled_programs
from tests.conftest import _optimized_compiles
