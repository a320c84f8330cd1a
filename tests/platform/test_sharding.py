"""`mjx_composer.platform.sharding`: a batch of worlds spread over devices.

The test process has initialised JAX with one CPU device, so every check on
several devices runs in a fresh Python process with forced host devices
(`XLA_FLAGS=--xla_force_host_platform_device_count=N`). Those processes run
this module (`python -m tests.platform.test_sharding <mode> <out>`), build one small
environment and compile each program once:

* `meshes` (4 devices): the same 8 worlds on meshes of 1, 2 and 4 devices,
  on 2 also the reset compiled with GSPMD (`mjx_composer.platform.partitioner`'s
  choice for several GPUs), and the batched host environment on 4;
* `multihost` (2 processes of 2 devices each, through `jax.distributed`);
* `brax` (2 devices): Brax's `ppo.train`, which spreads over local devices
  with its own `pmap`.

What the tests found (CPU, JAX 0.10.2, 8 worlds, 3 steps): 2 devices
against 1, every array of every state bit for bit equal; 4 devices against
1, everything bit for bit (`qpos`, `qvel`, observations, rewards, keys,
per-world model fields) except MJX's `data.qacc` and `data.qacc_warmstart`,
which differed by at most 1.9e-6 (relative 2e-7: one or two float32
roundings) in a few entries. Each device compiles the per-world program for
its own number of worlds (here 8, 4 or 2), and XLA may order a
floating-point reduction differently for another batch size, as between
batch sizes on one device; the solver's warm start carries
such a difference to the next step. So floats are compared at rtol 1e-5
(atol 1e-5) across device counts, integers exactly, and everything bit for
bit where each device holds as many worlds (4 devices in one process against
2 processes of 2 devices).
"""

import fcntl
import json
import os
import pathlib
import pickle
import socket
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
from jax.experimental import multihost_utils
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.platform import internals_jax
from mjx_composer.platform import partitioner
from mjx_composer.platform import sharding
from mjx_composer import variation
from mjx_composer.variation import distributions
from mjx_composer.variation import noises
from tests import conftest

_REPO = pathlib.Path(__file__).resolve().parents[2]
_WORLDS = 8
_STEPS = 3
# Episodes of 2 control steps: the third step auto-resets every world.
_TIME_LIMIT = 0.02
_COLLECTIVES = (
    'all-gather',
    'all-reduce',
    'all-to-all',
    'collective-permute',
    'collective-broadcast',
    'reduce-scatter',
)
_RTOL = 1e-5
_ATOL = 1e-5


class _VariedSwing(conftest.SwingTask):
  """`SwingTask` with per-episode randomized joint damping and ball friction.

  The damping changes the dynamics, and both fields become per-world model
  fields of the `State` (with the variator's persistent entries), so they
  are sharded too.
  """

  def __init__(self):
    super().__init__()
    self.variator = variation.PhysicsVariator()
    scale = noises.Multiplicative(distributions.Uniform(0.5, 2.0))
    self.variator.bind_attributes(self.pendulum.joint, damping=scale)
    self.variator.bind_attributes(self.ball.geom, friction=scale)

  def initialize_episode(self, physics, key):
    variation_key, key = jax.random.split(key)
    physics = self.variator.apply_variations(physics, variation_key)
    return super().initialize_episode(physics, key)


def _make_env(**options):
  return composer.Environment(
      _VariedSwing(),
      time_limit=_TIME_LIMIT,
      options=composer.ExecutionOptions(auto_reset='same_step', **options),
  )


def _actions():
  return np.asarray(
      jax.random.uniform(
          jax.random.key(1), (_STEPS, _WORLDS, 1), minval=-1.0, maxval=1.0
      )
  )


# The key BatchedHostEnvironment(seed=0) splits its first batch of keys from.
def _first_host_key():
  return jax.random.split(jax.random.key(0))[1]


# -- what the worker processes run -------------------------------------------


def _collectives(compiled):
  """How many of each cross-device operation the compiled HLO holds."""
  text = compiled.as_text()
  counts = {}
  for op in _COLLECTIVES:
    # Synchronous `op(` and asynchronous `op-start(` forms.
    counts[op] = text.count(f' {op}(') + text.count(f' {op}-start(')
  return counts


