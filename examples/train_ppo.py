"""Trains a registered task with Brax's PPO and saves a Brax checkpoint.

    python examples/train_ppo.py reach --out runs/reach_ppo
    python examples/train_ppo.py walk --num-timesteps 20000000

Training a task of this package with Brax takes library calls only, as in
MuJoCo Playground's training scripts: the task's environment from the
registry, made a Brax `Env` by `mjx_composer.adapters.brax`
(`mjx_composer.training.policy.make_environment`); the task's training
settings (`mjx_composer.training.config.defaults(task)`: Playground's PPO
settings for walk and joystick, as `ppo.train`'s arguments by
`config.ppo_kwargs`); Brax's PPO networks for them
(`training.policy.network_factory`: the policy sees the 'policy'
observation group, the critic the config's `critic_obs`); and Brax's
`ppo.train`, unchanged, on one device. Each evaluation is printed; the
final parameters are saved with Brax's checkpoint API in `OUT/<step>/`
(twelve digits), which Brax loads back:

    from brax.training.agents.ppo import checkpoint
    policy = checkpoint.load_policy('runs/reach_ppo/000013107200')
    action, _ = policy(obs, jax.random.PRNGKey(0))   # obs: {'policy': ...}

`mjx-composer train TASK` trains with the same settings into a run folder
that resumes, plays and exports, on several devices, with TensorBoard and
videos (docs/training.md).
"""

import argparse
import os
import sys
import time

from brax.training.agents.ppo import checkpoint
from brax.training.agents.ppo import train as ppo

from mjx_composer import platform
from mjx_composer.adapters import brax as brax_adapter
from mjx_composer.suite.tasks import registry
from mjx_composer.training import config as config_lib
from mjx_composer.training import policy

# Settings the command line overrides (the rest are the task's defaults).
OVERRIDES = (
    'num_timesteps num_envs num_evals num_eval_envs batch_size num_minibatches'
    ' unroll_length seed'
).split()


def parse_args(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('task', choices=registry.names(), help='task to train')
  parser.add_argument(
      '--out', help='checkpoint folder (default: runs/<task>_ppo)'
  )
  for name in OVERRIDES:
    parser.add_argument(
        '--' + name.replace('_', '-'), type=int, help="default: the task's"
    )
  args = parser.parse_args(argv)
  overrides = {k: getattr(args, k) for k in OVERRIDES}
  overrides = {k: v for k, v in overrides.items() if v is not None}
  try:
    config = config_lib.defaults(args.task).replace(**overrides)
  except ValueError as e:
    parser.error(str(e))
  return config, args.out or os.path.join('runs', f'{args.task}_ppo')


def train(config, out):
  """Trains `config` and saves a checkpoint in `out`.

  Returns:
    `(make_policy, params, path)`: Brax's inference-function factory, the
    trained `(normalizer, policy, value)` parameters and the checkpoint.
  """
  env, brax_env = policy.make_environment(config)
  print(
      f'{config.task}: physics on {env.impl}, episodes of '
      f'{brax_env.episode_length} steps, observations '
      f'{brax_env.observation_size}, {brax_env.action_size} actions.'
  )
  network_factory = policy.network_factory(config)
  start = time.perf_counter()
  steps = []

  def progress(step, metrics):
    steps.append(int(step))
    print(
        f'step {step:>12,}  {time.perf_counter() - start:8.1f} s  return '
        f'{metrics["eval/episode_reward"]:9.3f} ± '
        f'{metrics["eval/episode_reward_std"]:.3f}',
        flush=True,
    )

  make_policy, params, _ = ppo.train(
      environment=brax_env,
      **config_lib.ppo_kwargs(config),  # the task's hyper-parameters
      deterministic_eval=True,
      max_devices_per_host=1,
      network_factory=network_factory,
      progress_fn=progress,
      **brax_adapter.training_kwargs(brax_env),  # episode_length, wrapper
  )
  network_config = checkpoint.network_config(
      brax_env.observation_size,
      brax_env.action_size,
      config.normalize,
      network_factory,
  )
  # Brax 0.14's load_config looks every kernel initializer up by name, None
  # too: leave those out (their default, None, applies when loading).
  kwargs = network_config.network_factory_kwargs
  for name in [k for k, v in kwargs.items() if k.endswith('_fn') and v is None]:
    del kwargs[name]
  out = os.path.abspath(out)  # orbax writes to absolute paths only
  checkpoint.save(out, steps[-1], params, network_config)
  path = os.path.join(out, f'{steps[-1]:012d}')
  print(f'Trained in {time.perf_counter() - start:.1f} s; saved {path}')
  return make_policy, params, path


def main(argv=None):
  config, out = parse_args(argv)
  platform.configure()  # JAX's persistent compilation cache, among others
  train(config, out)
  return 0


if __name__ == '__main__':
  sys.exit(main())
