"""benchmarks/train_compare.py without training: the environments and their
settings, saved policies, GPUs and the command line."""

import json
import os
import pickle

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_composer.training import config as config_lib
from mjx_composer.training import policy

import train_compare  # benchmarks/train_compare.py
import train_segments  # benchmarks/train_segments.py
import train_setups  # benchmarks/train_setups.py


def _setup(env, *flags):
  """`train_setups.setup` of `env` with the fallback hyper-parameters."""
  args = train_compare.parse_args(['--envs', env] + list(flags))
  assert args.envs == [env]
  return train_setups.setup(env, train_setups.fallback_config(), args)


def test_the_fallback_is_playgrounds_humanoid_walk_config():
  # What Playground 0.2.0 gave at run time, in a stored run's record.
  stored = os.path.join(
      os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
      'results',
      'train_compare_walk_full_schedule',
      'runs',
      'playground_seed0.json',
  )
  with open(stored) as f:
    run = json.load(f)
  assert run['hyperparameters_from'] == 'playground 0.2.0'
  assert train_setups.fallback_config() == run['hyperparameters']
  args = train_compare.parse_args(['--num-envs', '8', '--episode-length', '50'])
  overridden, _ = train_setups.hyperparameters(args)
  assert overridden['num_envs'] == 8 and overridden['episode_length'] == 50


def test_ours_trains_as_the_training_command_trains_walk():
  brax_env, kwargs, saved = _setup('ours', '--auto-reset-batch', '4')
  walk = config_lib.defaults('walk')
  # The walk task as shipped: its privileged group too; batched resets.
  assert {'policy', 'critic'} <= set(brax_env.observation_size)
  assert brax_env.environment.auto_reset_batch == 4
  assert brax_env.episode_length == kwargs['episode_length'] == 1000
  # Playground's values, the package's networks for walk.
  for key, value in train_setups.fallback_config().items():
    if key != 'episode_length':
      assert kwargs[key] == value, key
  assert kwargs['network_factory'].keywords == (
      policy.network_factory(walk).keywords
  )
  assert saved['value_obs_key'] == walk.critic_obs == 'policy'
  assert tuple(saved['policy_layers']) == walk.policy_layers
  assert tuple(saved['value_layers']) == walk.value_layers


def test_ours_off_observes_humanoid_walks_vector():
  brax_env, _, saved = _setup('ours_off')
  # HumanoidWalk's 67 values alone: no history, no privileged group.
  assert brax_env.observation_size == {'policy': (67,)}
  assert saved['observation_size'] == {'policy': (67,)}
  assert brax_env.environment.auto_reset_batch is None


def test_feature_variants_train_like_ours_off_with_those_features():
  with pytest.raises(SystemExit):
    train_compare.parse_args(['--envs', 'only_wings'])
  brax_env, kwargs, _ = _setup('only_noise+randomize')
  task = brax_env.environment.task
  # The two features on; pushes and fall terminations stay off, so the
  # episodes are HumanoidWalk's 1,000 steps.
  assert task._randomize and task._pushes.interval == 0
  assert not task._terminate_on_fall
  assert brax_env.episode_length == 1000
  assert kwargs['num_envs'] == 2048


def test_a_shared_feature_variant_fuses_the_restart():
  brax_env, _, _ = _setup('only_noise_shared', '--no-share-reset-forward')
  assert brax_env.environment.share_reset_forward
  assert not brax_env.environment.task._randomize  # only the noise is on


def test_settings_brax_cannot_split_are_refused_before_building():
  config = dict(train_setups.fallback_config(), num_envs=3, batch_size=8)
  with pytest.raises(ValueError, match='multiple of num_envs'):
    train_setups.ours_config(config)