def _flatten(tree):
  """`{path: numpy array}` of a gathered tree (a `State` holds functions in
  its static fields, which do not pickle)."""
  return {
      jax.tree_util.keystr(path): np.asarray(x)
      for path, x in jax.tree_util.tree_leaves_with_path(tree)
  }


def _not_world_sharded(tree, mesh):
  """Paths of non-empty arrays not split over `mesh` along the world axis."""
  expected = sharding.world_sharding(mesh)
  rows = _WORLDS // mesh.devices.size
  bad = []
  for path, x in jax.tree_util.tree_leaves_with_path(tree):
    if x.size == 0:
      continue  # e.g. `act` of a model without activations: no layout
    shards = x.addressable_shards
    if not x.sharding.is_equivalent_to(expected, x.ndim) or any(
        s.data.shape[0] != rows for s in shards
    ):
      bad.append(jax.tree_util.keystr(path))
  return bad


def _trajectory(env, mesh, host_key, read=sharding.gather_worlds):
  """States of `_STEPS` steps of the 8 worlds on `mesh`, and their checks.

  `read` brings a state to the host: every world, or (`local_worlds`) this
  process's worlds.
  """
  reset = sharding.batched_reset(env, mesh)
  step = sharding.batched_step(env, mesh)
  keys = sharding.world_keys(host_key, _WORLDS, mesh)
  states = reset(keys)
  report = {
      'collectives': {'reset': _collectives(reset.lower(keys).compile())},
      'not_world_sharded': _not_world_sharded(states, mesh),
  }
  trajectory = [_flatten(read(states))]
  for t, action in enumerate(_actions()):
    actions = sharding.put_worlds(action, mesh)
    if t == 0:  # the program the calls below use: no second compile
      report['collectives']['step'] = _collectives(
          step.lower(states, actions).compile()
      )
    states = step(states, actions)
    report['not_world_sharded'] += _not_world_sharded(states, mesh)
    trajectory.append(_flatten(read(states)))
  return trajectory, report, states


def _error(fn):
  try:
    fn()
  except ValueError as e:
    return str(e)
  return None


def _worker_meshes(out):
  """One process, 4 devices: meshes of 1, 2 and 4, and the host loop."""
  env = _make_env()
  devices = jax.devices()
  assert len(devices) == 4, devices
  trajectories, reports = {}, {}
  for count in (1, 2, 4):
    mesh = sharding.world_mesh(devices[:count])
    trajectories[count], reports[count], _ = _trajectory(
        env, mesh, _first_host_key()
    )

  # The 2-device reset compiled with GSPMD, as on several GPUs
  # (`mjx_composer.platform.partitioner`): recompiled (JAX keys programs on the
  # partitioner), then called with the same keys. (The reset alone: the
  # step would double this worker's compile time for the same check.)
  mesh = sharding.world_mesh(devices[:2])
  keys = sharding.world_keys(_first_host_key(), _WORLDS, mesh)
  reset = sharding.batched_reset(env, mesh)
  lowered_reset = {}
  for name in ('shardy', 'gspmd'):
    os.environ[partitioner.PARTITIONER_ENV] = name
    lowered_reset[name] = reset.lower(keys).as_text()
  compiled = reset.lower(keys).compile()
  states = reset(keys)
  del os.environ[partitioner.PARTITIONER_ENV]
  trajectories['2_gspmd'] = [_flatten(sharding.gather_worlds(states))]
  reports['2_gspmd'] = {
      'collectives': _collectives(compiled),
      'not_world_sharded': _not_world_sharded(states, mesh),
  }
  reports['lowered_as'] = {
      name: {
          'shardy': 'sdy.manual_computation' in text,
          'gspmd': 'SPMDFullToShardShape' in text,
      }
      for name, text in lowered_reset.items()
  }
  # The 2-device step of a restart that gathers the ended worlds two at a
  # time (`auto_reset_batch`, the default on large batches), with GSPMD: a
  # sort in it aborted GSPMD's compile.
  os.environ[partitioner.PARTITIONER_ENV] = 'gspmd'
  trajectories['2_gspmd_chunks'], reports['2_gspmd_chunks'], _ = _trajectory(
      _make_env(auto_reset_batch=2), mesh, _first_host_key()
  )
  del os.environ[partitioner.PARTITIONER_ENV]

  mesh = sharding.world_mesh()
  # A list of devices makes the same mesh, so the programs compiled above
  # for it are reused.
  host = composer.HostEnvironment(env, num_worlds=_WORLDS, seed=0, mesh=devices)
  assert host.mesh == mesh
  timesteps = [host.reset()]
  host_sharded = _not_world_sharded(host.state, mesh)
  for action in _actions():
    timesteps.append(host.step(action))
  host_sharded += _not_world_sharded(host.state, mesh)

  six = jnp.zeros((6, 1))
  states = host.state
  errors = {
      'put_worlds': _error(lambda: sharding.put_worlds(six, mesh)),
      'world_keys': _error(
          lambda: sharding.world_keys(jax.random.key(0), 6, mesh)
      ),
      'step': _error(
          lambda: sharding.batched_step(env, mesh)(
              jax.tree.map(lambda x: x[:6], states), six
          )
      ),
      'host': _error(
          lambda: composer.HostEnvironment(env, num_worlds=6, mesh=mesh)
      ),
  }
  with open(os.path.join(out, 'meshes.pkl'), 'wb') as f:
    pickle.dump(
        {
            'trajectories': trajectories,
            'host': [
                (np.asarray(t.step_type), t.reward, t.observation)
                for t in timesteps
            ],
        },
        f,
    )
  with open(os.path.join(out, 'meshes.json'), 'w') as f:
    json.dump(
        {
            'reports': reports,
            'host_not_world_sharded': host_sharded,
            'host_mesh_devices': int(host.mesh.devices.size),
            'errors': errors,
        },
        f,
    )


