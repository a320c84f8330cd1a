"""A training loop in plain JAX: `lax.scan` over `vmap(env.step)`, no Brax.

    python examples/jax_training_loop.py --worlds 256 --iterations 40

The functional API is all a training loop needs. `reset` and `step` are pure
functions of one world; `jax.vmap` makes them a batch, `jax.lax.scan` an
unroll, and `jax.jit` one compiled program for a whole iteration: rollout,
policy gradient and optimizer update.

The learner is REINFORCE with a per-time-step baseline (the mean return-to-go
over worlds) and a Gaussian flax policy on the reach task's 'policy'
observation group. Reach episodes only end at the time limit, so every world
starts together and an unroll of one episode length is one episode per world;
with `auto_reset='same_step'` the state after the unroll already holds the
next episode's first observation, so iterations just carry the state on.

The compiled iteration is kept in JAX's persistent compilation cache
(`mjx_composer.platform.compilation_cache`; `MJX_COMPOSER_COMPILATION_CACHE=0` turns
it off), so a second run starts training sooner.
"""

import argparse
import time

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax

import mjx_composer as composer
from mjx_composer import platform
from mjx_composer.suite.tasks import registry


class Policy(nn.Module):
  """A Gaussian policy: an MLP for the mean, a learned log-std per action."""

  action_size: int
  hidden: tuple = (64, 64)

  @nn.compact
  def __call__(self, obs):
    x = obs
    for width in self.hidden:
      x = nn.tanh(nn.Dense(width)(x))
    mean = nn.Dense(self.action_size, kernel_init=nn.initializers.normal(0.01))(
        x
    )
    log_std = self.param(
        'log_std', nn.initializers.constant(-0.5), (self.action_size,)
    )
    return mean, log_std


def gaussian_log_prob(action, mean, log_std):
  return jnp.sum(
      -0.5 * ((action - mean) / jnp.exp(log_std)) ** 2
      - log_std
      - 0.5 * jnp.log(2 * jnp.pi),
      axis=-1,
  )


def make_trainer(env, num_worlds, learning_rate=3e-3, discount=0.97):
  """Returns `init(key) -> carry` and a jitted `iteration(carry) -> carry, stats`."""
  action_size = env.action_spec().shape[0]
  unroll = round(env.time_limit / env.control_timestep())
  policy = Policy(action_size)
  optimizer = optax.adam(learning_rate)
  reset = jax.vmap(env.reset)
  step = jax.vmap(env.step)

  def init(key):
    reset_key, param_key, key = jax.random.split(key, 3)
    states = reset(jax.random.split(reset_key, num_worlds))
    params = policy.init(param_key, states.observation['policy'])
    return states, params, optimizer.init(params), key

  def rollout(params, states, key):
    """One episode per world; returns the observations, actions and rewards."""

    def one_step(carry, step_key):
      states = carry
      obs = states.observation['policy']
      mean, log_std = policy.apply(params, obs)
      action = mean + jnp.exp(log_std) * jax.random.normal(step_key, mean.shape)
      states = step(states, jnp.clip(action, -1.0, 1.0))
      return states, (obs, action, states.reward)

    states, (obs, actions, rewards) = jax.lax.scan(
        one_step, states, jax.random.split(key, unroll)
    )
    return states, obs, actions, rewards

  def loss_fn(params, obs, actions, returns):
    mean, log_std = policy.apply(params, obs)
    log_prob = gaussian_log_prob(actions, mean, log_std)
    # Baseline: the mean return-to-go of all worlds at each time step.
    advantage = returns - returns.mean(axis=1, keepdims=True)
    advantage = advantage / (advantage.std() + 1e-6)
    return -jnp.mean(log_prob * jax.lax.stop_gradient(advantage))

  @jax.jit
  def iteration(carry):
    states, params, opt_state, key = carry
    key, rollout_key = jax.random.split(key)
    states, obs, actions, rewards = rollout(params, states, rollout_key)

    def discounted(next_return, reward):
      ret = reward + discount * next_return
      return ret, ret

    _, returns = jax.lax.scan(
        discounted, jnp.zeros(num_worlds), rewards, reverse=True
    )
    grads = jax.grad(loss_fn)(params, obs, actions, returns)
    updates, opt_state = optimizer.update(grads, opt_state)
    params = optax.apply_updates(params, updates)
    stats = {
        'episode_return': rewards.sum(0).mean(),
        'final_distance': states.metrics['distance'].mean(),
    }
    return (states, params, opt_state, key), stats

  return init, iteration


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
  parser.add_argument('--worlds', type=int, default=256)
  parser.add_argument('--iterations', type=int, default=40)
  parser.add_argument('--time-limit', type=float, default=1.0)
  parser.add_argument('--learning-rate', type=float, default=3e-3)
  parser.add_argument('--seed', type=int, default=0)
  args = parser.parse_args(argv)
  platform.configure()

  env = registry.make_environment(
      'reach',
      time_limit=args.time_limit,
      options=composer.ExecutionOptions(auto_reset='same_step'),
  )
  init, iteration = make_trainer(env, args.worlds, args.learning_rate)
  carry = init(jax.random.key(args.seed))
  start = time.perf_counter()
  returns = []
  for i in range(args.iterations):
    carry, stats = iteration(carry)
    returns.append(float(stats['episode_return']))
    if i == 0:
      print(f'compiled in {time.perf_counter() - start:.0f}s')
    print(
        f'iteration {i:3d}  return {returns[-1]:7.3f}  final distance '
        f'{float(stats["final_distance"]):.3f} m'
    )
  print(
      f'return: first {returns[0]:.3f}, last {returns[-1]:.3f}, in '
      f'{time.perf_counter() - start:.0f}s'
  )
  return returns


if __name__ == '__main__':
  main()
