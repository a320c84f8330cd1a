"""What `train_compare.py` trains: environments and hyper-parameters.

Environments (`ENVS`, and variants of ours):

* playground: `mujoco_playground.registry.load('HumanoidWalk')` with the
  config overrides `{'impl': --playground-impl}` (default 'jax', MJX's JAX
  implementation, like ours; Playground's training script takes `--impl`
  too), trained the way Playground's `learning/train_jax_ppo.py` does: its
  PPO config as `ppo.train`'s arguments, Brax's default PPO networks, a
  second instance as `eval_env`, `wrap_env_fn=wrapper.wrap_for_brax_training`;
* ours: the registered walk task as shipped (policy noise, latency and
  history, per-episode randomization, pushes, falls end episodes) through
  `mjx_composer.adapters.brax`, trained as `mjx-composer train walk` trains
  it: `mjx_composer.training.config.defaults('walk')` with the
  hyper-parameters below (`ours_config`), its networks
  (`training.policy.network_factory`: the policy and critic both see the
  'policy' group) and `ppo.train`'s arguments from that config;
* ours_off: the walk task with those additions off
  (`walk.PLAYGROUND_EQUIVALENT`, the 'policy' group only: HumanoidWalk's
  observation, reward and episodes), otherwise as `ours`;
* only_<feature>[+<feature>...]: ours_off with those of ours' additions
  switched back on, named as in `playground_compare.py` (noise, delay,
  history, randomize, push, fall; e.g. only_noise+delay+history+randomize:
  the shipped task without pushes and fall terminations, so its episodes,
  and returns, are HumanoidWalk's), otherwise as `ours_off`; with the
  suffix `_shared` (as in `playground_compare.py`), with
  `share_reset_forward=True` whatever `--share-reset-forward` says.

Hyper-parameters (`hyperparameters`): `mujoco_playground.config.
dm_control_suite_params.brax_ppo_config('HumanoidWalk')` read at run time
when Playground imports (otherwise `config.defaults('walk')`, a copy of it,
plus `FALLBACK_EXTRA`), the same for every environment, with the command
line's overrides of single entries (`OVERRIDES`, for smoke runs).

Each set-up gives the environment, `ppo.train`'s keyword arguments but the
seed and evaluation settings, and what rebuilds its networks from saved
parameters (`saved_policy`).
"""

ENVS = ('playground', 'ours', 'ours_off')
PLAYGROUND_ENV = 'HumanoidWalk'
# Playground 0.2.0's HumanoidWalk PPO config entries that `TrainConfig` has
# no field for.
FALLBACK_EXTRA = {
    'episode_length': 1000,
    'action_repeat': 1,
    'num_resets_per_eval': 10,
}
# walk.Walk's default control timestep, Playground's ctrl_dt (seconds).
_WALK_CONTROL_TIMESTEP = 0.025
# `config.ppo_kwargs` entries that Playground's HumanoidWalk config leaves
# to Brax's defaults (the rest are its hyper-parameters).
NOT_PLAYGROUND = ('num_eval_envs', 'max_grad_norm', 'seed')
# Command-line overrides of single hyper-parameters (flag dest = ppo name).
OVERRIDES = (
    'num_timesteps',
    'num_evals',
    'num_resets_per_eval',
    'num_envs',
    'batch_size',
    'num_minibatches',
    'unroll_length',
    'num_updates_per_batch',
    'episode_length',
)

# -- hyper-parameters ----------------------------------------------------------


def playground_config():
  """(Playground's HumanoidWalk PPO config, a dict; version), or (None, why)."""
  try:
    # pylint: disable=g-import-not-at-top
    import importlib.metadata
    from mujoco_playground.config import dm_control_suite_params
    # pylint: enable=g-import-not-at-top
  except Exception as e:  # pylint: disable=broad-except
    return None, f'mujoco_playground cannot be imported: {e!r}'
  config = dm_control_suite_params.brax_ppo_config(PLAYGROUND_ENV).to_dict()
  try:
    version = importlib.metadata.version('playground')
  except importlib.metadata.PackageNotFoundError:
    version = 'unknown'
  return config, f'playground {version}'


