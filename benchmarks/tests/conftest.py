"""Tests of the benchmark scripts: `benchmarks/` on the import path.

The scripts are not a package: each runs as `python benchmarks/NAME.py`,
which puts `benchmarks/` first on `sys.path` (they import `common` and each
other so). Their tests import them the same way. They run in the package
suite's run (`testpaths` in pyproject.toml) and with its settings: its
compile flags, compilation cache and per-module fixtures
(`tests/conftest.py`), also when run by themselves.
"""

import os
import sys

_BENCHMARKS = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path[:0] = [_BENCHMARKS, os.path.dirname(_BENCHMARKS)]  # + `tests`

# pylint: disable=g-import-not-at-top,wrong-import-position,unused-import
from tests.conftest import _free_compiled_programs
from tests.conftest import _optimized_compiles