def _coordinator_port(out, process_id, timeout_s=600.0):
  """The coordinator's port: process 0 picks a free one, process 1 reads it.

  Process 0 (which runs the coordination service) picks the port itself,
  moments before the service binds it, and writes it to a file that process
  1 waits for: no port picked by the parent seconds before a child binds it.
  """
  path = os.path.join(out, 'coordinator_port')
  if process_id == 0:
    with socket.socket() as s:
      s.bind(('localhost', 0))
      port = s.getsockname()[1]
    with open(f'{path}.tmp', 'w') as f:
      f.write(str(port))
    os.replace(f'{path}.tmp', path)
    return port
  deadline = time.monotonic() + timeout_s
  while not os.path.exists(path):
    if time.monotonic() > deadline:
      raise TimeoutError(f'process 0 wrote no port to {path}')
    time.sleep(0.05)
  with open(path) as f:
    return int(f.read())


def _worker_multihost(out, process_id):
  """One of 2 processes of 2 devices: 8 worlds over the 4 global devices.

  It reads back its own worlds (no communication) while stepping, and
  gathers every world once at the end, when both processes have compiled
  everything: JAX's CPU collectives (gloo) give up when the other process is
  more than 30 s late to their first collective.
  """
  jax.distributed.initialize(
      coordinator_address=f'localhost:{_coordinator_port(out, process_id)}',
      num_processes=2,
      process_id=process_id,
  )
  assert jax.device_count() == 4 and jax.local_device_count() == 2
  env = _make_env()
  mesh = sharding.world_mesh()
  trajectory, report, states = _trajectory(
      env, mesh, _first_host_key(), read=sharding.local_worlds
  )
  report['process_devices'] = [d.process_index for d in mesh.devices.flat]
  report['local_rows'] = len(trajectory[-1]['.step_type'])
  # Every world on every process (an all-gather), and the local rows joined
  # back into one batch. Gloo gives up on a process 30 s late to the first
  # collective, and compiling the gather can take that long on a busy CPU:
  # so the processes meet at the coordination service's barrier (which
  # waits as long as it takes), then connect with a collective that
  # compiles in a moment; a connected collective waits for the other
  # process however long its compile takes.
  internals_jax.wait_for_processes('test_sharding_gather', 1800.0)
  multihost_utils.sync_global_devices('test_sharding_connect')
  gathered = _flatten(sharding.gather_worlds(states))
  local = sharding.local_worlds(states.observation['tip'])
  rejoined = sharding.gather_worlds(sharding.put_local_worlds(local, mesh))
  report['rejoined_equal'] = bool(
      np.array_equal(rejoined, gathered[".observation['tip']"])
  )
  with open(os.path.join(out, f'multihost_{process_id}.pkl'), 'wb') as f:
    pickle.dump(
        {'trajectory': trajectory, 'gathered': gathered, 'report': report}, f
    )


