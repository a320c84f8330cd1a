"""Every Python code block of README.md and docs/ runs, and passes.

Each Markdown file's fenced blocks whose info string is `python` run in
order, in one namespace per file, from the repository's root: a page reads
as one program. A block marked `python notest` (one that needs a GPU, a
headless OpenGL, several devices or minutes of training) is only compiled,
so its syntax is checked; the page says that it is not run. Fences must
start at the line's first column.
"""

import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
# ```python, ```python notest, ```bash, ... at the start of a line; a block
# ends at the next line that is a bare fence.
_FENCE = re.compile(
    r'^```(?P<info>[^`\n]*)\n(?P<code>.*?)^```[ \t]*$', re.M | re.S
)


def markdown_files():
  """README.md and every page under docs/, relative to the root."""
  files = [ROOT / 'README.md'] + sorted((ROOT / 'docs').rglob('*.md'))
  return [path.relative_to(ROOT) for path in files]


def python_blocks(path):
  """The `(line, code, run)` of each Python block of a Markdown file."""
  text = (ROOT / path).read_text()
  blocks = []
  for match in _FENCE.finditer(text):
    words = match.group('info').split()
    if not words or words[0] != 'python':
      continue
    line = text.count('\n', 0, match.start('code')) + 1
    blocks.append((line, match.group('code'), 'notest' not in words[1:]))
  return blocks


def _compiled(path, line, code):
  # Padded with blank lines, so that a traceback names the Markdown line.
  return compile('\n' * (line - 1) + code, str(path), 'exec')


_RUN = [
    path for path in markdown_files() if any(r for *_, r in python_blocks(path))
]


@pytest.mark.parametrize('path', markdown_files(), ids=str)
def test_blocks_compile(path):
  """Every Python block, run or not, is valid Python."""
  for line, code, _ in python_blocks(path):
    _compiled(path, line, code)


@pytest.mark.parametrize('path', _RUN, ids=str)
def test_blocks_run(path, monkeypatch):
  """A file's runnable blocks run in order in one namespace, without error."""
  monkeypatch.chdir(ROOT)
  namespace = {'__name__': f'docs_{path.stem}'}
  for line, code, run in python_blocks(path):
    if not run:
      continue
    try:
      exec(_compiled(path, line, code), namespace)  # pylint: disable=exec-used
    except Exception as e:
      raise AssertionError(f'{path}, the block at line {line} failed') from e


def test_pages_have_runnable_blocks():
  """The README and the getting-started guide run (not all `notest`)."""
  assert pathlib.Path('README.md') in _RUN
  assert pathlib.Path('docs/getting-started.md') in _RUN
