"""Sharding and the compilation cache refuse what they cannot use safely."""

import re

import numpy as np
import pytest

from tests import conftest

# -- sharding: arrays on other devices than the program's mesh ---------------

_SHARDING_SCRIPT = r"""
import json
import jax
import numpy as np
from mjx_composer.platform import sharding

d = jax.devices()
a, b = sharding.world_mesh(d[:2]), sharding.world_mesh(d[2:])
program = sharding.per_device(lambda states, actions: states + actions, a)
x = np.arange(12, dtype=np.float32).reshape(4, 3)
on = lambda mesh: sharding.put_worlds(x, mesh)
cases = {
    'states_of_another_mesh': (on(b), on(a)),
    'both_of_another_mesh': (on(b), on(b)),
    'actions_on_one_device': (on(a), jax.device_put(x, d[0])),
    'actions_on_every_device': (on(a), on(sharding.world_mesh(d))),
    'numpy_actions': (on(a), x),
    'placed': (on(a), on(a)),
}
out = {}
for name, args in cases.items():
  try:
    out[name] = np.asarray(program(*args)).tolist()
  except ValueError as error:
    out[name] = str(error)
try:
  program.lower(on(b), on(a))
  out['lower'] = 'lowered'
except ValueError as error:
  out['lower'] = str(error)
print(json.dumps(out))
"""


def test_a_program_refuses_arrays_of_another_mesh(tmp_path):
  """jax.jit said "Received incompatible devices", naming no fix."""
  out = conftest.run_script(
      _SHARDING_SCRIPT,
      None,
      tmp_path,
      env={'XLA_FLAGS': '--xla_force_host_platform_device_count=4'},
  )
  expected = (np.arange(12).reshape(4, 3) * 2).tolist()
  assert out['placed'] == expected
  assert out['numpy_actions'] == expected  # jax.jit moves numpy arrays.
  for name, where, devices in [
      ('states_of_another_mesh', r'args\[0\]', r'\[2, 3\]'),
      ('both_of_another_mesh', r'args\[0\]', r'\[2, 3\]'),
      ('actions_on_one_device', r'args\[1\]', r'\[0\]'),
      ('actions_on_every_device', r'args\[1\]', r'\[0, 1, 2, 3\]'),
      ('lower', r'args\[0\]', r'\[2, 3\]'),
  ]:
    assert re.search(
        rf'{where} is on devices {devices}, but this program runs on the '
        r'devices \[0, 1\] of its mesh: .*sharding.put_worlds',
        out[name],
    ), (name, out[name])


def test_a_mesh_of_no_devices_is_refused_naming_the_fix():
  """check_num_worlds divided by the device count: a ZeroDivisionError."""
  import jax  # pylint: disable=g-import-not-at-top

  import mjx_composer as composer  # pylint: disable=g-import-not-at-top
  from mjx_composer.platform import sharding  # pylint: disable=g-import-not-at-top
  from tests.package.bad_inputs import common  # pylint: disable=g-import-not-at-top

  empty = jax.sharding.Mesh(np.array([], dtype=object), (sharding.WORLD_AXIS,))
  assert empty.size == 0  # JAX builds it without complaint.
  for use in [
      lambda: sharding.check_num_worlds(4, empty),
      lambda: sharding.world_sharding(empty),
      lambda: sharding.per_device(lambda x: x, empty),
      lambda: sharding.put_worlds(np.zeros((4, 1)), empty),
      lambda: composer.HostEnvironment(
          common.pendulum_environment(), num_worlds=4, mesh=empty
      ),
  ]:
    with pytest.raises(
        ValueError,
        match=r'The mesh has no devices.*sharding.world_mesh\(\)',
    ):
      use()
  for use in [
      lambda: sharding.world_mesh([]),
      lambda: composer.HostEnvironment(
          common.pendulum_environment(), num_worlds=4, mesh=[]
      ),
  ]:
    with pytest.raises(
        ValueError, match=r'world_mesh: `devices` is empty.*jax.devices\(\)'
    ):
      use()
  one = sharding.world_mesh(jax.devices()[:1])
  assert sharding.check_num_worlds(4, one) == 4


# -- the persistent compilation cache ----------------------------------------

_CACHE_SCRIPT = r"""
import json, sys, warnings
import jax
import jax.numpy as jnp

hits = []
jax.monitoring.register_event_listener(
    lambda event, **kwargs: hits.append(event)
    if event == '/jax/compilation_cache/cache_hits' else None)

from mjx_composer.platform import compilation_cache

with warnings.catch_warnings(record=True) as caught:
  warnings.simplefilter('always')
  path = compilation_cache.enable(sys.argv[1] and json.loads(sys.argv[1]),
                                  min_compile_time_secs=0.0)
  f = jax.jit(lambda x: jnp.sin(x) * 3.0 + jnp.cos(x) ** 2)
  f(jnp.arange(7.0)).block_until_ready()
print(json.dumps({'path': path, 'hits': len(hits),
                  'warnings': [str(w.message) for w in caught]}))
"""


def _cache_run(tmp_path, folder):
  return conftest.run_script(
      _CACHE_SCRIPT,
      str(folder),
      tmp_path,
      drop=('MJX_COMPOSER_CACHE_DIR', 'JAX_COMPILATION_CACHE_DIR'),
  )


@pytest.mark.parametrize(
    'mode, reason',
    [
        (0o777, 'can be written by everyone (mode 777)'),
        (0o1777, 'can be written by everyone (mode 1777)'),
        (0o770, 'can be written by its group (mode 770)'),
        (0o700, None),
        (0o755, None),
    ],
)
def test_unsafe_cache_folders_are_recognised(tmp_path, mode, reason):
  from mjx_composer.platform import compilation_cache  # pylint: disable=g-import-not-at-top

  tmp_path.chmod(mode)
  assert compilation_cache.unsafe_folder_reason(str(tmp_path)) == reason


def test_a_cache_folder_others_can_write_is_refused(tmp_path):
  folder = tmp_path / 'shared_cache'
  folder.mkdir()
  folder.chmod(0o777)
  out = _cache_run(tmp_path, folder)
  assert out['path'] is None
  assert not list(folder.iterdir())
  (message,) = [w for w in out['warnings'] if 'compilation cache' in w]
  assert re.search(
      rf'No persistent compilation cache: {re.escape(str(folder))} can be '
      r'written by everyone \(mode 777\), and JAX runs whatever a cache '
      r'entry holds.*chmod 700',
      message,
  ), message


def test_a_corrupted_cache_entry_is_removed_and_written_afresh(tmp_path):
  folder = tmp_path / 'cache'
  first = _cache_run(tmp_path, folder)
  assert first['path'] == str(folder) and first['hits'] == 0
  entries = sorted(folder.glob('*-cache'))
  assert entries
  for entry in entries:  # Writes cut short, within the key's header.
    entry.write_bytes(entry.read_bytes()[:100])
  repaired = _cache_run(tmp_path, folder)
  assert repaired['hits'] == 0
  removed = [
      w
      for w in repaired['warnings']
      if 'Removed the compilation cache entry' in w and 'cut short' in w
  ]
  assert len(removed) == len(entries), repaired['warnings']
  assert all(any(e.name in w for w in removed) for e in entries)
  # Written afresh by the compilations, and loaded by the next process.
  assert all(e.stat().st_size > 100 for e in entries)
  again = _cache_run(tmp_path, folder)
  assert again['hits'] == len(entries) and not again['warnings']
