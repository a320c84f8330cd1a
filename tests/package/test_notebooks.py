"""Tests for the notebooks in `notebooks/`: saved executed, and still run.

The notebooks are saved with their outputs so that they read well on GitHub.
Two kinds of test:

* the saved file was executed top to bottom, and its outputs include plots or
  renders and the values the text refers to;
* a temporary copy executes without errors in a fresh `python3` kernel on the
  CPU (`JAX_PLATFORMS=cpu`), and prints values of the expected form.

To refresh a saved notebook after changing it or the package, execute it in
place from the repository root:

    JAX_PLATFORMS=cpu python -c "import nbclient, nbformat; \
p = 'notebooks/getting_started.ipynb'; nb = nbformat.read(p, 4); \
nbclient.NotebookClient(nb, timeout=900, kernel_name='python3', \
resources={'metadata': {'path': 'notebooks'}}).execute(); nbformat.write(nb, p)"
"""

import pathlib
import re
import shutil
import time

# The notebook tools come with the test extra: a missing install fails here.
import ipykernel  # pylint: disable=unused-import
import matplotlib  # pylint: disable=unused-import
import nbclient
import nbformat
import pytest

_NOTEBOOKS = pathlib.Path(__file__).resolve().parents[2] / 'notebooks'
# Per cell: the first jitted rollout compiles for about a minute on 2 CPU
# cores, and CI machines may be slower still.
_CELL_TIMEOUT_S = 900

# Notebooks whose kernel compiles with XLA's optimizations on, unlike the
# rest of the suite (tests/conftest.py): the tutorial's capsule-cylinder
# contacts (MJX's iterative SDF collision) run so slowly unoptimized that
# the porting notebook's 4 x 40 steps took 280 s on a 2-core CPU, against
# 56 s optimized (compiled programs loaded from the cache in both).
_OPTIMIZED = ('porting_from_dm_control.ipynb',)

# Printed lines each notebook must produce (regular expressions, searched in
# the text of its stdout and text/plain outputs).
_EXPECTED_TEXT = {
    'getting_started.ipynb': [
        r'JAX \S+ on cpu',
        r"bodies: \['world', 'arm/', 'arm/base', 'arm/upper', 'arm/lower', "
        r"'ball/', 'ball/body'\]",
        r'all worlds LAST after 100 steps: True',
        r'all truncated \(time limit\): True',
        r'ball radii \(m\): \[[0-9. \n]+\]',
    ],
    'porting_from_dm_control.ipynb': [
        r'DM_CONTROL_SOURCE: kept \d+ lines as text, not run',
        r'MJX_SOURCE: ran \d+ lines',
        r'(?m)^\+\+\+ mjx_composer$',
        r'(?m)^-  def initialize_episode\(self, physics, random_state\):$',
        r'(?m)^\+  def initial_state\(self\):$',
        r"\d+ of \d+ lines of dm_control's code changed",
        r'4 worlds x 40 steps of 0\.05 s: button distances \[[0-9. ]+\] m, '
        r'max touch force \d+\.\d\d N, total reward \d+\.\d\d',
    ],
}


def _code_cells(nb):
  return [cell for cell in nb.cells if cell.cell_type == 'code']


def _text(nb) -> str:
  """The notebook's printed and text/plain outputs, as a reader sees them.

  The kernel sends stdout in chunks as its IO thread flushes, so one printed
  line may arrive as two stream outputs: stdout chunks are concatenated as
  they came (they carry their own newlines), and stderr, which may arrive
  between them, is left out.
  """
  parts = []
  for cell in _code_cells(nb):
    for output in cell.outputs:
      if output.output_type == 'stream' and output.name == 'stdout':
        parts.append(output.text)
      elif output.output_type in ('display_data', 'execute_result'):
        parts.append(f"\n{output.data.get('text/plain', '')}\n")
  return ''.join(parts)


def _images(nb) -> list:
  return [
      output.data['image/png']
      for cell in _code_cells(nb)
      for output in cell.outputs
      if output.output_type in ('display_data', 'execute_result')
      and 'image/png' in output.data
  ]


def _check_outputs(nb, name):
  """Checks what both the saved and the freshly executed notebook show."""
  errors = [
      output
      for cell in _code_cells(nb)
      for output in cell.outputs
      if output.output_type == 'error'
  ]
  assert not errors, f'{name}: error outputs {errors}'
  assert _images(nb), f'{name}: no image/png output'
  text = _text(nb)
  for pattern in _EXPECTED_TEXT[name]:
    assert re.search(
        pattern, text
    ), f'{name}: no output matches {pattern!r} in:\n{text}'
  if name == 'getting_started.ipynb':
    # Domain randomization: the variator scales the ball's 0.06 m radius by
    # U(0.5, 2) per world, so the shown worlds differ within those bounds.
    line = re.search(r'ball radii \(m\): \[([0-9. \n]+)\]', text).group(1)
    radii = [float(r) for r in line.split()]
    assert len(radii) == 8
    assert all(0.03 - 1e-3 <= r <= 0.12 + 1e-3 for r in radii), radii
    assert len(set(radii)) > 1, radii


@pytest.mark.parametrize('name', sorted(_EXPECTED_TEXT))
def test_saved_notebook_was_executed(name):
  nb = nbformat.read(_NOTEBOOKS / name, as_version=4)
  cells = _code_cells(nb)
  assert cells
  # Executed in one pass, top to bottom: execution counts 1, 2, 3, ...
  assert [cell.execution_count for cell in cells] == list(
      range(1, len(cells) + 1)
  ), f'{name} was not saved executed in order'
  for i, cell in enumerate(cells):
    assert cell.outputs, f'{name}: code cell {i} has no saved output'
  _check_outputs(nb, name)
  # Keep the repository small: modest images only.
  for image in _images(nb):
    assert len(image) * 3 // 4 < 100_000, f'{name}: an image over 100 KB'


@pytest.mark.parametrize('name', sorted(_EXPECTED_TEXT))
def test_notebook_executes(name, tmp_path, monkeypatch):
  path = tmp_path / name
  shutil.copy(_NOTEBOOKS / name, path)
  # The kernel inherits the environment: run JAX on the CPU, as CI does.
  monkeypatch.setenv('JAX_PLATFORMS', 'cpu')
  if name in _OPTIMIZED:
    monkeypatch.setenv('JAX_DISABLE_MOST_OPTIMIZATIONS', '0')
  nb = nbformat.read(path, as_version=4)
  for cell in _code_cells(nb):
    cell.outputs = []
    cell.execution_count = None
  client = nbclient.NotebookClient(
      nb,
      timeout=_CELL_TIMEOUT_S,
      kernel_name='python3',
      resources={'metadata': {'path': str(tmp_path)}},
  )
  start = time.monotonic()
  try:
    client.execute()
  except nbclient.exceptions.CellExecutionError as e:
    pytest.fail(f'{name} failed to execute:\n{e}')
  print(f'{name}: executed in {time.monotonic() - start:.0f} s')
  _check_outputs(nb, name)
  assert all(cell.execution_count for cell in _code_cells(nb))