def fallback_config():
  """Playground's config as `config.defaults('walk')` copies it."""
  from mjx_composer.training import config as config_lib  # pylint: disable=g-import-not-at-top

  config = config_lib.ppo_kwargs(config_lib.defaults('walk'))
  for name in NOT_PLAYGROUND:
    del config[name]
  return {**config, **FALLBACK_EXTRA}


def hyperparameters(args):
  """`(config, source)`: the `ppo.train` hyper-parameters every run uses.

  Playground's config (or the fallback), less its network factory (Brax's
  defaults, as for HumanoidWalk), with the command line's overrides.
  """
  config, source = playground_config()
  if config is None:
    print(f"Hyper-parameters: config.defaults('walk') ({source})")
    config, source = fallback_config(), "config.defaults('walk')"
  else:
    config.pop('network_factory', None)
    copy = fallback_config()
    differ = {
        k: (config.get(k), v) for k, v in copy.items() if config.get(k) != v
    }
    if differ:
      print(
          "Warning: config.defaults('walk') differs from "
          f'{source} (playground, copy): {differ}'
      )
  for name in OVERRIDES:
    value = getattr(args, name)
    if value is not None:
      config[name] = value
  return config, source


# -- environments --------------------------------------------------------------


def _playground_setup(config, args):
  """(env, ppo.train kwargs, policy config) for Playground's HumanoidWalk."""
  # pylint: disable=g-import-not-at-top
  from brax.training.agents.ppo import networks as ppo_networks
  from mujoco_playground import registry
  from mujoco_playground import wrapper
  from mjx_composer.adapters import brax as brax_adapter
  # pylint: enable=g-import-not-at-top

  brax_adapter.install_jax_compat()  # Brax 0.14 on JAX >= 0.10.
  overrides = {'impl': args.playground_impl}
  env = registry.load(
      PLAYGROUND_ENV,
      config=registry.get_default_config(PLAYGROUND_ENV),
      config_overrides=overrides,
  )
  eval_env = registry.load(
      PLAYGROUND_ENV,
      config=registry.get_default_config(PLAYGROUND_ENV),
      config_overrides=overrides,
  )
  kwargs = dict(config)
  kwargs.update(
      network_factory=ppo_networks.make_ppo_networks,
      wrap_env_fn=wrapper.wrap_for_brax_training,
      eval_env=eval_env,
  )
  policy = {
      'env': 'playground',
      'observation_size': env.observation_size,
      'action_size': env.action_size,
      'normalize': config['normalize_observations'],
      'network_factory': 'brax ppo_networks.make_ppo_networks defaults',
  }
  return env, kwargs, policy


def ours_config(config):
  """Our walk task's `TrainConfig`: its defaults with `config`'s values.

  `mjx_composer.training.config.defaults('walk')` (the settings of
  `mjx-composer train walk`: its networks among them) with the `ppo.train`
  hyper-parameters `config` and episodes of `config['episode_length']`
  control steps; checked as a config file's values would be.
  """
  from mjx_composer.training import config as config_lib  # pylint: disable=g-import-not-at-top

  return config_lib.defaults('walk').replace(
      time_limit=config['episode_length'] * _WALK_CONTROL_TIMESTEP,
      **{
          field: config[ppo]
          for field, ppo in config_lib.PPO_ARGUMENTS.items()
          if ppo in config
      },
  )


def ours_environment(name, time_limit, args):
  """The `Environment` of ours, ours_off or an only_... variant."""
  # pylint: disable=g-import-not-at-top
  import common
  import playground_compare
  import mjx_composer as composer
  from mjx_composer.suite.tasks import registry
  # pylint: enable=g-import-not-at-top

  if name.startswith('only_'):
    return playground_compare.env_variants(
        [name], share_reset_forward=args.share_reset_forward
    )[name]
  options = dict(share_reset_forward=args.share_reset_forward)
  if args.auto_reset_batch is not None:
    options['auto_reset_batch'] = args.auto_reset_batch
  if name == 'ours_off':
    return common.make_walk_like_playground(time_limit, **options)
  return registry.make_environment(
      'walk',
      time_limit=time_limit,
      options=composer.ExecutionOptions(auto_reset='same_step', **options),
  )


