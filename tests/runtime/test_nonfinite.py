"""What can only go wrong inside a jitted step becomes a per-world flag.

A non-finite action, reward, discount or observation ends that world's
episode as a physics error does (LAST, reward 0, discount 0) with a flag in
its metrics; an initializer that draws a NaN fails the attempt (counted in
`init_failures`); no NaN or infinity reaches the returned observation or
reward; and the other worlds equal a clean run bit for bit. Each case runs
on MJX's JAX implementation (whose step program on the CPU fuses the
restart into the sub-step loop) and on MuJoCo Warp on the CPU (whose restart
is separate).

One small environment per backend: a pendulum with a motor, a ball placed
by `PropPlacer`, and task state that the reward, the discount and two
observables read. Every case is one call of the same compiled step on
states that differ only where the case poisons world 1, so the clean run is
the same program on the clean inputs. A world's persistent entry
`_POISON` chooses what its `initialize_episode` draws, so the reset's cases
run through the step program's auto-reset too.
"""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer import initializers
from mjx_composer.observation import observable
from mjx_composer.platform import shared_buffers
from mjx_composer.runtime import episode
from tests import conftest

WORLDS = 4
POISONED = 1
ATTEMPTS = 3
_POISON = 'test/poison'
# What a world's `initialize_episode` draws, by its `_POISON` entry.
CLEAN, PROP_ALWAYS, PROP_FIRST_CANDIDATE, HOOK = 0, 1, 2, 3
FLAGS = (
    'diverged',
    'nonfinite_action',
    'nonfinite_reward',
    'nonfinite_observation',
)


def _ball_position(initial, current, key):
  """The ball's candidate position; NaN as the world's `_POISON` asks.

  `current` is `(mode, the previous candidate)`: `_Task` passes the mode of
  the world being initialized.
  """
  del initial
  mode, previous = current
  xy = jax.random.uniform(key, (2,), minval=-1.0, maxval=1.0)
  position = jnp.concatenate([xy, jnp.array([0.3])])
  nan = jnp.full(3, jnp.nan)
  first_candidate = jnp.all(jnp.isfinite(previous))
  poisoned = (mode == PROP_ALWAYS) | (
      (mode == PROP_FIRST_CANDIDATE) & first_candidate
  )
  return jnp.where(poisoned, nan, position)


class _Task(conftest.PendulumTask):
  """Swing a pendulum; a ball is placed on the floor by `PropPlacer`.

  Task state: `command` (the reward's target angle, observed), `discount`
  (the discount) and `probe` (observed only).
  """

  def __init__(self):
    self.arena = composer.Arena()
    self.arena.mjcf_model.worldbody.add_geom(
        name='floor', type=mujoco.mjtGeom.mjGEOM_PLANE, size=[2, 2, 0.1]
    )
    self.pendulum = conftest.Pendulum()
    self.arena.attach(self.pendulum)
    self.ball = conftest.Ball()
    self.arena.add_free_entity(self.ball)
    self.set_timesteps(control_timestep=0.01, physics_timestep=0.005)
    self._mode = None
    self.placer = initializers.PropPlacer(
        [self.ball],
        position=lambda initial, current, key: _ball_position(
            initial, (self._mode, current), key
        ),
        max_attempts_per_prop=2,
    )

  @property
  def task_observables(self):
    observables = dict(super().task_observables)
    sources = {
        'angle': lambda physics: physics.bind(self.pendulum.joint).qpos,
        'ball': lambda physics: physics.bind(self.ball.body).xpos,
        'command': lambda physics: physics.task_state['command'],
        'probe': lambda physics: physics.task_state['probe'],
    }
    for name, source in sources.items():
      observables[name] = observable.Generic(source)
      observables[name].enabled = True
    return observables

  def initial_task_state(self):
    return {
        'command': jnp.zeros(()),
        'discount': jnp.ones(()),
        'probe': jnp.zeros(()),
    }

  def initialize_episode(self, physics, key):
    mode = physics.get_persistent(_POISON, jnp.zeros((), jnp.int32))
    physics = physics.set_persistent(_POISON, mode)
    angle_key, place_key = jax.random.split(key)
    angle = jax.random.uniform(angle_key, (1,), minval=-1, maxval=1)
    angle = jnp.where(mode == HOOK, jnp.nan, angle)
    physics = physics.bind(self.pendulum.joint).set(qpos=angle)
    # The placer's variation reads the mode (one trace, per-world value).
    self._mode = mode
    try:
      return self.placer(physics, place_key)
    finally:
      self._mode = None

  def get_reward(self, physics):
    angle = physics.bind(self.pendulum.joint).qpos[0]
    return -jnp.square(angle - physics.task_state['command'])

  def get_discount(self, physics):
    return physics.task_state['discount']


