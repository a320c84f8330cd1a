"""examples/train_ppo.py: a tiny run of a small task, loaded back by Brax.

The task is the tests' pendulum swing, registered as 'swing' for this
module (it compiles in seconds where a bundled robot takes minutes); the
script trains it for two updates of four worlds.
"""

import contextlib
import io

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from brax.training.agents.ppo import checkpoint
from mjx_composer.observation import groups as groups_lib
from mjx_composer.suite.tasks import registry
from tests import conftest

import train_ppo  # examples/train_ppo.py

# 4 worlds x 5 steps x 2 minibatches: 40 env steps per update; two updates
# between the two evaluations.
_TINY = [
    '--num-timesteps', '80', '--num-envs', '4', '--batch-size', '4',
    '--num-minibatches', '2', '--unroll-length', '5', '--num-evals', '2',
    '--num-eval-envs', '2',
]  # fmt: skip


class _Swing(conftest.SwingTask):
  """The swing task with the 'policy' group that training reads."""

  def observation_groups(self):
    return {'policy': groups_lib.ObservationGroup(keys=['tip'], flatten=True)}


@pytest.fixture(scope='module', autouse=True)
def swing():
  registry.register('swing', _Swing, description='The tests pendulum.')
  yield
  registry.unregister('swing')


@pytest.fixture(scope='module')
def trained(tmp_path_factory, swing):
  """`(config, make_policy, params, checkpoint path, printed lines)`."""
  del swing
  out = str(tmp_path_factory.mktemp('ppo'))
  config, folder = train_ppo.parse_args(['swing', '--out', out] + _TINY)
  assert folder == out
  printed = io.StringIO()
  with contextlib.redirect_stdout(printed):
    make_policy, params, path = train_ppo.train(config, folder)
  return config, make_policy, params, path, printed.getvalue().splitlines()


def test_each_evaluation_is_printed(trained):
  lines = trained[4]
  evaluations = [line.split()[1] for line in lines if line.startswith('step')]
  assert evaluations == ['0', '80']
  assert lines[-1].startswith('Trained in') and lines[-1].endswith(trained[3])


def test_the_checkpoint_is_at_the_trained_step(trained):
  config, _, _, path, _ = trained
  assert (config.num_envs, config.batch_size) == (4, 4)
  # Brax trains whole updates of 40 steps: 80 steps, two updates.
  assert path.endswith('/000000000080')
  saved = checkpoint.load_config(path)
  sizes = {k: list(v) for k, v in saved.observation_size.items()}
  assert sizes == {'policy': [3]}  # the tip's position
  assert saved.action_size == 1
  kwargs = saved.network_factory_kwargs
  assert (kwargs.policy_obs_key, kwargs.value_obs_key) == ('policy', 'policy')
  assert tuple(kwargs.policy_hidden_layer_sizes) == config.policy_layers
  assert tuple(kwargs.value_hidden_layer_sizes) == config.value_layers


def test_brax_loads_the_trained_parameters(trained):
  _, _, params, path, _ = trained
  loaded = checkpoint.load(path)
  got, want = jax.tree.leaves(loaded), jax.tree.leaves(params)
  assert len(got) == len(want)
  for a, b in zip(got, want):
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_brax_policy_from_the_checkpoint_acts_as_the_trained_one(trained):
  _, make_policy, params, path, _ = trained
  loaded = checkpoint.load_policy(path)  # Brax's default network factory
  trained_policy = make_policy(params, deterministic=True)
  obs = {'policy': jnp.linspace(-1.0, 1.0, 21).reshape(7, 3)}
  key = jax.random.PRNGKey(0)
  got, want = loaded(obs, key)[0], trained_policy(obs, key)[0]
  assert got.shape == (7, 1)
  np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)
  # The policy depends on its observation (trained networks, not zeros).
  assert np.ptp(np.asarray(got)) > 0


def test_settings_brax_cannot_split_are_refused_early(swing, capsys):
  del swing
  with pytest.raises(SystemExit):
    train_ppo.parse_args(['swing', '--num-envs', '3', '--batch-size', '4'])
  assert 'multiple of num_envs' in capsys.readouterr().err
  with pytest.raises(SystemExit):
    train_ppo.parse_args(['no_such_task'])
