"""Trained walk policies swapped between Playground's HumanoidWalk and ours.

Our walk task with its additions off (`walk.PLAYGROUND_EQUIVALENT`,
`train_compare.py`'s `ours_off`, `train_ppo.py --task walk
--like-playground`) is meant to be MuJoCo Playground's `HumanoidWalk`: the
same model, the same 67 observed numbers in the same order, the same reward,
control step and 1,000-step episodes. If it is, a policy trained on either
earns on the other what it earns at home. This runs each policy of
`--policies` (`train_compare.py`'s `runs/<env>_seed<k>_policy.pkl`, from
either environment) for one episode in `--worlds` worlds of each environment,
and reports the episode return (the sum of the 1,000 rewards) per policy and
environment, mean and standard deviation over the worlds:

* deterministic: the policy's mean action. Every episode of both
  environments starts from the model's `qpos0`, so the worlds agree up to
  rounding;
* stochastic: actions sampled from the policy, as Brax's evaluator in
  `train_compare.py` does (its evaluation returns are of this kind).

    PYTHONPATH=<playground's site> python benchmarks/swap_policies.py \\
        --policies OUT/runs/playground_seed1_policy.pkl \\
                   OUT/runs/ours_off_seed0_policy.pkl --out swap.json

Needs `mujoco_playground` (0.2.0, as `train_compare.py`).
"""

import argparse
import json
import os
import pickle
import sys

import jax
import jax.numpy as jnp

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
# pylint: disable=g-import-not-at-top,wrong-import-position
import train_compare
import train_ppo

# pylint: enable=g-import-not-at-top,wrong-import-position

ENVS = ('playground', 'ours_off')


def load_policy(path, deterministic):
  """`(policy(obs, key) -> (action, extras), its observation's form)`.

  The form is 'array' for a policy trained on Playground (its observation
  is one vector) and 'group' for one trained on ours (a dict with the
  'policy' group's vector).
  """
  with open(path, 'rb') as f:
    saved = pickle.load(f)
  if saved['config'].get('env') == 'playground':
    return train_ppo.playground_policy(saved, deterministic), 'array'
  return train_ppo.load_policy(path, deterministic), 'group'


def make_env(name):
  """`(reset(keys) -> states, step(states, actions) -> states, obs form)`.

  Both batched over worlds; a state's `obs` and `reward` are per world.
  """
  if name == 'playground':
    # pylint: disable=g-import-not-at-top
    from mujoco_playground import registry
    from mjx_composer.adapters import brax as brax_adapter
    # pylint: enable=g-import-not-at-top

    brax_adapter.install_jax_compat()
    env = registry.load(
        train_compare.PLAYGROUND_ENV,
        config=registry.get_default_config(train_compare.PLAYGROUND_ENV),
        config_overrides={'impl': 'jax'},
    )
    return jax.vmap(env.reset), jax.vmap(env.step), 'array'
  args = train_ppo.parse_args(['--task', 'walk', '--like-playground'])
  _, brax_env = train_ppo.make_brax_env(args)
  return brax_env.reset, brax_env.step, 'group'


def _observation(obs, env_form, policy_form):
  """`obs` of an environment, in the form a policy takes."""
  if env_form == policy_form:
    return obs
  if env_form == 'group':  # Ours, to a Playground policy.
    return obs['policy']
  return {'policy': obs}  # Playground's, to ours.


def episode_returns(env, policy, worlds, steps, seed):
  """Per-world sums of `steps` rewards of `policy` in `env` (`make_env`)."""
  reset, step, env_form = env
  act, policy_form = policy

  def one_step(state, key):
    keys = jax.random.split(key, worlds)
    obs = _observation(state.obs, env_form, policy_form)
    action = jax.vmap(lambda o, k: act(o, k)[0])(obs, keys)
    state = step(state, action)
    return state, state.reward

  @jax.jit
  def rollout(key):
    reset_key, step_key = jax.random.split(key)
    state = reset(jax.random.split(reset_key, worlds))
    _, rewards = jax.lax.scan(
        one_step, state, jax.random.split(step_key, steps)
    )
    return jnp.sum(rewards, axis=0)

  return rollout(jax.random.PRNGKey(seed))


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--policies', nargs='+', required=True)
  parser.add_argument('--worlds', type=int, default=16)
  parser.add_argument(
      '--steps', type=int, default=1000, help='control steps (one episode)'
  )
  parser.add_argument('--seed', type=int, default=0)
  parser.add_argument(
      '--envs', nargs='+', choices=ENVS, default=list(ENVS), help='run in'
  )
  parser.add_argument(
      '--modes',
      nargs='+',
      choices=('deterministic', 'stochastic'),
      default=['deterministic', 'stochastic'],
      help='which actions: the mean, sampled, or both',
  )
  parser.add_argument('--out', default=None, help='JSON of the returns')
  args = parser.parse_args(argv)

  envs = {name: make_env(name) for name in args.envs}
  results = []
  for path in args.policies:
    for deterministic in [mode == 'deterministic' for mode in args.modes]:
      policy = load_policy(path, deterministic)
      for name, env in envs.items():
        returns = episode_returns(
            env, policy, args.worlds, args.steps, args.seed
        )
        row = {
            'policy': os.path.basename(path),
            'deterministic': deterministic,
            'env': name,
            'return_mean': float(jnp.mean(returns)),
            'return_std': float(jnp.std(returns)),
        }
        results.append(row)
        print(
            f'{row["policy"]:32s} '
            f'{"deterministic" if deterministic else "stochastic":13s} '
            f'in {name:10s}: {row["return_mean"]:8.2f} ± '
            f'{row["return_std"]:.2f}',
            flush=True,
        )
  if args.out:
    with open(args.out, 'w') as f:
      json.dump(
          {
              'device': str(jax.devices()[0].device_kind),
              'worlds': args.worlds,
              'steps': args.steps,
              'seed': args.seed,
              'results': results,
          },
          f,
          indent=1,
      )
  return 0


if __name__ == '__main__':
  sys.exit(main())
