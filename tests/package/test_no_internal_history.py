"""The repository speaks to its users: no internal history in tracked files.

How the code got here lives in commit messages. Tracked files must not name
the team's internal milestones ("stop" or "issue" and a number), name the GPU
models that measurements ran on inside the package's docstrings and comments
(they belong with their figures in docs/performance.md), or point outside the
repository (`../shared`, `/work/`).
"""

import pathlib
import subprocess

ROOT = pathlib.Path(__file__).resolve().parents[2]
# This file spells the patterns out.
_SELF = f':(exclude){pathlib.Path(__file__).relative_to(ROOT)}'


def _git_grep(pattern, *pathspecs):
  """`git grep -nIE` hits of `pattern` in tracked files, case-insensitive."""
  result = subprocess.run(
      ['git', 'grep', '-nIiE', pattern, '--', *pathspecs, _SELF],
      cwd=ROOT,
      capture_output=True,
      text=True,
      check=False,
  )
  if result.returncode not in (0, 1):  # 1: no hit.
    raise RuntimeError(result.stderr)
  return result.stdout.splitlines()


def _check(hits, what):
  assert not hits, f'{len(hits)} lines {what}:\n' + '\n'.join(hits)


def test_no_internal_milestones():
  _check(
      _git_grep(r'\bstops? [0-9]+|\bissues? [0-9]+', '.'),
      'name internal milestones (say what changed instead)',
  )


def test_no_gpu_models_in_package():
  _check(
      _git_grep(r'\bH[12]00\b', 'mjx_composer/'),
      'of the package name a GPU model (figures belong in docs/performance.md)',
  )


def test_no_paths_outside_repository():
  _check(
      _git_grep(r'\.\./shared|/work/', '.'),
      'point outside the repository',
  )