@pytest.fixture(scope='module', params=['jax', 'warp'])
def env(request):
  options = composer.ExecutionOptions(auto_reset='next_step', impl='jax')
  if request.param == 'warp':
    options = composer.ExecutionOptions(
        auto_reset='next_step', impl='warp', naconmax=8 * WORLDS
    )
  return composer.Environment(
      _Task(), time_limit=1.0, max_reset_attempts=ATTEMPTS, options=options
  )


@pytest.fixture(scope='module')
def fns(env):
  return {
      'reset': jax.jit(jax.vmap(env.reset)),
      'step': jax.jit(jax.vmap(env.step)),
  }


@pytest.fixture(scope='module')
def started(fns):
  return fns['reset'](jax.random.split(jax.random.key(0), WORLDS))


@pytest.fixture(scope='module')
def actions(env):
  shape = (WORLDS,) + env.action_spec().shape
  return jax.random.uniform(jax.random.key(1), shape, minval=-1, maxval=1)


@pytest.fixture(scope='module')
def clean(fns, started, actions):
  return fns['step'](started, actions)


def _at(tree, world):
  """One world's leaves (MuJoCo Warp's buffers shared by the batch left
  out: they hold every world's contacts)."""
  return jax.tree.map(
      lambda x, shared: jnp.zeros(0) if shared else x[world],
      tree,
      shared_buffers.shared_leaves(tree),
  )


def _assert_bitwise(a, b):
  leaves_a, tree_a = jax.tree.flatten(a)
  leaves_b, tree_b = jax.tree.flatten(b)
  assert tree_a == tree_b
  for x, y in zip(leaves_a, leaves_b):
    if jnp.issubdtype(jnp.asarray(x).dtype, jax.dtypes.prng_key):
      x, y = jax.random.key_data(x), jax.random.key_data(y)
    np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def _assert_others_clean(states, clean):
  """Every world but `POISONED` equals the clean run, bit for bit."""
  for world in range(WORLDS):
    if world != POISONED:
      _assert_bitwise(_at(states, world), _at(clean, world))


def _assert_flags(states, raised):
  """Exactly the flags `raised` are set, on `POISONED` only."""
  for flag in FLAGS:
    expected = np.zeros(WORLDS, np.float32)
    expected[POISONED] = float(flag in raised)
    np.testing.assert_array_equal(states.metrics[flag], expected, err_msg=flag)


def _assert_failed_step(states):
  """`POISONED`'s step ended as a physics error, with finite outputs."""
  assert int(states.step_type[POISONED]) == composer.StepType.LAST
  assert bool(states.terminated[POISONED])
  assert not bool(states.truncated[POISONED])
  assert float(states.reward[POISONED]) == 0.0
  assert float(states.discount[POISONED]) == 0.0
  assert bool(episode.finite(states.observation))
  assert bool(episode.finite(states.final_observation))
  assert bool(episode.finite((states.reward, states.discount)))


