"""Environment, HostEnvironment, Brax adapter and demo: bad input refused."""

import functools
import re
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mjx_composer as composer
from tests import conftest
from tests.package.bad_inputs import common

# -- 3. HostEnvironment arguments and action shapes ----------------------------


@pytest.mark.parametrize('num_worlds', [0, -2, 2.5, True, '3'])
def test_host_environment_rejects_bad_num_worlds(num_worlds):
  with pytest.raises(
      ValueError, match=r'num_worlds must be a positive int.*num_worlds=None'
  ):
    composer.HostEnvironment(
        common.pendulum_environment(), num_worlds=num_worlds
    )


def test_batched_host_environment_explains_a_single_world_action():
  env = composer.HostEnvironment(common.pendulum_environment(), num_worlds=3)
  env.reset()
  single = np.zeros(env.action_spec().shape, np.float32)  # (1,)
  with pytest.raises(
      ValueError,
      match=r'steps 3 worlds at once: expected actions of shape \(3, 1\).*got '
      r"\(1,\), the shape of one world's action.*np.broadcast_to\(action, "
      r'\(3, 1\)\)',
  ):
    env.step(single)
  timestep = env.step(np.broadcast_to(single, (3, 1)))
  assert timestep.step_type.shape == (3,)


def test_single_world_host_environment_explains_a_batched_action():
  env = composer.HostEnvironment(common.pendulum_environment())
  env.reset()
  with pytest.raises(
      ValueError,
      match=r'steps one world: expected an action of shape \(1,\).*got '
      r'\(4, 1\).*HostEnvironment\(environment, num_worlds=4\)',
  ):
    env.step(np.zeros((4, 1), np.float32))


# -- 5. importing the package prints nothing ----------------------------------


def test_import_prints_nothing():
  result = subprocess.run(
      [sys.executable, '-c', 'import mjx_composer'],
      capture_output=True,
      text=True,
      check=True,
  )
  assert result.stdout == ''
  assert result.stderr == ''


# -- the Brax adapter -----------------------------------------------------------


@pytest.mark.parametrize(
    'length', [0, -5, 2.5, True, float('inf'), float('nan'), '5']
)
def test_brax_env_rejects_a_bad_episode_length(length):
  from mjx_composer.adapters import brax as brax_adapter  # pylint: disable=g-import-not-at-top

  env = composer.Environment(
      composer.NullTask(common.Arm()),
      time_limit=1.0,
      options=composer.ExecutionOptions(auto_reset='same_step'),
  )
  with pytest.raises(ValueError, match='positive number of control steps'):
    brax_adapter.BraxEnv(env, episode_length=length)


def test_a_batched_state_in_the_single_world_step_says_use_vmap():
  env = composer.Environment(composer.NullTask(common.Arm()))
  states = jax.eval_shape(
      jax.vmap(env.reset), jax.random.split(jax.random.key(0), 3)
  )
  with pytest.raises(ValueError, match=r'holds 3 worlds.*jax.vmap\(env.step\)'):
    jax.eval_shape(env.step, states, jnp.zeros((1,)))


class _GroupedSwing(conftest.SwingTask):
  """The swing task with a flattened and a dict-valued observation group."""

  def observation_groups(self):
    group = composer.ObservationGroup
    return {
        'policy': group(keys=['tip'], flatten=True),
        'raw': group(keys=['tip']),
    }


@functools.lru_cache(maxsize=None)
def _brax_envs():
  """(ungrouped, grouped) swing environments that Brax can wrap."""
  options = composer.ExecutionOptions(auto_reset='same_step')
  return (
      conftest.make_swing_env(time_limit=0.05, options=options),
      composer.Environment(_GroupedSwing(), time_limit=0.05, options=options),
  )


@pytest.mark.parametrize(
    'obs_key, error, match',
    [
        ([], ValueError, r'obs_key=\[\] selects no observation.*Pass None'),
        (('tip', 'tip'), ValueError, r"obs_key=.*names \['tip'\] more than"),
        (3, TypeError, r'obs_key must be None, a string.*got 3'),
        (['tip', 4], TypeError, r'obs_key must be None, a string'),
        ('nope', ValueError, r"obs_key: no observation \['nope'\].*'tip'"),
    ],
)
def test_brax_env_refuses_a_bad_obs_key(obs_key, error, match):
  from mjx_composer.adapters import brax as brax_adapter  # pylint: disable=g-import-not-at-top

  with pytest.raises(error, match=match):
    brax_adapter.BraxEnv(_brax_envs()[0], obs_key=obs_key)


def test_brax_env_refuses_a_group_that_is_not_flattened():
  from mjx_composer.adapters import brax as brax_adapter  # pylint: disable=g-import-not-at-top

  grouped = _brax_envs()[1]
  for obs_key in (None, 'raw', ['policy', 'raw']):
    with pytest.raises(
        ValueError, match=r"\['raw'\] are not flattened.*flatten=True"
    ):
      brax_adapter.BraxEnv(grouped, obs_key=obs_key)
  assert brax_adapter.BraxEnv(grouped, obs_key='policy').observation_size == 3


