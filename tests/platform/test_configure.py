"""`platform.configure()` and what importing `mjx_composer` sets.

JAX's settings are process-wide, so each check runs in a fresh process.
"""

import pytest

from mjx_composer.platform import compilation_cache
from mjx_composer.platform import cpu_linalg
from mjx_composer.platform import prng_lowering
from tests import conftest

# Imports the package, reports the Cholesky lowering, then (unless told not
# to) calls `configure` and reports what it set, as JSON.
_SCRIPT = """
import json, sys
import jax
import jax.numpy as jnp

import mjx_composer
from mjx_composer import platform

def lapack():
  a = jnp.eye(3)[None]
  return 'lapack' in jax.jit(jax.vmap(jnp.linalg.cholesky)).lower(a).as_text()

report = {'lapack_after_import': lapack()}
argument = json.loads(sys.argv[1])
if argument != 'skip':
  report['cache_dir'] = platform.configure(argument)
  report['threefry_kernel'] = bool(jax.config.jax_threefry_gpu_kernel_lowering)
  report['lapack_after_configure'] = lapack()
print(json.dumps(report))
"""

_OUR_VARS = (
    compilation_cache.CACHE_DIR_ENV,
    compilation_cache.SWITCH_ENV,
    cpu_linalg.SWITCH_ENV,
    prng_lowering.SWITCH_ENV,
    prng_lowering.FLAG.upper(),
    'JAX_COMPILATION_CACHE_DIR',
    'JAX_ENABLE_COMPILATION_CACHE',
)


def _run(tmp_path, argument, **env):
  return conftest.run_script(
      _SCRIPT, argument, tmp_path, drop=_OUR_VARS, env=env
  )


def test_importing_the_package_lowers_cholesky_without_lapack(tmp_path):
  assert _run(tmp_path, 'skip') == {'lapack_after_import': False}


def test_the_environment_keeps_lapack_at_import(tmp_path):
  report = _run(tmp_path, 'skip', **{cpu_linalg.SWITCH_ENV: '0'})
  assert report == {'lapack_after_import': True}


@pytest.mark.parametrize('argument', [None, True, False, 'folder'])
def test_configure_switches_the_three_settings_on(tmp_path, argument):
  default = tmp_path / 'xdg' / 'mjx_composer' / 'jax'
  if argument == 'folder':
    argument = str(tmp_path / 'folder')
    expected = argument
  else:
    expected = None if argument is False else str(default)
  report = _run(tmp_path, argument)
  assert report == {
      'lapack_after_import': False,
      'cache_dir': expected,
      'threefry_kernel': True,
      'lapack_after_configure': False,
  }


def test_configure_obeys_the_environment(tmp_path):
  report = _run(
      tmp_path,
      None,
      **{
          compilation_cache.SWITCH_ENV: 'off',
          prng_lowering.SWITCH_ENV: 'off',
          cpu_linalg.SWITCH_ENV: 'off',
      },
  )
  assert report == {
      'lapack_after_import': True,
      'cache_dir': None,
      'threefry_kernel': False,
      'lapack_after_configure': True,
  }
