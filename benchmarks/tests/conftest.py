"""Tests of the benchmark scripts: `benchmarks/` on the import path.

The scripts are not a package: each runs as `python benchmarks/NAME.py`,
which puts `benchmarks/` first on `sys.path` (they import `common` and each
other so). Their tests import them the same way. `.ci/run` runs these tests
in a step of their own, with the package suite's settings
(`-p tests.conftest`, see README).
"""

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