def _worker_brax(out):
  """Brax's PPO on 2 devices (its pmap), a few updates, no evaluation."""
  # pylint: disable=g-import-not-at-top
  import functools

  from brax.training.agents.ppo import networks as ppo_networks
  from brax.training.agents.ppo import train as ppo

  from mjx_composer.adapters import brax as brax_adapter

  # pylint: enable=g-import-not-at-top
  assert jax.local_device_count() == 2
  brax_env = brax_adapter.BraxEnv(
      conftest.make_swing_env(
          time_limit=0.03,
          options=composer.ExecutionOptions(auto_reset='same_step'),
      ),
      obs_key='tip',
  )
  progress = []
  _, params, _ = ppo.train(
      environment=brax_env,
      num_timesteps=32,
      num_envs=4,  # 2 per device
      batch_size=2,
      num_minibatches=4,
      unroll_length=2,
      num_updates_per_batch=1,
      learning_rate=1e-3,
      num_evals=2,
      run_evals=False,  # the evaluator runs on one device: not ours to test
      max_devices_per_host=2,
      seed=0,
      network_factory=functools.partial(
          ppo_networks.make_ppo_networks,
          policy_hidden_layer_sizes=(8,),
          value_hidden_layer_sizes=(8,),
      ),
      progress_fn=lambda step, metrics: progress.append(
          (int(step), float(metrics['training/sps']))
      ),
      **brax_adapter.training_kwargs(brax_env),
  )
  finite = all(
      bool(np.all(np.isfinite(x))) for x in jax.tree.leaves(params[1:])
  )
  with open(os.path.join(out, 'brax.json'), 'w') as f:
    json.dump({'progress': progress, 'finite': finite}, f)


def _main(argv):
  from mjx_composer.platform import compilation_cache  # pylint: disable=g-import-not-at-top

  # As the test suite does (conftest): a rerun loads the programs.
  compilation_cache.enable()
  mode, out = argv[0], argv[1]
  if mode == 'meshes':
    _worker_meshes(out)
  elif mode == 'multihost':
    _worker_multihost(out, int(argv[2]))
  elif mode == 'brax':
    _worker_brax(out)
  else:
    raise ValueError(f'Unknown mode {mode!r}.')


# -- running the workers -----------------------------------------------------


def _worker_env(devices):
  env = dict(os.environ)
  env['JAX_PLATFORMS'] = 'cpu'
  env['XLA_FLAGS'] = ' '.join(
      [
          env.get('XLA_FLAGS', ''),
          f'--xla_force_host_platform_device_count={devices}',
      ]
  ).strip()
  env['PYTHONPATH'] = os.pathsep.join(
      [str(_REPO)] + [p for p in [os.environ.get('PYTHONPATH')] if p]
  )
  return env


def _start(devices, *args):
  return subprocess.Popen(
      [sys.executable, '-m', 'tests.platform.test_sharding', *map(str, args)],
      env=_worker_env(devices),
      cwd=_REPO,
      stdout=subprocess.PIPE,
      stderr=subprocess.STDOUT,
      text=True,
  )


def _finish(process, timeout=900):
  try:
    output, _ = process.communicate(timeout=timeout)
  except subprocess.TimeoutExpired:
    process.kill()
    output, _ = process.communicate()
  assert process.returncode == 0, output[-6000:]


@pytest.fixture(scope='module')
def meshes(tmp_path_factory):
  """What the `meshes` worker found; run once per test run.

  Under pytest-xdist, tests of this module may run in several workers, each
  setting up this fixture: the first runs the worker process, in a folder
  all workers of the run share (the parent of their temporary folders), and
  the others wait on a lock and read what it wrote.
  """
  if 'PYTEST_XDIST_WORKER' in os.environ:
    out = tmp_path_factory.getbasetemp().parent / 'sharding_meshes'
    out.mkdir(exist_ok=True)
    with open(out / 'lock', 'w') as lock:
      fcntl.flock(lock, fcntl.LOCK_EX)
      if not (out / 'meshes.json').exists():
        _finish(_start(4, 'meshes', out))
  else:
    out = tmp_path_factory.mktemp('meshes')
    _finish(_start(4, 'meshes', out))
  with open(out / 'meshes.pkl', 'rb') as f:
    data = pickle.load(f)
  with open(out / 'meshes.json') as f:
    data.update(json.load(f))
  return data


