"""`Environment(impl='warp')`: MuJoCo Warp against MJX's JAX implementation.

One Warp environment (the bundled reach task, randomized per world) is
compiled for the module: MuJoCo Warp compiles its kernels per model, so
every Warp test here shares the reach model's. Its reset is checked against
the JAX implementation's, built as `test_tasks_reach.py` builds it (the
same batched reset program, which the persistent compilation cache holds
when that test ran first); its steps against MuJoCo's C library on the
host, world by world with each world's own model (a JAX step program would
add a minute of compiling on CI's CPU).
"""

import copy

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer import environment
from mjx_composer.platform import backend
from mjx_composer.platform import impl_choice
from mjx_composer.platform import internals
from mjx_composer.platform import shared_buffers
from mjx_composer.suite.tasks import joystick
from mjx_composer.suite.tasks import push
from mjx_composer.suite.tasks import reach
from tests import conftest

WORLDS = 8
STEPS = 3
# Warp runs float32, MuJoCo float64, and the constraint solvers stop at
# the same tolerance from different iterates: after 3 control steps of 5
# sub-steps positions agree to 1.3e-8 and velocities to 1.9e-7 (measured),
# so ATOL keeps three orders of magnitude of margin; the arm moves 7.5e-3
# or more in that time, and a wrong gear or mass (reach varies them by up
# to 20-30%) moves it by more than ATOL.
ATOL = 1e-5


@pytest.fixture(scope='module')
def warp_env():
  # max_reset_attempts=2: the reset's retry loop, whose carry must leave
  # Warp's batch-shared contact buffer out (`shared_buffers.drop_shared`).
  return environment.Environment(
      reach.Reach(),
      time_limit=0.1,
      max_reset_attempts=2,
      options=composer.ExecutionOptions(impl='warp', naconmax=16 * WORLDS),
  )


@pytest.fixture(scope='module')
def warp_fns(warp_env):
  return {
      'reset': jax.jit(jax.vmap(warp_env.reset)),
      'step': jax.jit(jax.vmap(warp_env.step)),
  }


def test_warp_resets_the_whole_batch(warp_env):
  # Its contact buffer is shared by the batch: 'auto' gathers nothing.
  assert warp_env.auto_reset_batch is None


@pytest.fixture(scope='module')
def jax_env():
  # As test_tasks_reach.py builds it: the same reset program.
  return environment.Environment(reach.Reach(), time_limit=0.1)


def _keys():
  return jax.random.split(jax.random.key(0), WORLDS)


def _actions(env):
  shape = (WORLDS,) + env.action_spec().shape
  return jax.random.uniform(jax.random.key(1), shape, minval=-1.0, maxval=1.0)


def _rollout(fns, env):
  states = fns['reset'](_keys())
  trajectory = [states]
  for _ in range(STEPS):
    states = fns['step'](states, _actions(env))
    trajectory.append(states)
  return trajectory


@pytest.fixture(scope='module')
def warp_rollout(warp_env, warp_fns):
  return _rollout(warp_fns, warp_env)


def test_warp_reset_equals_jax_reset(warp_env, warp_rollout, jax_env):
  assert warp_env.impl == 'warp' and jax_env.impl == 'jax'
  warp = warp_rollout[0]
  ref = jax.jit(jax.vmap(jax_env.reset))(_keys())
  # Randomized per world: the same draws, the same derived fields (the
  # compiler runs on MJX's JAX implementation for both).
  assert set(warp.model_fields) == set(ref.model_fields)
  assert 'body_mass' in warp.model_fields
  for name, value in ref.model_fields.items():
    jax.tree.map(
        lambda w, j, name=name: np.testing.assert_allclose(
            np.reshape(w, np.shape(j)), j, rtol=1e-6, atol=1e-7, err_msg=name
        ),
        warp.model_fields[name],
        value,
    )
  np.testing.assert_array_equal(warp.data.qpos, ref.data.qpos)
  jax.tree.map(
      lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5),
      warp.observation,
      ref.observation,
  )
  np.testing.assert_array_equal(backend.overflow(warp.data), 0)
  np.testing.assert_array_equal(warp.metrics['overflow'], 0)
  assert backend.naconmax(warp.data) == 16 * WORLDS
  assert backend.njmax(warp.data) == backend.default_njmax(warp_env.mj_model)


