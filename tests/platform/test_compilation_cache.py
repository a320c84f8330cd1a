"""`mjx_composer.platform.compilation_cache`: a second process loads what the first
compiled, and the switches turn it off.

JAX's cache settings are process-wide, so every check that enables the
cache runs in a fresh Python process.
"""

import pathlib

from mjx_composer.platform import compilation_cache
from tests import conftest

# Enables the cache (writing every program, however fast it compiled), jits
# one small function and prints what happened as JSON.
_SCRIPT = """
import json, sys
import jax
import jax.numpy as jnp

hits = []
jax.monitoring.register_event_listener(
    lambda event, **kwargs: hits.append(event)
    if event == '/jax/compilation_cache/cache_hits' else None)

from mjx_composer.platform import compilation_cache

kwargs = json.loads(sys.argv[1])
path = compilation_cache.enable(**kwargs)
f = jax.jit(lambda x: jnp.sin(x) * 3.0 + jnp.cos(x) ** 2)
f(jnp.arange(7.0)).block_until_ready()
print(json.dumps({
    'path': path,
    'hits': len(hits),
    'enabled': compilation_cache.is_enabled(),
    'jax_dir': jax.config.jax_compilation_cache_dir,
    'min_compile_time_secs': jax.config.jax_persistent_cache_min_compile_time_secs,
    'min_entry_size_bytes': jax.config.jax_persistent_cache_min_entry_size_bytes,
}))
"""

_OUR_VARS = (
    compilation_cache.CACHE_DIR_ENV,
    compilation_cache.SWITCH_ENV,
    'JAX_COMPILATION_CACHE_DIR',
    'JAX_ENABLE_COMPILATION_CACHE',
    'XDG_CACHE_HOME',
)


def _run(tmp_path, env=None, **kwargs):
  """Runs `_SCRIPT` in a fresh process; returns its JSON line."""
  return conftest.run_script(_SCRIPT, kwargs, tmp_path, drop=_OUR_VARS, env=env)


def _entries(path):
  path = pathlib.Path(path)
  return sorted(p.name for p in path.glob('*-cache')) if path.exists() else []


def test_second_process_loads_the_first_ones_program(tmp_path):
  cache = tmp_path / 'cache'
  env = {compilation_cache.CACHE_DIR_ENV: str(cache)}
  first = _run(tmp_path, env, min_compile_time_secs=0.0)
  assert first['path'] == str(cache)
  assert first['enabled'] and first['jax_dir'] == str(cache)
  assert first['hits'] == 0
  written = _entries(cache)
  assert written, 'the first process wrote no cache entry'

  second = _run(tmp_path, env, min_compile_time_secs=0.0)
  assert second['hits'] >= 1, 'the second process compiled again'
  assert _entries(cache) == written


def test_default_folder_and_thresholds(tmp_path):
  out = _run(tmp_path)
  expected = tmp_path / 'xdg' / 'mjx_composer' / 'jax'
  assert out['path'] == str(expected)
  assert expected.is_dir()
  assert expected.stat().st_mode & 0o077 == 0, 'cache folder not private'
  assert out['min_compile_time_secs'] == compilation_cache.MIN_COMPILE_TIME_SECS
  assert out['min_entry_size_bytes'] == -1


def test_environment_variable_switches_it_off(tmp_path):
  cache = tmp_path / 'cache'
  for value in ('0', 'false', 'off'):
    out = _run(
        tmp_path,
        {
            compilation_cache.CACHE_DIR_ENV: str(cache),
            compilation_cache.SWITCH_ENV: value,
        },
        min_compile_time_secs=0.0,
    )
    assert out['path'] is None and out['jax_dir'] is None
    assert not out['enabled']
    assert not cache.exists()


def test_argument_switches_it_off(tmp_path):
  cache = tmp_path / 'cache'
  out = _run(
      tmp_path,
      {compilation_cache.CACHE_DIR_ENV: str(cache)},
      enabled=False,
      min_compile_time_secs=0.0,
  )
  assert out['path'] is None and not out['enabled']
  assert not cache.exists()


def test_a_cache_folder_configured_for_jax_is_kept(tmp_path):
  theirs, ours = tmp_path / 'theirs', tmp_path / 'ours'
  out = _run(
      tmp_path,
      {
          'JAX_COMPILATION_CACHE_DIR': str(theirs),
          compilation_cache.CACHE_DIR_ENV: str(ours),
      },
  )
  assert out['path'] == str(theirs) and out['jax_dir'] == str(theirs)
  assert not ours.exists()
  # Their thresholds too: JAX's defaults, not ours.
  assert out['min_compile_time_secs'] == 1.0


def test_default_cache_dir(monkeypatch, tmp_path):
  monkeypatch.delenv(compilation_cache.CACHE_DIR_ENV, raising=False)
  monkeypatch.setenv('XDG_CACHE_HOME', str(tmp_path))
  assert compilation_cache.default_cache_dir() == str(
      tmp_path / 'mjx_composer' / 'jax'
  )
  monkeypatch.delenv('XDG_CACHE_HOME')
  monkeypatch.setenv('HOME', str(tmp_path / 'home'))
  assert compilation_cache.default_cache_dir() == str(
      tmp_path / 'home' / '.cache' / 'mjx_composer' / 'jax'
  )
  monkeypatch.setenv(compilation_cache.CACHE_DIR_ENV, str(tmp_path / 'mine'))
  assert compilation_cache.default_cache_dir() == str(tmp_path / 'mine')