def _poison_task_state(states, entry, value):
  task_state = dict(states.task_state)
  task_state[entry] = task_state[entry].at[POISONED].set(value)
  return states.replace(task_state=task_state)


def test_the_clean_run_has_no_flag(env, clean):
  assert env.impl in ('jax', 'warp')
  for flag in FLAGS:
    np.testing.assert_array_equal(clean.metrics[flag], 0.0, err_msg=flag)
  np.testing.assert_array_equal(clean.step_type, composer.StepType.MID)
  assert bool(episode.finite(clean.observation))


@pytest.mark.parametrize('value', [np.nan, np.inf, -np.inf])
def test_a_nonfinite_action_ends_the_world_as_a_zero_action(
    fns, started, actions, clean, value
):
  poisoned = fns['step'](started, actions.at[POISONED, 0].set(value))
  _assert_flags(poisoned, {'nonfinite_action'})
  _assert_failed_step(poisoned)
  _assert_others_clean(poisoned, clean)
  # The world stepped with a zero action (on both backends: on Warp a NaN
  # control would act as its lower bound), as the same program computes.
  zero = fns['step'](started, actions.at[POISONED].set(0.0))
  for field in ('observation', 'data', 'task_state', 'obs_state'):
    _assert_bitwise(
        _at(getattr(poisoned, field), POISONED),
        _at(getattr(zero, field), POISONED),
    )
  # The episode's return did not take the reward: it kept the FIRST's 0.
  assert float(poisoned.metrics['episode_return'][POISONED]) == 0.0


def test_a_nan_command_ends_the_world(fns, started, actions, clean):
  """The command enters the reward and the observation: both are flagged,
  and the observation's NaN entry is returned as 0."""
  poisoned = fns['step'](
      _poison_task_state(started, 'command', jnp.nan), actions
  )
  _assert_flags(poisoned, {'nonfinite_reward', 'nonfinite_observation'})
  _assert_failed_step(poisoned)
  _assert_others_clean(poisoned, clean)
  observed = _at(poisoned.observation, POISONED)
  expected = _at(clean.observation, POISONED)
  assert float(np.ravel(observed['command'])[0]) == 0.0
  for name in ('angle', 'ball', 'tip', 'probe'):
    np.testing.assert_array_equal(observed[name], expected[name])
  assert float(poisoned.metrics['episode_return'][POISONED]) == 0.0


def test_an_infinite_discount_ends_the_world(fns, started, actions, clean):
  poisoned = fns['step'](
      _poison_task_state(started, 'discount', jnp.inf), actions
  )
  _assert_flags(poisoned, {'nonfinite_reward'})
  _assert_failed_step(poisoned)
  _assert_others_clean(poisoned, clean)
  _assert_bitwise(
      _at(poisoned.observation, POISONED), _at(clean.observation, POISONED)
  )


def test_an_infinite_observation_ends_the_world(fns, started, actions, clean):
  poisoned = fns['step'](
      _poison_task_state(started, 'probe', -jnp.inf), actions
  )
  _assert_flags(poisoned, {'nonfinite_observation'})
  _assert_failed_step(poisoned)
  _assert_others_clean(poisoned, clean)
  observed = _at(poisoned.observation, POISONED)
  assert float(np.ravel(observed['probe'])[0]) == 0.0


def test_diverged_physics_returns_a_finite_observation(
    fns, started, actions, clean
):
  """Only `diverged` is raised (the outputs' flags name no second cause),
  and the NaN observation of the diverged world is returned as zeros."""
  data = started.data
  poisoned_data = data.replace(qvel=data.qvel.at[POISONED].set(jnp.nan))
  poisoned = fns['step'](started.replace(data=poisoned_data), actions)
  _assert_flags(poisoned, {'diverged'})
  _assert_failed_step(poisoned)
  _assert_others_clean(poisoned, clean)
  assert not np.isfinite(np.asarray(poisoned.data.qpos[POISONED])).all()
  for value in jax.tree.leaves(_at(poisoned.observation, POISONED)):
    np.testing.assert_array_equal(value, 0.0)