def _assert_same(reference, other, exact, label):
  """Every array of every state equal: floats within rtol unless `exact`."""
  for t, (a, b) in enumerate(zip(reference, other, strict=True)):
    assert list(a) == list(b)
    for path in a:
      x, y = a[path], b[path]
      message = f'{label}, state {t}, {path}'
      if exact or not np.issubdtype(x.dtype, np.floating):
        np.testing.assert_array_equal(x, y, err_msg=message)
      else:
        np.testing.assert_allclose(
            x, y, rtol=_RTOL, atol=_ATOL, err_msg=message
        )


# -- tests in this process (one device) ---------------------------------------


def test_world_mesh_and_sharding_on_the_default_devices():
  mesh = sharding.world_mesh()
  assert mesh.axis_names == ('worlds',)
  assert list(mesh.devices.flat) == jax.devices()
  spec = sharding.world_sharding(mesh).spec
  assert spec == jax.sharding.PartitionSpec('worlds')


def test_put_and_gather_keep_values_and_keys():
  keys = jax.random.split(jax.random.key(3), 4)
  tree = {'x': np.arange(8.0).reshape(4, 2), 'key': keys}
  placed = sharding.put_worlds(tree)
  assert placed['key'].dtype == keys.dtype
  back = sharding.gather_worlds(placed)
  np.testing.assert_array_equal(back['x'], tree['x'])
  np.testing.assert_array_equal(back['key'], jax.random.key_data(keys))
  np.testing.assert_array_equal(sharding.local_worlds(placed)['x'], tree['x'])
  joined = sharding.put_local_worlds(sharding.local_worlds(placed))
  np.testing.assert_array_equal(sharding.gather_worlds(joined)['x'], tree['x'])


def test_a_batch_needs_one_world_axis():
  with pytest.raises(ValueError, match='leading world axis of the same size'):
    sharding.put_worlds({'a': np.zeros((4, 2)), 'b': np.zeros((3,))})
  with pytest.raises(ValueError, match='None: a scalar'):
    sharding.count_worlds({'a': np.zeros((4,)), 'b': np.float32(0)})


def test_a_mesh_without_the_world_axis_is_refused():
  mesh = jax.sharding.Mesh(np.array(jax.devices()), ('batch',))
  with pytest.raises(ValueError, match="a 'worlds' axis"):
    sharding.world_sharding(mesh)
  with pytest.raises(ValueError, match='listed twice'):
    sharding.world_mesh(jax.devices() * 2)


def test_single_world_host_environment_refuses_a_mesh():
  env = conftest.make_swing_env(time_limit=0.05)
  with pytest.raises(ValueError, match='Pass num_worlds for a batch'):
    composer.HostEnvironment(env, mesh=sharding.world_mesh())


def test_a_warp_batch_is_not_split_over_devices():
  """Warp's batch-shared contact buffer cannot be cut along the worlds."""
  env = conftest.make_swing_env(
      time_limit=0.05, options=composer.ExecutionOptions(impl='warp')
  )
  # Two entries of this process's one device: only the mesh's size matters.
  two = jax.sharding.Mesh(np.array(jax.devices() * 2), (sharding.WORLD_AXIS,))
  for build in (sharding.batched_reset, sharding.batched_step):
    with pytest.raises(NotImplementedError, match="impl='jax'"):
      build(env, two)
  # One device: nothing is split.
  one = sharding.world_mesh(jax.devices()[:1])
  assert sharding.batched_reset(env, one) is sharding.batched_reset(env, one)


# -- 1, 2 and 4 devices in one process ----------------------------------------


def test_a_worlds_trajectory_does_not_depend_on_the_device_count(meshes):
  reference = meshes['trajectories'][1]
  # The second step ended every episode (LAST, auto-reset in the same step),
  # so the third stepped the next episode's randomized worlds.
  np.testing.assert_array_equal(reference[2]['.step_type'], 2)
  np.testing.assert_array_equal(reference[3]['.step_type'], 1)
  for count in (2, 4):
    _assert_same(
        reference, meshes['trajectories'][count], False, f'{count} devices'
    )


