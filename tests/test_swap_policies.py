"""benchmarks/swap_policies.py without Playground: policies, forms, returns."""

import os
import sys

import flax.struct
import jax
import jax.numpy as jnp
import numpy as np
import pytest

sys.path.insert(
    0, os.path.join(os.path.dirname(os.path.dirname(__file__)), 'benchmarks')
)
import swap_policies  # pylint: disable=g-import-not-at-top,wrong-import-position
import train_ppo  # pylint: disable=g-import-not-at-top,wrong-import-position

_OBS, _ACTIONS = 5, 3


def _save_playground_policy(path):
  """A policy file as `train_compare.py` writes Playground's runs'."""
  # pylint: disable=g-import-not-at-top
  from brax.training.acme import running_statistics
  from brax.training.acme import specs
  from brax.training.agents.ppo import networks as ppo_networks
  # pylint: enable=g-import-not-at-top

  networks = ppo_networks.make_ppo_networks(
      _OBS,
      _ACTIONS,
      preprocess_observations_fn=running_statistics.normalize,
  )
  key_policy, key_value = jax.random.split(jax.random.key(0))
  normalizer = running_statistics.init_state(specs.Array((_OBS,), jnp.float32))
  params = (
      normalizer,
      networks.policy_network.init(key_policy),
      networks.value_network.init(key_value),
  )
  train_ppo.save_policy(
      path,
      params,
      {
          'env': 'playground',
          'observation_size': _OBS,
          'action_size': _ACTIONS,
          'normalize': True,
      },
  )
  return networks, params


def test_a_playground_policy_takes_one_vector(tmp_path):
  path = str(tmp_path / 'playground_seed0_policy.pkl')
  networks, params = _save_playground_policy(path)
  policy, form = swap_policies.load_policy(path, deterministic=True)
  assert form == 'array'
  obs = jnp.linspace(-1.0, 1.0, _OBS)
  action, _ = policy(obs, jax.random.key(1))
  # Brax's own inference function on the same parameters.
  # pylint: disable=g-import-not-at-top
  from brax.training.agents.ppo import networks as ppo_networks
  # pylint: enable=g-import-not-at-top

  want, _ = ppo_networks.make_inference_fn(networks)(
      params, deterministic=True
  )(obs, jax.random.key(1))
  assert action.shape == (_ACTIONS,)
  np.testing.assert_allclose(action, want, rtol=1e-6)


def test_train_ppo_gives_a_playground_policy_the_policy_group(tmp_path):
  path = str(tmp_path / 'playground_seed0_policy.pkl')
  _save_playground_policy(path)
  array_policy, _ = swap_policies.load_policy(path, deterministic=True)
  group_policy = train_ppo.load_policy(path, deterministic=True)
  obs = jnp.linspace(-1.0, 1.0, _OBS)
  np.testing.assert_array_equal(
      group_policy({'policy': obs}, jax.random.key(0))[0],
      array_policy(obs, jax.random.key(0))[0],
  )


def test_observations_are_given_in_the_policys_form():
  vector = jnp.arange(4.0)
  group = {'policy': vector}
  assert swap_policies._observation(group, 'group', 'array') is vector
  assert swap_policies._observation(vector, 'array', 'group') == {
      'policy': vector
  }
  assert swap_policies._observation(vector, 'array', 'array') is vector
  assert swap_policies._observation(group, 'group', 'group') is group


@flax.struct.dataclass
class _State:
  obs: jax.Array
  reward: jax.Array


@pytest.mark.parametrize('env_form', ['array', 'group'])
def test_episode_returns_sum_each_worlds_rewards(env_form):
  """A counter environment: each world's reward is its action's first entry."""

  def wrap(x):
    return x if env_form == 'array' else {'policy': x}

  def reset(keys):
    worlds = keys.shape[0]
    start = jnp.arange(worlds, dtype=jnp.float32)[:, None]
    return _State(wrap(jnp.tile(start, (1, _OBS))), jnp.zeros(worlds))

  def step(state, action):
    obs = state.obs if env_form == 'array' else state.obs['policy']
    return _State(wrap(obs + 1.0), action[:, 0])

  def act(obs, unused_key):  # A Playground-form policy: the vector's sum.
    return jnp.full((_ACTIONS,), jnp.sum(obs)), {}

  returns = swap_policies.episode_returns(
      (reset, step, env_form), (act, 'array'), worlds=3, steps=4, seed=0
  )
  # World w observes w + t (all 5 entries) before step t and earns 5 (w + t).
  want = [sum(_OBS * (w + t) for t in range(4)) for w in range(3)]
  np.testing.assert_allclose(returns, want)