def _restart(fns, started, actions, mode):
  """All worlds' next step resets them (they are LAST); `POISONED`'s
  `initialize_episode` draws as `mode` says."""
  persistent = dict(started.persistent)
  persistent[_POISON] = persistent[_POISON].at[POISONED].set(mode)
  last = jnp.asarray(
      np.full(started.step_type.shape, composer.StepType.LAST, np.int32)
  )
  return fns['step'](
      started.replace(persistent=persistent, step_type=last), actions
  )


@pytest.fixture(scope='module')
def clean_restart(fns, started, actions):
  return _restart(fns, started, actions, CLEAN)


def test_the_clean_restart_places_every_world(clean_restart):
  np.testing.assert_array_equal(clean_restart.step_type, 0)
  np.testing.assert_array_equal(clean_restart.metrics['init_failures'], 0)
  np.testing.assert_array_equal(clean_restart.metrics['init_failed'], 0)
  assert np.isfinite(np.asarray(clean_restart.data.qpos)).all()


@pytest.mark.parametrize('mode', [PROP_ALWAYS, HOOK], ids=['prop', 'hook'])
def test_a_nan_drawn_at_reset_fails_every_attempt(
    env, fns, started, actions, clean_restart, mode
):
  """A NaN from `PropPlacer`'s variation, or written by a hook into the
  state, fails the attempt; all of them fail here, so the world reports
  `init_failed`, keeps the state its reset started from (the NaN is never
  run) and its first step ends the episode."""
  restarted = _restart(fns, started, actions, mode)
  expected = np.zeros(WORLDS, np.float32)
  expected[POISONED] = ATTEMPTS
  np.testing.assert_array_equal(restarted.metrics['init_failures'], expected)
  np.testing.assert_array_equal(
      restarted.metrics['init_failed'], expected / ATTEMPTS
  )
  np.testing.assert_array_equal(restarted.metrics['nonfinite_observation'], 0)
  np.testing.assert_array_equal(restarted.step_type, composer.StepType.FIRST)
  assert bool(episode.finite(restarted.observation))
  np.testing.assert_array_equal(
      restarted.data.qpos[POISONED], env.mj_model.qpos0
  )
  for world in range(WORLDS):
    if world != POISONED:
      _assert_bitwise(_at(restarted, world), _at(clean_restart, world))
  # Its first step ends it, from finite physics, with nothing to learn.
  stepped = fns['step'](restarted, actions)
  assert int(stepped.step_type[POISONED]) == composer.StepType.LAST
  assert bool(stepped.terminated[POISONED])
  assert float(stepped.metrics['diverged'][POISONED]) == 0.0
  assert float(stepped.reward[POISONED]) == 0.0
  assert float(stepped.discount[POISONED]) == 0.0
  assert np.isfinite(np.asarray(stepped.data.qpos[POISONED])).all()
  assert bool(episode.finite(stepped.observation))


def test_a_nan_candidate_is_rejected_like_a_collision(
    fns, started, actions, clean_restart
):
  """The first candidate pose is NaN, the second is not: `PropPlacer` keeps
  the second, and the attempt succeeds."""
  restarted = _restart(fns, started, actions, PROP_FIRST_CANDIDATE)
  np.testing.assert_array_equal(restarted.metrics['init_failures'], 0)
  np.testing.assert_array_equal(restarted.metrics['nonfinite_observation'], 0)
  ball = np.asarray(restarted.observation['ball'])
  assert np.isfinite(ball).all()
  assert not np.array_equal(
      ball[POISONED], np.asarray(clean_restart.observation['ball'])[POISONED]
  )
  for world in range(WORLDS):
    if world != POISONED:
      _assert_bitwise(_at(restarted, world), _at(clean_restart, world))