def test_brax_env_default_obs_key_works_with_brax_networks():
  """Without groups, Brax's default networks (policy_obs_key='state') fit.

  Before, obs_key=None gave Brax a dict without 'state' and Brax's network
  factory failed with KeyError: 'state'.
  """
  from brax.training.agents.ppo import networks as ppo_networks  # pylint: disable=g-import-not-at-top
  from mjx_composer.adapters import brax as brax_adapter  # pylint: disable=g-import-not-at-top

  brax_env = brax_adapter.BraxEnv(_brax_envs()[0])
  assert brax_env.observation_size == 3
  with pytest.raises(KeyError, match='state'):  # The reference: Brax.
    ppo_networks.make_ppo_networks({'tip': (3,)}, brax_env.action_size)
  networks = ppo_networks.make_ppo_networks(
      brax_env.observation_size, brax_env.action_size
  )
  params = networks.policy_network.init(jax.random.key(0))
  obs = brax_env.reset(jax.random.key(1)).obs
  assert obs.shape == (3,)
  logits = networks.policy_network.apply(None, params, obs[None])
  assert logits.shape == (1, 2 * brax_env.action_size)


def test_brax_env_refuses_actions_of_another_batch_than_the_state():
  """A single-world state with a batch of actions failed inside jax.vmap."""
  from mjx_composer.adapters import brax as brax_adapter  # pylint: disable=g-import-not-at-top

  brax_env = brax_adapter.BraxEnv(_brax_envs()[0])
  key = jax.random.key(0)
  one = jax.eval_shape(brax_env.reset, key)
  three = jax.eval_shape(brax_env.reset, jax.random.split(key, 3))
  size = brax_env.action_size
  for state, actions, match in [
      (
          one,
          jnp.zeros((4, size)),
          rf"`action` has shape \(4, {size}\), but `state` is one world's.*"
          rf'pass actions of shape \({size},\).*jax.random.split\(key, 4\)',
      ),
      (
          three,
          jnp.zeros((size,)),
          rf'shape \({size},\), but `state` is a batch of shape \(3,\).*'
          rf'jnp.broadcast_to\(action, \(3, {size}\)\)',
      ),
      (three, jnp.zeros((4, size)), rf'pass actions of shape \(3, {size}\)'),
      (one, jnp.zeros((size + 1,)), rf'pass actions of shape \({size},\)'),
  ]:
    with pytest.raises(ValueError, match=r'BraxEnv.step: .*' + match):
      jax.eval_shape(brax_env.step, state, actions)
  assert jax.eval_shape(
      brax_env.step, three, jnp.zeros((3, size))
  ).reward.shape == (3,)
  assert jax.eval_shape(brax_env.step, one, jnp.zeros(size)).reward.shape == ()


def test_wrappers_refuse_what_is_not_a_pure_environment():
  """HostEnvironment(task) and BraxEnv(HostEnvironment(...)) raised an
  AttributeError from deep inside."""
  from mjx_composer.adapters import brax as brax_adapter  # pylint: disable=g-import-not-at-top

  env = _brax_envs()[0]
  host = composer.HostEnvironment(env)
  brax_env = brax_adapter.BraxEnv(env)
  for make, match in [
      (
          lambda: brax_adapter.BraxEnv(host),
          r'BraxEnv: `environment` must be an mjx_composer.Environment.*got a '
          r'HostEnvironment, which wraps one: pass its `.environment`',
      ),
      (
          lambda: brax_adapter.BraxEnv(env.task),
          r'got a Task: build its environment first, '
          r'BraxEnv\(composer.Environment\(task',
      ),
      (
          lambda: composer.HostEnvironment(env.task),
          r'HostEnvironment: `environment` must be.*got a Task: build its '
          r'environment first, HostEnvironment\(composer.Environment\(task',
      ),
      (
          lambda: composer.HostEnvironment(env.task, num_worlds=2),
          r'BatchedHostEnvironment: `environment` must be.*got a Task',
      ),
      (
          lambda: composer.HostEnvironment(brax_env),
          r'got a BraxEnv, which wraps one: pass its `.environment`',
      ),
      (lambda: composer.HostEnvironment('walk'), r"got str 'walk'"),
  ]:
    with pytest.raises(TypeError, match=match):
      make()
  assert brax_adapter.BraxEnv(host.environment).action_size == 1
  assert composer.HostEnvironment(brax_env.environment).reset().first()