def _ours_setup(name, config, args):
  """(env, ppo.train kwargs, policy config) for ours and its variants.

  The environment of `name` (`ours_environment`), trained with
  `ours_config(config)`'s `ppo.train` arguments and networks: Playground's
  values, our walk task's networks.
  """
  # pylint: disable=g-import-not-at-top
  from mjx_composer.adapters import brax as brax_adapter
  from mjx_composer.training import config as config_lib
  from mjx_composer.training import policy
  # pylint: enable=g-import-not-at-top

  train_config = ours_config(config)
  brax_env = brax_adapter.BraxEnv(
      ours_environment(name, train_config.time_limit, args)
  )
  if brax_env.episode_length != config['episode_length']:
    raise ValueError(
        f'{name}: episodes of {brax_env.episode_length} steps, Playground '
        f'{config["episode_length"]}.'
    )
  kwargs = config_lib.ppo_kwargs(train_config)
  kwargs.update(
      # What TrainConfig has no field for, as Playground trains.
      num_resets_per_eval=config['num_resets_per_eval'],
      action_repeat=config['action_repeat'],
      network_factory=policy.network_factory(train_config),
      **brax_adapter.training_kwargs(brax_env),
  )
  different = {
      k: (kwargs[k], v)
      for k, v in config.items()
      if k in kwargs and kwargs[k] != v
  }
  if different:
    raise AssertionError(f'{name} would train with other values: {different}')
  policy_config = {
      'task': 'walk',
      'observation_size': brax_env.observation_size,
      'action_size': brax_env.action_size,
      'value_obs_key': train_config.critic_obs,
      'normalize': train_config.normalize,
      'policy_layers': list(train_config.policy_layers),
      'value_layers': list(train_config.value_layers),
  }
  return brax_env, kwargs, policy_config


def setup(env_name, config, args):
  """`(brax env, ppo.train kwargs, policy config)` of one environment.

  Args:
    env_name: `ENVS`' or an only_... variant.
    config: the `ppo.train` hyper-parameters (`hyperparameters`).
    args: `train_compare.py`'s flags (`--playground-impl`,
      `--share-reset-forward`, `--auto-reset-batch`).
  """
  if env_name == 'playground':
    return _playground_setup(config, args)
  return _ours_setup(env_name, config, args)


def saved_policy(config):
  """Brax's `make_policy(params, deterministic)` for a saved policy's config.

  Ours' networks from the sizes and groups the config records; a Playground
  run's are Brax's default networks over one vector, given our 'policy'
  group's (ours_off's is HumanoidWalk's observation).
  """
  # pylint: disable=g-import-not-at-top
  from brax.training import types
  from brax.training.acme import running_statistics
  from brax.training.agents.ppo import networks as ppo_networks
  # pylint: enable=g-import-not-at-top

  preprocess = (
      running_statistics.normalize
      if config['normalize']
      else types.identity_observation_preprocessor
  )
  if config.get('env') == 'playground':
    networks = ppo_networks.make_ppo_networks(
        config['observation_size'],
        config['action_size'],
        preprocess_observations_fn=preprocess,
    )
    make = ppo_networks.make_inference_fn(networks)

    def make_policy(params, deterministic=True):
      policy = make(params, deterministic=deterministic)
      return lambda obs, key: policy(obs['policy'], key)

    return make_policy
  networks = ppo_networks.make_ppo_networks(
      {k: tuple(v) for k, v in config['observation_size'].items()},
      config['action_size'],
      preprocess_observations_fn=preprocess,
      policy_obs_key='policy',
      value_obs_key=config['value_obs_key'],
      policy_hidden_layer_sizes=tuple(config['policy_layers']),
      value_hidden_layer_sizes=tuple(config['value_layers']),
  )
  return ppo_networks.make_inference_fn(networks)