def _host_rollout(env, state, world, actions):
  """World `world` of `state` stepped by MuJoCo (C, float64) on the host.

  With the world's own model: its per-world fields written into a copy of
  the compiled host model.
  """
  m = copy.deepcopy(env.mj_model)
  for name, value in state.model_fields.items():
    if name in ('opt', 'stat'):
      continue  # reach varies no option; the statistics do not step
    field = getattr(m, name)
    field[...] = np.reshape(np.asarray(value)[world], field.shape)
  d = mujoco.MjData(m)
  for name in ('qpos', 'qvel', 'act', 'qacc_warmstart', 'mocap_pos'):
    getattr(d, name)[...] = np.asarray(getattr(state.data, name))[world]
  d.time = float(state.data.time[world])
  for _ in range(STEPS):
    d.ctrl[:] = np.asarray(actions)[world]
    mujoco.mj_step(m, d, env.n_sub_steps)
  return d.qpos.copy(), d.qvel.copy()


def test_warp_steps_agree_with_mujoco(warp_env, warp_rollout):
  """Each world's Warp trajectory against MuJoCo's, with its own model."""
  start, end = warp_rollout[0], warp_rollout[-1]
  assert np.all(np.asarray(end.step_type) == int(environment.StepType.MID))
  actions = _actions(warp_env)
  for world in range(WORLDS):
    qpos, qvel = _host_rollout(warp_env, start, world, actions)
    np.testing.assert_allclose(end.data.qpos[world], qpos, atol=ATOL)
    np.testing.assert_allclose(end.data.qvel[world], qvel, atol=10 * ATOL)
  # The worlds moved: this compares trajectories, not resting arms.
  moved = np.abs(end.data.qpos - start.data.qpos).max(axis=1)
  assert np.all(moved > 1e-3), moved
  np.testing.assert_array_equal(backend.overflow(end.data), 0)
  np.testing.assert_array_equal(end.metrics['overflow'], 0)
  np.testing.assert_array_equal(end.metrics['diverged'], 0)


def test_warp_same_key_same_result(warp_env, warp_fns, warp_rollout):
  again = _rollout(warp_fns, warp_env)
  for first, second in zip(warp_rollout, again):
    jax.tree.map(
        lambda a, b: np.testing.assert_array_equal(
            jax.random.key_data(a)
            if jnp.issubdtype(a.dtype, jax.dtypes.prng_key)
            else a,
            jax.random.key_data(b)
            if jnp.issubdtype(b.dtype, jax.dtypes.prng_key)
            else b,
        ),
        first,
        second,
    )


def test_warp_keeps_the_contact_buffer_shared_by_the_batch(warp_rollout):
  """Warp's contacts are one buffer per batch, never copied per world."""
  data = warp_rollout[-1].data
  assert data.qpos.shape[0] == WORLDS
  contact_dist = internals.data_impl(data).contact__dist
  assert jnp.shape(contact_dist) == (backend.naconmax(data),)
  assert jax.tree.leaves(shared_buffers.shared_leaves(data)).count(True) > 10


