"""The environment and the networks a run trains, rebuilt from its config.

`make_environment` builds the task's `Environment` and `BraxEnv` as training
uses them; `network_factory` is Brax's PPO networks for the config (the
policy sees the 'policy' group, the critic `critic_obs`); `make_inference`
is Brax's `make_policy` for a checkpoint; `load` is a run's newest policy.
"""

from __future__ import annotations

import functools

from mjx_composer import environment as environment_lib
from mjx_composer.adapters import brax as brax_adapter
from mjx_composer.suite.tasks import registry
from mjx_composer.training import checkpoints
from mjx_composer.training import config as config_lib
from mjx_composer.training import run_folder

POLICY_GROUP = 'policy'


def make_environment(config: config_lib.TrainConfig, impl=None):
  """`(env, brax_env)` of the config's task; `impl` overrides `config.impl`."""
  impl = impl or config.impl
  options = environment_lib.ExecutionOptions(auto_reset='same_step', impl=impl)
  env = registry.make_environment(config.task, config.time_limit, options)
  brax_env = brax_adapter.BraxEnv(env)
  size = brax_env.observation_size
  needed = {POLICY_GROUP, config.critic_obs}
  if not isinstance(size, dict) or not needed <= set(size):
    raise ValueError(
        f'Task {config.task!r} gives observations {size}; training needs the '
        f'observation groups {sorted(needed)} (Task.observation_groups). '
        "Pass --critic-obs policy if the task has no 'critic' group."
    )
  return env, brax_env


def network_factory(config: config_lib.TrainConfig):
  """Brax's `make_ppo_networks` with the config's sizes and groups."""
  from brax.training.agents.ppo import networks as ppo_networks  # pylint: disable=g-import-not-at-top

  return functools.partial(
      ppo_networks.make_ppo_networks,
      policy_obs_key=POLICY_GROUP,
      value_obs_key=config.critic_obs,
      policy_hidden_layer_sizes=tuple(config.policy_layers),
      value_hidden_layer_sizes=tuple(config.value_layers),
      init_noise_std=config.init_noise_std,
  )


def make_inference(config: config_lib.TrainConfig, checkpoint):
  """Brax's `make_policy(params, deterministic)` for a checkpoint's networks."""
  # pylint: disable=g-import-not-at-top
  from brax.training import types as brax_types
  from brax.training.acme import running_statistics
  from brax.training.agents.ppo import networks as ppo_networks
  # pylint: enable=g-import-not-at-top

  networks = network_factory(config)(
      checkpoint.observation_size,
      checkpoint.action_size,
      preprocess_observations_fn=(
          running_statistics.normalize
          if config.normalize
          else brax_types.identity_observation_preprocessor
      ),
  )
  return ppo_networks.make_inference_fn(networks)


def load(run_path: str):
  """`(run, config, newest checkpoint, env, brax_env)` of a run folder."""
  run = run_folder.open_run(run_path)
  config = run.read_config()
  checkpoint = checkpoints.latest(run)
  env, brax_env = make_environment(config)
  checkpoints.check_compatible(checkpoint, config.task, brax_env)
  return run, config, checkpoint, env, brax_env