def test_gspmd_compiles_the_same_worlds(meshes):
  # Each lowering is the partitioner's own: Shardy's manual computation or
  # GSPMD's full-to-shard conversion.
  assert meshes['reports']['lowered_as'] == {
      'shardy': {'shardy': True, 'gspmd': False},
      'gspmd': {'shardy': False, 'gspmd': True},
  }
  # The reset states (randomized model fields, the forward pass,
  # observations) bit for bit.
  _assert_same(
      meshes['trajectories'][2][:1],
      meshes['trajectories']['2_gspmd'],
      True,
      'GSPMD on 2 devices',
  )
  assert meshes['reports']['2_gspmd']['not_world_sharded'] == []
  counts = meshes['reports']['2_gspmd']['collectives']
  assert not any(counts.values()), counts


def test_gspmd_compiles_a_restart_in_chunks(meshes):
  # Every episode ends at the second step: each device restarts its four
  # worlds two at a time.
  _assert_same(
      meshes['trajectories'][1],
      meshes['trajectories']['2_gspmd_chunks'],
      False,
      'GSPMD on 2 devices, restarts in chunks',
  )
  report = meshes['reports']['2_gspmd_chunks']
  assert report['not_world_sharded'] == []
  for program, counts in report['collectives'].items():
    assert not any(counts.values()), (program, counts)


def test_states_stay_sharded_over_the_world_axis(meshes):
  for count in ('1', '2', '4'):
    assert meshes['reports'][count]['not_world_sharded'] == [], count


def test_per_world_programs_hold_no_collective(meshes):
  for count in ('1', '2', '4'):
    for program in ('reset', 'step'):
      counts = meshes['reports'][count]['collectives'][program]
      assert set(counts) == set(_COLLECTIVES)
      assert not any(counts.values()), (count, program, counts)


def test_worlds_that_do_not_split_over_the_devices_say_what_to_do(meshes):
  errors = meshes['errors']
  for name in ('put_worlds', 'world_keys', 'step', 'host'):
    assert errors[name] is not None, name
    assert errors[name].startswith(
        '6 worlds cannot be split evenly over the 4 devices of the mesh: use '
        'a multiple of 4 worlds (e.g. 8), or a mesh of fewer devices, such as '
        'world_mesh(jax.devices()[:3]).'
    ), errors[name]


def test_sharded_host_environment_steps_the_same_worlds(meshes):
  assert meshes['host_mesh_devices'] == 4
  assert meshes['host_not_world_sharded'] == []
  # Same program, same keys and actions as the 4-device trajectory.
  for t, (step_type, reward, observation) in enumerate(meshes['host']):
    state = meshes['trajectories'][4][t]
    np.testing.assert_array_equal(step_type, state['.step_type'])
    np.testing.assert_array_equal(reward, state['.reward'])
    for key, value in observation.items():
      np.testing.assert_array_equal(value, state[f".observation['{key}']"])


# -- 2 processes of 2 devices -------------------------------------------------


def test_two_processes_step_the_same_worlds(meshes, tmp_path):
  workers = [_start(2, 'multihost', tmp_path, i) for i in (0, 1)]
  for worker in workers:
    _finish(worker)
  results = []
  for i in (0, 1):
    with open(tmp_path / f'multihost_{i}.pkl', 'rb') as f:
      results.append(pickle.load(f))
  for result in results:
    report = result['report']
    assert report['process_devices'] == [0, 0, 1, 1]
    assert report['not_world_sharded'] == []
    for program in ('reset', 'step'):
      assert not any(report['collectives'][program].values()), report
    assert report['local_rows'] == _WORLDS // 2
    assert report['rejoined_equal']
  # Process p holds worlds [4p, 4p + 4).
  trajectory = [
      {path: np.concatenate([a[path], b[path]]) for path in a}
      for a, b in zip(results[0]['trajectory'], results[1]['trajectory'])
  ]
  # 2 worlds per device, as with 4 devices in one process: bit for bit.
  _assert_same(meshes['trajectories'][4], trajectory, True, 'two processes')
  _assert_same(
      meshes['trajectories'][1], trajectory, False, 'two processes, 1 device'
  )
  for result in results:
    _assert_same(trajectory[-1:], [result['gathered']], True, 'all-gather')


# -- Brax -------------------------------------------------------------------------


def test_brax_ppo_trains_on_two_devices(tmp_path):
  _finish(_start(2, 'brax', tmp_path))
  with open(tmp_path / 'brax.json') as f:
    result = json.load(f)
  assert result['finite']
  assert result['progress'] and result['progress'][-1][0] >= 32


if __name__ == '__main__':
  _main(sys.argv[1:])
