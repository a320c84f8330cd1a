"""Every Python code block of README.md and docs/ runs, and passes.

Each Markdown file's fenced blocks whose info string is `python` run in
order, in one namespace per file, from the repository's root: a page reads
as one program. A block marked `python notest` (one that needs a GPU, a
headless OpenGL, several devices or minutes of training) is only compiled,
so its syntax is checked; the page says that it is not run. Fences must
start at the line's first column.

Expected output. A comment `# -> TEXT` at the end of a top-level statement
says what it shows: for a statement that prints (a `print(...)` call, or a
loop that prints), TEXT is what it prints, its final newline dropped; for
an expression statement that does not print, TEXT is the `repr` of its
value. Lines right after the statement holding only `# -> MORE` continue
TEXT on new lines, or start it (a long or several-line output). The
comparison is exact.
A `# ->` comment anywhere else (in a `notest` block, inside a statement, not
after one) is an error, as is a comment after a `print(...)` that is not
one: explanations go before the statement or in the prose.
"""

import ast
import contextlib
import io
import pathlib
import re
import tokenize

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
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


_EXPECTED = re.compile(r'#\s*->\s?(?P<text>.*)$')


def _comments(code):
  """`{line in the block (1-based): (comment, whether code precedes it)}`."""
  comments = {}
  lines = code.splitlines()
  for token in tokenize.generate_tokens(io.StringIO(code).readline):
    if token.type == tokenize.COMMENT:
      row, column = token.start
      comments[row] = (token.string, bool(lines[row - 1][:column].strip()))
  return comments


def expected_outputs(path, line, code):
  """The statements of a block with their expected output.

  Returns:
    `(statements, expectations)`: the block's top-level statements (`ast`
    nodes, numbered by Markdown line) and `{statement index: TEXT}`.

  Raises:
    AssertionError: a `# ->` comment that is not at the end of a top-level
      statement or on the lines right after it, or a comment after a
      `print(...)` call that is not a `# ->` one.
  """
  tree = ast.parse('\n' * (line - 1) + code, str(path))
  comments = _comments(code)
  where = lambda row: f'{path}:{row + line - 1}'
  ends = {stmt.end_lineno - line + 1: i for i, stmt in enumerate(tree.body)}
  expectations, claimed = {}, set()
  for end, index in ends.items():
    comment = comments.get(end)
    text = []
    if comment and comment[1] and _EXPECTED.match(comment[0]):
      text.append(_EXPECTED.match(comment[0]).group('text'))
      claimed.add(end)
    row = end + 1
    while row in comments and not comments[row][1]:
      more = _EXPECTED.match(comments[row][0].strip())
      if not more:
        break
      text.append(more.group('text'))
      claimed.add(row)
      row += 1
    if text:
      expectations[index] = '\n'.join(text)
  lines = code.splitlines()
  for row, (comment, after_code) in comments.items():
    if _EXPECTED.match(comment) and row not in claimed:
      raise AssertionError(
          f'{where(row)}: a `# ->` comment belongs at the end of a top-level '
          'statement, or on the lines right after it'
      )
    if after_code and not _EXPECTED.match(comment):
      if re.match(r'\s*print\(', lines[row - 1]):
        raise AssertionError(
            f'{where(row)}: a comment after print(...) must be its expected '
            'output, `# -> TEXT`; put explanations before the statement'
        )
  return tree.body, expectations


def _run_block(path, line, code, namespace):
  """Runs a block's statements in turn, checking their expected output."""
  statements, expectations = expected_outputs(path, line, code)
  for index, statement in enumerate(statements):
    expected = expectations.get(index)
    printed = io.StringIO()
    value = None
    with contextlib.redirect_stdout(printed):
      if expected is not None and isinstance(statement, ast.Expr):
        value = eval(  # pylint: disable=eval-used
            compile(ast.Expression(statement.value), str(path), 'eval'),
            namespace,
        )
      else:
        exec(  # pylint: disable=exec-used
            compile(ast.Module([statement], []), str(path), 'exec'), namespace
        )
    print(printed.getvalue(), end='')
    if expected is None:
      continue
    shown = printed.getvalue()
    shown = shown[:-1] if shown.endswith('\n') else shown
    if not shown and isinstance(statement, ast.Expr):
      shown = repr(value)
    assert shown == expected, (
        f'{path}:{statement.end_lineno}: the comment says {expected!r}, '
        f'the statement shows {shown!r}'
    )


_RUN = [
    path for path in markdown_files() if any(r for *_, r in python_blocks(path))
]


@pytest.mark.parametrize('path', markdown_files(), ids=str)
def test_blocks_compile(path):
  """Every Python block, run or not, is valid Python; only blocks that run
  say what they show."""
  for line, code, run in python_blocks(path):
    _compiled(path, line, code)
    if not run:
      for row, (comment, _) in _comments(code).items():
        assert not _EXPECTED.match(comment), (
            f'{path}:{row + line - 1}: a `python notest` block is not run: '
            'its `# ->` comment would never be checked'
        )


@pytest.mark.parametrize('path', _RUN, ids=str)
def test_blocks_run(path, monkeypatch):
  """A file's runnable blocks run in order in one namespace, without error,
  and show what their `# ->` comments say."""
  monkeypatch.chdir(ROOT)
  namespace = {'__name__': f'docs_{path.stem}'}
  for line, code, run in python_blocks(path):
    if not run:
      continue
    try:
      _run_block(path, line, code, namespace)
    except Exception as e:
      raise AssertionError(f'{path}, the block at line {line} failed') from e


def test_pages_have_runnable_blocks():
  """The README and the getting-started guide run (not all `notest`)."""
  assert pathlib.Path('README.md') in _RUN
  assert pathlib.Path('docs/getting-started.md') in _RUN


def test_expected_output_comments_are_compared():
  """The checker itself: right comments pass, wrong or misplaced ones fail."""
  run = lambda code: _run_block(pathlib.Path('page.md'), 1, code, {})
  run(
      'x = [1, 2]\n'
      'print(len(x))  # -> 2\n'
      'x  # -> [1, 2]\n'
      'for i in x:\n'
      '  print(i)\n'
      '# -> 1\n'
      '# -> 2\n'
      'print("a")\n'
      '# -> a\n'
  )
  with pytest.raises(AssertionError, match="says '3'.*shows '2'"):
    run('print(1 + 1)  # -> 3\n')
  with pytest.raises(AssertionError, match="says '2'.*shows '1'"):
    run('1  # -> 2\n')
  for misplaced in ('x = (\n    1  # -> 1\n)\n', 'x = 2\n\n# -> 2\n'):
    with pytest.raises(AssertionError, match='end of a top-level statement'):
      run(misplaced)
  with pytest.raises(AssertionError, match='must be its expected output'):
    run('print(1)  # one\n')
