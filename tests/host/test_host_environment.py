"""`HostEnvironment` passes dm_env's conformance tests in every auto-reset mode.

`dm_env.test_utils.EnvironmentTestMixin` checks the dm_env contract (FIRST
after reset and after LAST, no reward/discount at FIRST, values conforming to
the specs). One tiny environment per mode is built once for the module; every test wraps
it in a fresh host environment (JAX reuses the compiled reset and step).
"""

import functools

from absl.testing import absltest
import dm_env
from dm_env import test_utils
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.host import host_environment
from tests import conftest

_EPISODE_STEPS = 3


class _TinySwing(conftest.PendulumTask):
  """A single pendulum; episodes end by time limit, or early by termination."""

  def __init__(self):
    self.arena = composer.Arena()
    self.pendulum = conftest.Pendulum()
    self.arena.attach(self.pendulum)
    self.set_timesteps(control_timestep=0.01, physics_timestep=0.01)

  def initialize_episode(self, physics, key):
    angle = jax.random.uniform(key, (1,), minval=-1.0, maxval=1.0)
    return physics.bind(self.pendulum.joint).set(qpos=angle)

  def get_reward(self, physics):
    return physics.bind(self.pendulum.tip).xpos[2]

  def should_terminate_episode(self, physics):
    # Ends some episodes before the time limit (a large push on the motor).
    return jnp.abs(physics.bind(self.pendulum.joint).qvel[0]) > 5.0


@functools.lru_cache(maxsize=None)
def _environment(auto_reset):
  return composer.Environment(
      _TinySwing(),
      time_limit=_EPISODE_STEPS * 0.01,
      options=composer.ExecutionOptions(auto_reset=auto_reset),
  )


def _host_environment(auto_reset, num_worlds=None):
  """A fresh host environment (JAX reuses the mode's compiled functions)."""
  return composer.HostEnvironment(
      _environment(auto_reset), num_worlds=num_worlds, seed=0
  )


class _ConformanceMixin(test_utils.EnvironmentTestMixin):
  AUTO_RESET = None

  def make_object_under_test(self):
    return _host_environment(self.AUTO_RESET)

  def make_action_sequence(self):
    # Long enough for several episodes (each ends within _EPISODE_STEPS).
    for i in range(4 * _EPISODE_STEPS + 1):
      yield np.full(
          self.environment.action_spec().shape, (-1.0) ** i, np.float32
      )


class NextStepConformanceTest(_ConformanceMixin, absltest.TestCase):
  AUTO_RESET = 'next_step'


class SameStepConformanceTest(_ConformanceMixin, absltest.TestCase):
  AUTO_RESET = 'same_step'


@pytest.mark.parametrize('auto_reset', ['next_step', 'same_step'])
def test_single_world_is_a_dm_env_environment(auto_reset):
  env = _host_environment(auto_reset)
  assert isinstance(env, dm_env.Environment)
  assert isinstance(env, composer.HostEnvironment)


@pytest.mark.parametrize('auto_reset', ['next_step', 'same_step'])
def test_last_then_first_with_the_ended_episodes_observation(auto_reset):
  """LAST carries the ended episode's observation; FIRST the next one's."""
  env = _host_environment(auto_reset)
  action = np.zeros(env.action_spec().shape, np.float32)
  timestep = env.reset()
  types = [timestep.step_type]
  observations = [timestep.observation['tip']]
  for _ in range(2 * _EPISODE_STEPS + 2):
    timestep = env.step(action)
    types.append(timestep.step_type)
    observations.append(timestep.observation['tip'])
  first, mid, last = (
      dm_env.StepType.FIRST,
      dm_env.StepType.MID,
      dm_env.StepType.LAST,
  )
  assert types == [first, mid, mid, last, first, mid, mid, last, first]
  # A LAST observation ends its episode; the next FIRST starts a new one
  # from another random angle.
  assert not np.allclose(observations[3], observations[4])
  assert env.state.first()


def test_same_step_last_matches_next_step_last():
  """Both modes report the same LAST: the ended episode's last observation."""
  last = {}
  for auto_reset in ('next_step', 'same_step'):
    env = composer.HostEnvironment(_environment(auto_reset), seed=7)
    env.reset()
    for _ in range(_EPISODE_STEPS):
      timestep = env.step(np.zeros(env.action_spec().shape, np.float32))
    assert timestep.last()
    last[auto_reset] = timestep
  np.testing.assert_allclose(
      last['same_step'].observation['tip'], last['next_step'].observation['tip']
  )
  np.testing.assert_allclose(last['same_step'].reward, last['next_step'].reward)


def test_same_step_first_ignores_the_action():
  env = _host_environment('same_step')
  env.reset()
  zero = np.zeros(env.action_spec().shape, np.float32)
  for _ in range(_EPISODE_STEPS):
    timestep = env.step(zero)
  assert timestep.last()
  held = np.asarray(env.state.data.qpos)
  timestep = env.step(np.full_like(zero, 1.0))  # Ignored.
  assert timestep.first()
  assert timestep.reward is None and timestep.discount is None
  np.testing.assert_array_equal(np.asarray(env.state.data.qpos), held)


def test_batched_is_not_a_dm_env_environment():
  env = _host_environment('next_step', num_worlds=2)
  assert isinstance(env, host_environment.BatchedHostEnvironment)
  assert not isinstance(env, dm_env.Environment)
  timestep = env.reset()
  assert isinstance(timestep, host_environment.BatchedTimeStep)
  assert timestep.step_type.shape == (2,)
  assert timestep.first().all()
  timestep = env.step(np.zeros((2,) + env.action_spec().shape, np.float32))
  assert timestep.mid().all()
  assert timestep.reward.shape == (2,)


if __name__ == '__main__':
  absltest.main()