def test_warp_overflow_is_reported_until_the_episode_ends(warp_env, warp_fns):
  """`metrics['overflow']`: the world that lost rows, for its episode only."""
  kind = backend._overflow_type()  # pylint: disable=protected-access
  states = warp_fns['reset'](_keys())
  # MuJoCo Warp ORs its flags into the world's bitmask at each step; set
  # them as it would: world 2 dropped constraint rows, world 5 hit the
  # solver's iteration limit (the model's setting, not a lost constraint).
  flags = np.zeros(WORLDS, np.int32)
  flags[2] = int(kind.NEFC)
  flags[5] = int(kind.ITERATIONS)
  dtype = internals.data_impl(states.data).overflow.dtype
  states = states.replace(
      data=internals.replace_data_impl(
          states.data, overflow=jnp.asarray(flags, dtype)
      )
  )
  expected = (np.arange(WORLDS) == 2).astype(np.float32)
  for _ in range(int(warp_env.step_limit)):
    states = warp_fns['step'](states, _actions(warp_env))
    np.testing.assert_array_equal(states.metrics['overflow'], expected)
  assert np.all(np.asarray(states.last())), 'the episodes should have ended'
  # Same-step auto-reset: the next episode starts from a fresh reset.
  states = warp_fns['step'](states, _actions(warp_env))
  np.testing.assert_array_equal(states.metrics['overflow'], 0)


def test_default_njmax_holds_the_jax_implementations_rows():
  """Warp's estimate, raised to MJX's JAX allocation where that is larger."""

  def jax_rows(mj_model):
    data = mjx.make_data(mj_model, impl='jax')
    return internals.data_impl(data).efc_J.shape[0]

  arm = reach.Reach().root_entity.compose()[0].compile()
  boxes = push.Push().root_entity.compose()[0].compile()
  # Push's boxes can touch the floor, the arm and each other at once: more
  # rows than Warp's estimate (which 194 of 8,192 worlds overflowed).
  assert jax_rows(boxes) > internals.warp_default_njmax(boxes)
  assert backend.default_njmax(boxes) == jax_rows(boxes)
  # The arm needs fewer than Warp's estimate, which stays.
  assert jax_rows(arm) < internals.warp_default_njmax(arm)
  assert backend.default_njmax(arm) == internals.warp_default_njmax(arm)


# -- refusals -------------------------------------------------------------------


def test_warp_refuses_a_per_world_height_field():
  with pytest.raises(NotImplementedError) as raised:
    environment.Environment(
        joystick.Joystick(terrain='rough'),
        options=composer.ExecutionOptions(impl='warp'),
    )
  message = str(raised.value)
  assert 'hfield_data' in message
  assert 'Joystick.initialize_episode' in message
  assert "impl='jax'" in message


def test_warp_refuses_declared_unbatchable_fields():
  with pytest.raises(NotImplementedError, match='hfield_data'):
    conftest.make_swing_env(
        options=composer.ExecutionOptions(
            impl='warp', per_world_model_fields=('hfield_data',)
        )
    )


def test_warp_refuses_the_shared_reset_forward():
  with pytest.raises(ValueError, match='share_reset_forward=True'):
    conftest.make_swing_env(
        options=composer.ExecutionOptions(impl='warp', share_reset_forward=True)
    )


def test_warp_buffer_sizes_need_warp_or_the_default():
  with pytest.raises(ValueError, match="impl='warp' or impl=None only"):
    conftest.make_swing_env(
        options=composer.ExecutionOptions(impl='jax', naconmax=64)
    )
  with pytest.raises(ValueError, match='positive integer'):
    conftest.make_swing_env(
        options=composer.ExecutionOptions(impl='warp', njmax=0)
    )
  with pytest.raises(ValueError, match='positive integer'):
    conftest.make_swing_env(options=composer.ExecutionOptions(njmax=0))
  # The default builds on 'jax' here (a CPU): sizes meant for Warp on a GPU
  # are ignored, so the same call runs on either.
  env = conftest.make_swing_env(
      options=composer.ExecutionOptions(naconmax=64, njmax=32)
  )
  assert env.impl == 'jax'


def test_unknown_impl_is_refused():
  with pytest.raises(ValueError, match="impl must be 'jax', 'warp'"):
    conftest.make_swing_env(options=composer.ExecutionOptions(impl='cpp'))