@pytest.mark.parametrize(
    'action', ['a', '0.5', {'motor': 0.5}, ['0.5'], [[0.5], [0.5, 0.5]], None]
)
@pytest.mark.parametrize('num_worlds', [None, 2])
def test_host_environment_step_refuses_what_is_not_numbers(action, num_worlds):
  """Strings and dicts failed in NumPy's float conversion; strings of
  digits were taken as numbers."""
  env = composer.HostEnvironment(
      common.pendulum_environment(), num_worlds=num_worlds
  )
  env.reset()
  shape = r'\(1,\)' if num_worlds is None else r'\(2, 1\)'
  name = 'action' if num_worlds is None else 'actions'
  with pytest.raises(
      TypeError,
      match=rf'step: `{name}` must be numbers, an array of shape {shape}, '
      rf'got .*np.zeros\({shape}, np.float32\)',
  ):
    env.step(action)


# -- HostEnvironment: seeds and failed initializations -----------------------


@pytest.mark.parametrize(
    'seed, error, match',
    [
        ('abc', TypeError, r"seed must be an int, got 'abc' \(str\).*seed=0"),
        (1.5, TypeError, r'seed must be an int, got 1.5 \(float\)'),
        (None, TypeError, r'seed must be an int, got None'),
        (True, TypeError, r'seed must be an int, got True'),
        (2**70, ValueError, r'seed must be in \[0, 2\*\*63\).*got 1180591'),
        (-1, ValueError, r'seed must be in \[0, 2\*\*63\).*got -1'),
    ],
)
@pytest.mark.parametrize('num_worlds', [None, 2])
def test_host_environment_refuses_a_bad_seed(seed, error, match, num_worlds):
  with pytest.raises(error, match=match):
    composer.HostEnvironment(
        common.pendulum_environment(), num_worlds=num_worlds, seed=seed
    )


def test_host_environment_accepts_the_largest_seed():
  env = composer.HostEnvironment(common.pendulum_environment(), seed=2**63 - 1)
  assert env.reset().first()


class _FlakyInitialization(composer.NullTask):
  """Fails an episode's initialization with probability `p` per attempt."""

  def __init__(self, p):
    arena = composer.Arena()
    arena.attach(conftest.Pendulum())
    super().__init__(arena)
    self.p = p

  def initialize_episode(self, physics, key):
    return physics.fail_initialization(jax.random.uniform(key) < self.p)


@functools.lru_cache(maxsize=None)
def _flaky_environment(p, attempts):
  return composer.Environment(
      _FlakyInitialization(p), time_limit=0.1, max_reset_attempts=attempts
  )


@pytest.mark.parametrize('num_worlds', [None, 3])
def test_host_reset_raises_when_every_attempt_fails(num_worlds):
  """composer's reset raises EpisodeInitializationError after its retries."""
  env = composer.HostEnvironment(
      _flaky_environment(1.0, 3), num_worlds=num_worlds
  )
  where = r' in world\(s\) \[0, 1, 2\]' if num_worlds else ''
  with pytest.raises(
      composer.EpisodeInitializationError,
      match=rf'all 3 attempt\(s\).*failed{where}.*max_reset_attempts',
  ):
    env.reset()


def test_host_reset_succeeds_when_a_retry_succeeds():
  env = composer.HostEnvironment(_flaky_environment(0.9, 200), num_worlds=3)
  env.reset()  # Each world fails all 200 attempts with probability 7e-10.
  failures = np.asarray(env.state.metrics['init_failures'])
  assert not np.any(np.asarray(env.state.metrics['init_failed']))
  assert failures.sum() > 0  # Retries happened, and one succeeded.


# -- first use: a cold demo says what it compiles before compiling -----------


def test_demo_says_what_it_compiles_before_compiling(capsys, monkeypatch):
  from mjx_composer import cli  # pylint: disable=g-import-not-at-top
  from mjx_composer.suite.tasks import registry  # pylint: disable=g-import-not-at-top

  before_compiling = []
  make_rollout = cli.make_rollout

  def recording_make_rollout(*args):
    rollout = make_rollout(*args)

    def first_call(*call_args):
      if not before_compiling:
        before_compiling.append(capsys.readouterr().out)
      return rollout(*call_args)

    return first_call

  monkeypatch.setattr(cli, 'make_rollout', recording_make_rollout)
  registry.register('swing_for_the_demo_test', conftest.SwingTask)
  try:
    assert (
        cli.demo(
            [
                '--task',
                'swing_for_the_demo_test',
                '--worlds',
                '2',
                '--steps',
                '2',
                '--chunk',
                '2',
                '--time-limit',
                '0.05',
            ]
        )
        == 0
    )
  finally:
    registry.unregister('swing_for_the_demo_test')
  (printed,) = before_compiling
  assert re.search(
      r'Compiling the reset of 2 worlds and a 2-step rollout \(seconds on a '
      r'GPU, minutes on a CPU; .*compilation cache',
      printed,
  ), printed
  assert 'Compiled reset' in capsys.readouterr().out
