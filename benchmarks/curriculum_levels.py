"""The terrain levels a trained policy reaches: the curriculum's distribution.

Loads a training run's newest checkpoint (`mjx-composer train` of a task on
generated terrain, e.g. joystick_terrain), runs `--worlds` worlds of the
run's task for `--episodes` episodes' worth of control steps with the
policy (deterministic, same-step auto-reset: each world's curriculum moves
its level at every restart, as in training), and reports how many worlds
stand at each level after each episode's worth of steps, with the mean
return and length of the episodes that ended.

    python benchmarks/curriculum_levels.py RUN --worlds 4096 --episodes 6
"""

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer.adapters import brax as brax_adapter
from mjx_composer.training import checkpoints
from mjx_composer.training import policy as policy_lib
from mjx_composer.training import run_folder

import common  # benchmarks/common.py

LEVEL = 'terrain_level'


def level_histograms(run_path, worlds, episodes, seed=0):
  """`(levels, histograms, returns, lengths, config)` of the run's policy.

  `histograms[e]` counts the worlds at each level after `e + 1` episodes'
  worth of steps; `returns` and `lengths` are those of the episodes that
  ended in each of those spans (NaN where none ended).
  """
  run = run_folder.open_run(run_path)
  config = run.read_config()
  checkpoint = checkpoints.latest(run)
  env, brax_env = policy_lib.make_environment(config)
  levels = env.task.terrain.levels
  policy = policy_lib.make_inference(config, checkpoint)(
      checkpoint.params, deterministic=True
  )
  steps = brax_env.episode_length

  @jax.jit
  def span(state, key):
    def one_step(carry, key):
      state, returns, lengths, ended = carry
      action, _ = policy(state.obs, key)
      state = brax_env.step(state, action)
      metrics = brax_adapter.composer_state(state).metrics
      done = state.done > 0
      returns += jnp.where(done, metrics['episode_return'], 0.0)
      lengths += jnp.where(done, metrics['episode_length'], 0.0)
      return (state, returns, lengths, ended + done), None

    zeros = jnp.zeros(worlds, jnp.float32)
    (state, returns, lengths, ended), _ = jax.lax.scan(
        one_step, (state, zeros, zeros, zeros), jax.random.split(key, steps)
    )
    level = brax_adapter.composer_state(state).metrics[LEVEL].astype(jnp.int32)
    histogram = jnp.bincount(level, length=levels)
    return state, histogram, returns.sum(), lengths.sum(), ended.sum()

  key = jax.random.PRNGKey(seed)
  state = jax.jit(brax_env.reset)(jax.random.split(key, worlds))
  histograms, returns, lengths = [], [], []
  for episode in range(episodes):
    state, histogram, total_return, total_length, ended = span(
        state, jax.random.fold_in(key, episode)
    )
    ended = float(ended)
    histograms.append(np.asarray(histogram).tolist())
    returns.append(float(total_return) / ended if ended else float('nan'))
    lengths.append(float(total_length) / ended if ended else float('nan'))
    print(
        f'after {episode + 1} episodes of steps: levels {histograms[-1]}, '
        f'{ended:.0f} episodes ended, mean return {returns[-1]:.2f}, '
        f'mean length {lengths[-1]:.0f}',
        flush=True,
    )
  return levels, histograms, returns, lengths, config


def main():
  parser = argparse.ArgumentParser(
      description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
  )
  parser.add_argument('run', help='the training run folder')
  parser.add_argument('--worlds', type=int, default=4096)
  parser.add_argument('--episodes', type=int, default=6)
  parser.add_argument('--seed', type=int, default=0)
  common.add_out_arg(parser, 'curriculum_levels.json')
  args = parser.parse_args()
  device = common.print_device()
  levels, histograms, returns, lengths, config = level_histograms(
      args.run, args.worlds, args.episodes, args.seed
  )
  common.write_json(
      args.out,
      dict(
          device=device.device_kind,
          task=config.task,
          run=args.run,
          worlds=args.worlds,
          levels=levels,
          histograms=histograms,
          mean_returns=returns,
          mean_lengths=lengths,
      ),
  )
  print(f'Wrote {args.out}')


if __name__ == '__main__':
  main()
