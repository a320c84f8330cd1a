"""benchmarks/suite_profile.py: its per-process files summed and reported."""

import collections
import json
import os
import sys

sys.path.insert(
    0, os.path.join(os.path.dirname(os.path.dirname(__file__)), 'benchmarks')
)

import suite_profile  # pylint: disable=g-import-not-at-top,wrong-import-position


def _write(folder, name, rows):
  with open(os.path.join(folder, name), 'w') as f:
    json.dump(rows, f)


def test_processes_are_summed_per_test_and_per_file(tmp_path):
  _write(
      tmp_path,
      '1.json',
      {
          'tests/test_a.py::one': {'wall_s': 3.0, 'compile_s': 2.0},
          'tests/test_b.py::two': {'wall_s': 1.0, 'compiles': 4},
      },
  )
  _write(
      tmp_path,
      '2.json',
      {
          'tests/test_a.py::one': {'wall_s': 1.0, 'cache_hits': 2},
          'tests/test_a.py::three': {'wall_s': 5.0, 'trace_s': 0.5},
      },
  )
  rows = suite_profile.load(str(tmp_path))
  assert rows['tests/test_a.py::one'] == {
      'wall_s': 4.0,
      'compile_s': 2.0,
      'cache_hits': 2,
  }
  files = suite_profile.by_file(rows)
  assert files['tests/test_a.py']['wall_s'] == 9.0
  assert files['tests/test_b.py']['compiles'] == 4
  # Slowest first, limited to `limit` rows after the header.
  lines = suite_profile.table(rows, limit=2).splitlines()
  assert len(lines) == 4
  assert lines[2].startswith('| tests/test_a.py::three | 5.0 | 0.0 | 0.5 |')
  assert lines[3].startswith('| tests/test_a.py::one | 4.0 | 2.0 |')
  assert lines[3].endswith('| 0 | 2 |')


def test_the_listener_attributes_events_to_the_running_test(monkeypatch):
  # Fresh state: the plugin may be profiling this very run.
  # pylint: disable=protected-access
  monkeypatch.setattr(
      suite_profile,
      '_totals',
      collections.defaultdict(collections.Counter),
  )
  monkeypatch.setattr(suite_profile, '_current', {'test': 'x::y'})
  suite_profile._listener('/jax/core/compile/backend_compile_duration', 1.5)
  suite_profile._listener('/jax/core/compile/backend_compile_duration', 0.5)
  suite_profile._listener('/jax/some/other_event', 9.0)
  suite_profile._count('/jax/compilation_cache/cache_hits')
  totals = suite_profile._totals['x::y']
  assert totals == {'compile_s': 2.0, 'compiles': 2, 'cache_hits': 1}
