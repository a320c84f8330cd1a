"""Where the test suite's time goes: JAX's compile events, per test.

A pytest plugin and its report. Loaded into a test run, it sums, for each
test (setup, call and teardown), the durations JAX reports through
`jax.monitoring` (tracing to a jaxpr, lowering to StableHLO, XLA's backend
compile) and counts the backend compiles and the programs loaded from the
persistent compilation cache, next to the test's wall-clock time. Each
process (every xdist worker) writes its own JSON file into
`$MJX_COMPOSER_SUITE_PROFILE` (default `suite_profile/`); the report sums
them per test file and lists the slowest tests:

    PYTHONPATH=benchmarks python -m pytest -q -n 2 -p suite_profile
    python benchmarks/suite_profile.py suite_profile/

Tests that start subprocesses (the CLI, notebooks, several devices) show
their wall time only: their compiles happen in the other processes. Traces
of nested jitted functions are reported inside their callers' traces too,
so the trace column overcounts. Run it with nothing else on the machine if
the seconds matter; the shares hold either way.
"""

import argparse
import collections
import glob
import json
import os
import sys

EVENTS = {
    '/jax/core/compile/jaxpr_trace_duration': 'trace_s',
    '/jax/core/compile/jaxpr_to_mlir_module_duration': 'lower_s',
    '/jax/core/compile/backend_compile_duration': 'compile_s',
}
FOLDER_ENV = 'MJX_COMPOSER_SUITE_PROFILE'

_current = {'test': '(outside tests)'}
_totals = collections.defaultdict(collections.Counter)


def _listener(event, duration, **kwargs):
  del kwargs
  name = EVENTS.get(event)
  if name is None:
    return
  counts = _totals[_current['test']]
  counts[name] += duration
  if name == 'compile_s':
    counts['compiles'] += 1


def _count(event, **kwargs):
  del kwargs
  if event == '/jax/compilation_cache/cache_hits':
    _totals[_current['test']]['cache_hits'] += 1


def pytest_configure(config):
  del config
  import jax  # pylint: disable=g-import-not-at-top

  jax.monitoring.register_event_duration_secs_listener(_listener)
  jax.monitoring.register_event_listener(_count)


def pytest_runtest_protocol(item, nextitem):
  """Attributes what happens during one test to its node id."""
  del nextitem
  _current['test'] = item.nodeid


def pytest_runtest_logfinish(nodeid, location):
  del location
  _current['test'] = '(outside tests)'
  _totals[nodeid]  # every test gets a row, even without compiles


def pytest_runtest_makereport(item, call):
  _totals[item.nodeid]['wall_s'] += call.stop - call.start


def pytest_sessionfinish(session):
  del session
  folder = os.environ.get(FOLDER_ENV, 'suite_profile')
  os.makedirs(folder, exist_ok=True)
  path = os.path.join(folder, f'{os.getpid()}.json')
  with open(path, 'w') as f:
    json.dump({k: dict(v) for k, v in _totals.items()}, f)


# -- the report -----------------------------------------------------------


def load(folder):
  """{test node id: {column: value}} from every process's file."""
  rows = {}
  for path in sorted(glob.glob(os.path.join(folder, '*.json'))):
    with open(path) as f:
      for test, counts in json.load(f).items():
        row = rows.setdefault(test, collections.Counter())
        row.update(counts)
  return rows


def by_file(rows):
  """The same columns summed per test file (the part before '::')."""
  files = collections.defaultdict(collections.Counter)
  for test, counts in rows.items():
    files[test.split('::')[0]].update(counts)
  return files


_COLUMNS = (
    'wall_s',
    'compile_s',
    'trace_s',
    'lower_s',
    'compiles',
    'cache_hits',
)


def table(rows, limit):
  lines = ['| ' + ' | '.join(('', *_COLUMNS)) + ' |']
  lines.append('|' + '---|' * (len(_COLUMNS) + 1))
  ordered = sorted(rows.items(), key=lambda kv: -kv[1].get('wall_s', 0.0))
  for name, counts in ordered[:limit]:
    cells = [f'{counts.get(c, 0):.1f}' for c in _COLUMNS[:4]]
    cells += [str(int(counts.get(c, 0))) for c in _COLUMNS[4:]]
    lines.append(f'| {name} | ' + ' | '.join(cells) + ' |')
  return '\n'.join(lines)


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('folder', help='where the plugin wrote its files')
  parser.add_argument('--top', type=int, default=25, help='rows per table')
  args = parser.parse_args(argv)
  rows = load(args.folder)
  if not rows:
    sys.exit(f'no profile files in {args.folder!r}')
  total = collections.Counter()
  for counts in rows.values():
    total.update(counts)
  print(
      'all tests: ' + ', '.join(f'{c} {total.get(c, 0):.1f}' for c in _COLUMNS)
  )
  print('\nby file\n' + table(by_file(rows), args.top))
  print('\nslowest tests\n' + table(rows, args.top))


if __name__ == '__main__':
  main()
