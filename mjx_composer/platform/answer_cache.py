"""Answers of the program analyses, kept on disk beside compiled programs.

Building an environment asks MJX's forward pass what its stages read and
write (`runtime.data_reads.PerStructure`): answers that depend only on the
model's structure and on the code that traces it, each a trace of about a
second on a CPU, asked again by every new process. Where JAX's persistent
compilation cache is on (`compilation_cache.enable`, which
`platform.configure` calls), each answer is also kept in that folder's
`FOLDER` subfolder, one small JSON file per question, and a later process
reads it instead of tracing.

A file's name is the SHA-256 digest of the question and of everything else
the answer could depend on (`code_fingerprint`): the sources of this
package and of MJX, and the versions of Python, JAX, jaxlib and MuJoCo.
Editing either package, or upgrading one, asks afresh. The answers are
JSON data (sets of field names), never code; a file that cannot be read or
decoded is ignored, and written afresh by the analysis that follows. The
folder is created private (mode 0700), and neither it nor the compilation
cache's folder is used where others could write to it (`folder`).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib
import importlib.metadata
import json
import os
import pathlib
import pickle
import sys
import tempfile
from typing import Any

import jax

from mjx_composer.platform import compilation_cache

FOLDER = 'mjx_composer-analyses'
# The packages whose Python sources the answers depend on.
_SOURCE_PACKAGES = ('mjx_composer', 'mujoco.mjx')
_VERSIONED = ('jax', 'jaxlib', 'mujoco', 'mujoco-mjx')


def folder(cache_dir: str | None = None) -> str | None:
  """Where answers are kept: `FOLDER` inside `cache_dir` (default: JAX's
  compilation cache folder, where the cache is on). None where there is no
  such folder, or where it or `FOLDER` could be written by others
  (`compilation_cache.unsafe_folder_reason`): an answer planted there
  would change what the programs compute."""
  if cache_dir is None:
    if not compilation_cache.is_enabled():
      return None
    cache_dir = jax.config.jax_compilation_cache_dir
  where = os.path.join(cache_dir, FOLDER)
  try:
    if compilation_cache.unsafe_folder_reason(cache_dir):
      return None
    if os.path.isdir(where) and compilation_cache.unsafe_folder_reason(where):
      return None
  except OSError:
    return None
  return where


@functools.cache
def code_fingerprint() -> bytes:
  """What an answer depends on besides its question: the sources of this
  package and of MJX (every `.py` file, by path and content) and the
  versions of Python and of the packages that trace (read once a process).
  """
  digest = hashlib.sha256()
  digest.update(sys.version.encode())
  for name in _VERSIONED:
    try:
      version = importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
      version = None
    digest.update(f'{name}={version};'.encode())
  for package in _SOURCE_PACKAGES:
    root = pathlib.Path(importlib.import_module(package).__file__).parent
    for path in sorted(root.rglob('*.py')):
      digest.update(str(path.relative_to(root)).encode() + b'\0')
      digest.update(path.read_bytes() + b'\0')
  return digest.digest()


def question_digest(kind: str, question: Any) -> str | None:
  """The file name of `question`'s answer: a hex SHA-256 digest of the
  code (`code_fingerprint`), `kind` (which analysis asks) and the pickled
  `question` (a tuple that may hold tree structures); None where the
  question cannot be pickled (it is then traced, as without this cache)."""
  try:
    pickled = pickle.dumps(question, protocol=5)
  except (pickle.PicklingError, TypeError, AttributeError):
    return None
  digest = hashlib.sha256(code_fingerprint())
  digest.update(kind.encode() + b'\0')
  digest.update(pickled)
  return digest.hexdigest()


def load(name: str) -> Any:
  """The JSON value kept under `name`, or None (none kept, or unreadable)."""
  where = folder()
  if where is None:
    return None
  try:
    with open(os.path.join(where, name + '.json')) as f:
      return json.load(f)
  except (OSError, ValueError):
    return None


def store(name: str, value: Any) -> None:
  """Keeps the JSON `value` under `name` (atomically; nothing where the
  folder cannot be written: the answer is only not kept)."""
  where = folder()
  if where is None:
    return
  try:
    os.makedirs(where, mode=0o700, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=where, suffix='.tmp')
  except OSError:
    return
  try:
    with os.fdopen(handle, 'w') as f:
      json.dump(value, f)
    os.replace(temporary, os.path.join(where, name + '.json'))
  except OSError:
    with contextlib.suppress(OSError):
      os.remove(temporary)
