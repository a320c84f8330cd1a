"""`mjx_composer.__version__`: pyproject.toml's version, read from metadata."""

import importlib.metadata
import pathlib

import pytest

import mjx_composer

PYPROJECT = pathlib.Path(__file__).resolve().parents[2] / 'pyproject.toml'


def test_the_version_is_the_installed_distributions():
  assert mjx_composer.__version__ == importlib.metadata.version('mjx-composer')


def test_the_installed_version_is_pyproject_tomls():
  """The number is written once, in pyproject.toml (a stale install of an
  older checkout fails here: reinstall it)."""
  tomllib = pytest.importorskip('tomllib')  # Python 3.11 and later
  project = tomllib.loads(PYPROJECT.read_text())['project']
  assert project['name'] == mjx_composer._DISTRIBUTION
  assert mjx_composer._version() == project['version']


def test_an_uninstalled_checkout_says_its_version_is_unknown(monkeypatch):
  def not_installed(name):
    raise importlib.metadata.PackageNotFoundError(name)

  monkeypatch.setattr(importlib.metadata, 'version', not_installed)
  assert mjx_composer._version() == '0+unknown'