def test_warp_not_installed_says_how_to_install(monkeypatch):
  monkeypatch.setattr(impl_choice, 'warp_installed', lambda: False)
  with pytest.raises(ImportError, match=r"pip install 'mjx-composer\[warp\]'"):
    conftest.make_swing_env(options=composer.ExecutionOptions(impl='warp'))


def test_default_impl_is_jax_on_a_cpu():
  env = conftest.make_swing_env()
  assert env.impl == 'jax'
  assert env.mjx_model.impl == mjx.Impl.JAX


class _FakeClient:
  platform_version = 'cuda 12.8'


class _FakeGpu:
  platform = 'gpu'
  client = _FakeClient()


def test_default_impls_put_warp_first_on_a_cuda_gpu(monkeypatch):
  monkeypatch.setattr(impl_choice, 'warp_installed', lambda: True)
  gpu = _FakeGpu()
  assert impl_choice.resolve_impl(None, gpu) == ('warp', 'jax')
  # The fused restart runs on 'jax' only.
  assert impl_choice.resolve_impl(None, gpu, share_reset_forward=True) == (
      'jax',
  )
  # An explicit choice is the only one tried.
  assert impl_choice.resolve_impl('jax', gpu) == ('jax',)
  assert impl_choice.resolve_impl('warp', gpu) == ('warp',)
  cpu = jax.devices('cpu')[0]
  assert impl_choice.resolve_impl(None, cpu) == ('jax',)
  monkeypatch.setattr(impl_choice, 'warp_installed', lambda: False)
  assert impl_choice.resolve_impl(None, gpu) == ('jax',)


def _warp_first_everywhere(monkeypatch):
  """impl=None tries 'warp' then 'jax' on this CPU, as on a CUDA GPU."""
  monkeypatch.setattr(
      impl_choice, 'default_impls', lambda device, share: ('warp', 'jax')
  )


def test_default_impl_takes_warp_where_it_runs(monkeypatch):
  _warp_first_everywhere(monkeypatch)
  env = conftest.make_swing_env()
  assert env.impl == 'warp'
  assert env.mjx_model.impl == mjx.Impl.WARP


def test_default_impl_falls_back_to_jax_where_warp_refuses(monkeypatch, caplog):
  """Warp refuses a per-world height field; the default builds on 'jax'."""
  _warp_first_everywhere(monkeypatch)

  def build(**options):
    task = _DrawingSwingTask()
    env = environment.Environment(
        task, random_state=3, options=composer.ExecutionOptions(**options)
    )
    return env, task.draws

  with caplog.at_level('WARNING'):
    env, draws = build()
  assert env.impl == 'jax'
  assert env.mjx_model.impl == mjx.Impl.JAX
  assert any(
      'impl=None' in r.message and 'hfield_data' in r.message
      for r in caplog.records
  ), caplog.text
  # Warp's refusal came after `after_compile` (it needs reset traced), which
  # then ran again from the same random state: the environment is the one
  # impl='jax' builds.
  direct_env, direct_draws = build(impl='jax')
  assert draws == direct_draws * 2
  np.testing.assert_array_equal(
      env.random_state.get_state()[1], direct_env.random_state.get_state()[1]
  )
  # An explicit 'warp' still refuses.
  with pytest.raises(backend.WarpUnsupportedError, match='hfield_data'):
    build(impl='warp')


class _DrawingSwingTask(conftest.SwingTask):
  """Draws from the host random state after compiling; writes a field that
  MuJoCo Warp cannot vary per world in every episode."""

  def __init__(self):
    super().__init__()
    self.draws = []

  def after_compile(self, physics, random_state):
    self.draws.append(random_state.uniform())

  def initialize_episode(self, physics, key):
    physics = super().initialize_episode(physics, key)
    # The swing model has no height field: an empty per-world write.
    heights = physics.model.hfield_data
    shift = jax.random.uniform(key, dtype=heights.dtype)
    return physics.replace(
        model=physics.model.replace(hfield_data=heights + shift)
    )