@pytest.mark.parametrize('env', ['ours', 'playground'])
def test_a_saved_policy_acts_as_the_one_trained(env, tmp_path):
  """`saved_policy` rebuilds the networks a run's saved config describes."""
  # pylint: disable=g-import-not-at-top
  from brax.training.acme import running_statistics
  from brax.training.agents.ppo import networks as ppo_networks
  # pylint: enable=g-import-not-at-top

  walk = config_lib.defaults('walk')
  if env == 'playground':
    # As `_playground_setup` saves it: Brax's default networks, one vector.
    config = dict(env='playground', observation_size=5, action_size=2)
    networks = ppo_networks.make_ppo_networks(
        5, 2, preprocess_observations_fn=running_statistics.normalize
    )
    spec = jnp.zeros((5,))
  else:
    config = dict(
        task='walk',
        observation_size={'policy': (5,)},
        action_size=2,
        value_obs_key='policy',
        policy_layers=list(walk.policy_layers),
        value_layers=list(walk.value_layers),
    )
    networks = policy.network_factory(walk)(
        {'policy': (5,)},
        2,
        preprocess_observations_fn=running_statistics.normalize,
    )
    spec = {'policy': jnp.zeros((5,))}
  config['normalize'] = walk.normalize  # True, as Playground's
  key = jax.random.PRNGKey(3)
  params = (
      running_statistics.init_state(spec),
      networks.policy_network.init(key),
      networks.value_network.init(key),
  )
  path = str(tmp_path / 'policy.pkl')
  train_segments.save_params(path, params, config)
  with open(path, 'rb') as f:
    saved = pickle.load(f)
  obs = jax.random.normal(key, (4, 5))
  trained = ppo_networks.make_inference_fn(networks)(params, True)
  want = trained(obs if env == 'playground' else {'policy': obs}, key)[0]
  # Every saved policy acts on our observation dict (a Playground policy
  # on the 'policy' group: HumanoidWalk's vector in ours_off).
  make_policy = train_setups.saved_policy(saved['config'])
  got = make_policy(saved['params'], deterministic=True)({'policy': obs}, key)
  assert got[0].shape == (4, 2)
  np.testing.assert_allclose(got[0], want, rtol=1e-6, atol=1e-6)
  assert np.ptp(np.asarray(want)) > 0


def test_child_command_line():
  argv = ['--out', 'x', '--gpus', '0,1', '--max-wall-s', '500', '--gpus=2']
  assert train_compare._child_argv(argv, 'ours', 2) == [
      '--out',
      'x',
      '--max-wall-s',
      '500',
      '--envs',
      'ours',
      '--seeds',
      '2',
  ]
  args = train_compare.parse_args(
      train_compare._child_argv(['--envs', 'playground', 'ours'], 'ours', 2)
  )
  assert args.envs == ['ours'] and args.seeds == [2]


def test_gpu_groups_give_each_run_its_devices():
  assert train_compare.gpu_groups('0,1,2', 1) == ['0', '1', '2']
  assert train_compare.gpu_groups('0+1, 2+3', 2) == ['0,1', '2,3']
  with pytest.raises(ValueError, match='--devices is 2'):
    train_compare.gpu_groups('0,1', 2)
  with pytest.raises(ValueError, match='in two runs'):
    train_compare.gpu_groups('0+1,1+2', 2)
  with pytest.raises(ValueError, match='distinct'):
    train_compare.gpu_groups('0+0', 2)
  with pytest.raises(ValueError, match='names no GPU'):
    train_compare.gpu_groups(',', 1)


def test_gpu_groups_give_each_run_its_devices():
  assert train_compare.gpu_groups('0,1,2', 1) == ['0', '1', '2']
  assert train_compare.gpu_groups('0+1, 2+3', 2) == ['0,1', '2,3']
  with pytest.raises(ValueError, match='--devices is 2'):
    train_compare.gpu_groups('0,1', 2)
  with pytest.raises(ValueError, match='in two runs'):
    train_compare.gpu_groups('0+1,1+2', 2)
  with pytest.raises(ValueError, match='distinct'):
    train_compare.gpu_groups('0+0', 2)
  with pytest.raises(ValueError, match='names no GPU'):
    train_compare.gpu_groups(',', 1)


def test_resume_refuses_an_out_without_the_runs(tmp_path):
  # The mistake it guards against: the previous call's runs not brought.
  with pytest.raises(SystemExit, match='holds no record'):
    train_compare.main(
        [
            '--out',
            str(tmp_path),
            '--envs',
            'ours_off',
            '--seeds',
            '0',
            '--resume',
        ]
    )
  assert not (tmp_path / 'runs').exists()


def test_render_needs_a_saved_policy(tmp_path, capsys):
  argv = ['--out', str(tmp_path), '--envs', 'ours_off', '--seeds', '0']
  assert (
      train_compare.render(train_compare.parse_args(argv + ['--render'])) == 1
  )
  assert 'no saved policy' in capsys.readouterr().out
