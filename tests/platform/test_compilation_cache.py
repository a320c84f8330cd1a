"""`mjx_composer.platform.compilation_cache`: a second process loads what the first
compiled, and the switches turn it off.

JAX's cache settings are process-wide, so every check that enables the
cache runs in a fresh Python process.
"""

import pathlib

import numpy as np

from mjx_composer.platform import compilation_cache
from mjx_composer.platform import internals_jax
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


# Two programs of different signatures, so that each one's entry, loaded
# for the other, would run another program (JAX failed in `safe_zip`
# counting the outputs). `plain` writes the entries as JAX alone does.
_TWO_PROGRAMS_SCRIPT = """
import json, sys, warnings
import jax
import jax.numpy as jnp

hits = []
jax.monitoring.register_event_listener(
    lambda event, **kwargs: hits.append(event)
    if event == '/jax/compilation_cache/cache_hits' else None)

from mjx_composer.platform import compilation_cache

folder, plain = json.loads(sys.argv[1])
if plain:
  jax.config.update('jax_compilation_cache_dir', folder)
  jax.config.update('jax_persistent_cache_min_compile_time_secs', 0.0)
  jax.config.update('jax_persistent_cache_min_entry_size_bytes', -1)
else:
  compilation_cache.enable(folder, min_compile_time_secs=0.0)

@jax.jit
def one(x):
  return jnp.sin(x) * 3.0

@jax.jit
def three(x, y):
  return x + y, x * y, jnp.cos(y)

x = jnp.arange(3.0)
with warnings.catch_warnings(record=True) as caught:
  warnings.simplefilter('always')
  results = [one(x), *three(x, x + 1.0)]
print(json.dumps({
    'results': [r.tolist() for r in results],
    'hits': len(hits),
    'warnings': [str(w.message) for w in caught],
}))
"""


def _run_two_programs(tmp_path, folder, plain=False):
  return conftest.run_script(
      _TWO_PROGRAMS_SCRIPT, [str(folder), plain], tmp_path, drop=_OUR_VARS
  )


def _program_entries(folder):
  one = [p for p in pathlib.Path(folder).glob('jit_one-*-cache')]
  three = [p for p in pathlib.Path(folder).glob('jit_three-*-cache')]
  assert len(one) == 1 and len(three) == 1, _entries(folder)
  return one[0], three[0]


def _key(entry):
  return entry.name[: -len('-cache')]


def _expected_results():
  x = np.arange(3.0)
  return [np.sin(x) * 3.0, x + x + 1.0, x * (x + 1.0), np.cos(x + 1.0)]


def _assert_results(out):
  for got, want in zip(out['results'], _expected_results(), strict=True):
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)


def test_swapped_entries_are_compiled_afresh_not_run(tmp_path):
  """An entry filed under another program's key is removed, not loaded."""
  folder = tmp_path / 'cache'
  first = _run_two_programs(tmp_path, folder)
  _assert_results(first)
  one, three = _program_entries(folder)
  one_bytes, three_bytes = one.read_bytes(), three.read_bytes()
  one.write_bytes(three_bytes)
  three.write_bytes(one_bytes)

  swapped = _run_two_programs(tmp_path, folder)
  _assert_results(swapped)
  removed = [w for w in swapped['warnings'] if 'holds the program of key' in w]
  assert len(removed) == 2, swapped['warnings']
  assert any(one.name in w and _key(three) in w for w in removed)
  assert all('compiles again and is written afresh' in w for w in removed)
  # Written afresh under their own keys: the next process loads both.
  for entry in (one, three):
    header = internals_jax.CACHE_KEY_HEADER + _key(entry).encode() + b'\0'
    assert entry.read_bytes().startswith(header)
  again = _run_two_programs(tmp_path, folder)
  _assert_results(again)
  assert again['hits'] >= 2 and not again['warnings']


def test_entries_written_by_jax_alone_are_compiled_afresh(tmp_path):
  """An entry that names no key may hold any program: it is not loaded."""
  folder = tmp_path / 'cache'
  _assert_results(_run_two_programs(tmp_path, folder, plain=True))
  one, three = _program_entries(folder)
  one_bytes, three_bytes = one.read_bytes(), three.read_bytes()
  one.write_bytes(three_bytes)
  three.write_bytes(one_bytes)

  out = _run_two_programs(tmp_path, folder)
  _assert_results(out)
  unbound = [w for w in out['warnings'] if 'holds no key' in w]
  for entry in (one, three):
    assert any(entry.name in w for w in unbound), out['warnings']
  assert one.read_bytes().startswith(internals_jax.CACHE_KEY_HEADER)
  assert three.read_bytes().startswith(internals_jax.CACHE_KEY_HEADER)
