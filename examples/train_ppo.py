"""Trains a bundled composed task with Brax's PPO and reports time to a return.

    python examples/train_ppo.py --task reach --num-timesteps 8000000 \\
        --threshold 20 --out runs/reach

`--task walk` and `--task joystick` (`joystick_rough`) default to MuJoCo
Playground's PPO settings for HumanoidWalk and Go1Joystick (`TASK_DEFAULTS`:
episode length, network sizes, discount, reward scaling, ...), the settings
of `mjx-composer train` (`mjx_composer.training.config.TASK_DEFAULTS`).

To train a task into a run folder that can be resumed, played and exported
(checkpoints, TensorBoard, videos, ONNX), use `mjx-composer train TASK`
(docs/training.md); this script is the benchmark-minded variant: time to a
return threshold, rollout metrics against zero actions, Playground's
comparison set-ups (`--like-playground`), and the pieces that
`benchmarks/train_compare.py` imports.

Brax trains on every local device by default (its `pmap`, each device with
`--num-envs / N` worlds and its share of each minibatch, gradients averaged
across them); `--devices N` trains on the first N (Brax's
`max_devices_per_host`). `--num-envs` and `--batch-size` must be multiples
of N.

Brax's `ppo.train` runs unchanged on the task through
`mjx_composer.adapters.brax` (per-episode randomization, our auto-reset,
truncation reported as truncation). The policy and the critic see the
'policy' observation group; with `--obs asymmetric` the critic sees the
privileged 'critic' group instead. The script shows a
progress bar, evaluates `--num-evals` times, and writes to `--out`:

* `returns.csv` and `returns.json`: step, wall-clock seconds since the start
  of `ppo.train` (compilation included), Brax's training wall time, and the
  evaluation return (mean and std over `--num-eval-envs` episodes);
* `returns.png`: evaluation return against wall-clock time, with the
  threshold (needs matplotlib; skipped with a warning without it);
* `policy.pkl`: `{'params': (normalizer, policy, value), 'config': ...}` with
  numpy leaves; `load_policy(path)` below rebuilds the inference function;
* `rollout_metrics.json`: the task's metrics (`State.metrics`, e.g. the
  joystick's velocity tracking error) and the reward, averaged over
  `--metrics-worlds` worlds and `--render-steps` steps, for the trained
  deterministic policy and, from the same reset, for zero actions
  (`write_rollout_metrics`);
* `rollout.png` (an image strip: one row per world, columns in time),
  `rollout_frames/step_NNN.png` (the strip's columns, each a grid of the
  worlds) and `rollout.gif` of the trained deterministic policy (needs a
  headless OpenGL; skipped with a warning without it). Walk and joystick
  are drawn from the robot's tracking camera, which
  follows its centre of mass (`mjx_composer.training.video.CAMERAS`);
* `summary.json`, including `time_to_threshold_s`.

`--max-wall-s S` ends training after the first evaluation from which the
next one would finish later than S seconds after the start of `ppo.train`
(the interval between the last two evaluations, less the time it spent
compiling, is the estimate), then saves
the last evaluated policy and writes everything as usual (`summary.json`
records `stopped_early`), so a run fits a time limit.

The last lines printed are a short table. Time to threshold is the wall-clock
time from the start of `ppo.train` (compilation included) to the first
evaluation whose mean return reaches `--threshold`.

JAX's persistent compilation cache is on (`mjx_composer.platform.compilation_cache`),
so a rerun with the same settings loads its programs instead of compiling
them and reaches the threshold sooner: for a cold-start time to threshold,
pass `--no-compilation-cache` (or set `MJX_COMPOSER_COMPILATION_CACHE=0`).
"""

import argparse
import csv
import functools
import json
import os
import pickle
import sys
import time
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import tqdm


def _parse_sizes(text):
  return tuple(int(x) for x in text.split(',') if x)


def _script_defaults(task):
  """A task's `mjx_composer.training.config.TASK_DEFAULTS` as this script's
  flags (the same settings `mjx-composer train` uses)."""
  from mjx_composer.training import config as training_config  # pylint: disable=g-import-not-at-top

  defaults = dict(training_config.TASK_DEFAULTS[task])
  if defaults.pop('critic_obs', 'policy') == 'critic':
    defaults['obs'] = 'asymmetric'
  defaults['render_steps'] = defaults.pop('video_steps')
  return defaults


# Per-task defaults; flags given on the command line win. walk: MuJoCo
# Playground 0.2.0's PPO config for HumanoidWalk (dm_control_suite_params);
# joystick: its config for Go1JoystickFlatTerrain / RoughTerrain
# (locomotion_params), whose critic sees the privileged state. Networks are
# Brax's defaults where Playground keeps them (init_noise_std 1.0 too).
TASK_DEFAULTS = {
    task: _script_defaults(task)
    for task in ('walk', 'joystick', 'joystick_rough')
}


def parse_args(argv=None):
  from mjx_composer.suite.tasks import registry  # pylint: disable=g-import-not-at-top

  parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
  parser.add_argument('--task', default='reach', choices=registry.names())
  parser.add_argument('--num-timesteps', type=int, default=10_000_000)
  parser.add_argument('--num-envs', type=int, default=2048)
  parser.add_argument(
      '--threshold',
      type=float,
      default=20.0,
      help='evaluation return to report the time to',
  )
  parser.add_argument('--out', default='runs/ppo')
  parser.add_argument(
      '--time-limit',
      type=float,
      default=1.0,
      help='episode length in seconds (reach: 50 steps)',
  )
  parser.add_argument('--num-evals', type=int, default=11)
  parser.add_argument('--num-eval-envs', type=int, default=256)
  parser.add_argument(
      '--batch-size', type=int, default=1024, help='minibatch size'
  )
  parser.add_argument('--num-minibatches', type=int, default=32)
  parser.add_argument('--unroll-length', type=int, default=10)
  parser.add_argument('--num-updates-per-batch', type=int, default=8)
  parser.add_argument('--learning-rate', type=float, default=3e-3)
  parser.add_argument('--entropy-cost', type=float, default=0.0)
  parser.add_argument('--init-noise-std', type=float, default=0.5)
  # Off by default: on CPU tests, Brax's running normalizer made PPO's KL and
  # value loss explode on reach (observation dims that are constant early,
  # such as the resting ball's velocities, get std 1e-6).
  parser.add_argument(
      '--normalize',
      action='store_true',
      help='normalize observations (Brax running stats)',
  )
  parser.add_argument('--discounting', type=float, default=0.95)
  parser.add_argument('--reward-scaling', type=float, default=1.0)
  parser.add_argument(
      '--max-grad-norm',
      type=float,
      default=None,
      help='clip the gradient norm (default: no clipping)',
  )
  parser.add_argument(
      '--policy-layers',
      type=_parse_sizes,
      default=(64, 64),
      help='comma-separated hidden sizes',
  )
  parser.add_argument('--value-layers', type=_parse_sizes, default=(256, 256))
  parser.add_argument(
      '--obs',
      choices=('asymmetric', 'policy'),
      default='policy',
      help="'asymmetric': the critic "
      "sees the 'critic' group; 'policy': both see 'policy'",
  )
  parser.add_argument('--seed', type=int, default=0)
  parser.add_argument(
      '--devices',
      type=int,
      default=None,
      help="local devices to train on (Brax's max_devices_per_host: it "
      'pmaps over them, splitting the worlds evenly); default: all. '
      '--num-envs and --batch-size must be multiples of it',
  )
  parser.add_argument(
      '--impl',
      choices=('jax', 'warp'),
      default=None,
      help="ExecutionOptions(impl=...): MJX's JAX physics or MuJoCo Warp's; "
      "default: ExecutionOptions' (warp on a CUDA GPU where it is installed "
      'and runs the task, else jax), and jax on several --devices',
  )
  parser.add_argument(
      '--share-reset-forward',
      action=argparse.BooleanOptionalAction,
      default=None,
      help='ExecutionOptions(share_reset_forward=...): restart ended '
      'episodes inside the sub-step loop (half the step compile time, '
      'slower steps on a GPU); default: on a CPU only',
  )
  parser.add_argument(
      '--auto-reset-batch',
      type=int,
      default=None,
      metavar='K',
      help='ExecutionOptions(auto_reset_batch=K): reset the worlds whose '
      'episodes end K at a time instead of the whole batch (for tasks whose '
      "episodes end often; needs impl='jax'); default: the whole batch",
  )
  parser.add_argument(
      '--no-compilation-cache',
      action='store_true',
      help="don't read or write JAX's persistent compilation cache (for "
      'cold-start timings)',
  )
  parser.add_argument(
      '--render-worlds',
      type=int,
      default=4,
      help='worlds in the rollout images (0: none)',
  )
  parser.add_argument(
      '--render-steps',
      type=int,
      default=50,
      help='control steps rendered (walk, joystick: 200)',
  )
  parser.add_argument(
      '--metrics-worlds',
      type=int,
      default=64,
      help='worlds in rollout_metrics.json (the policy against zero '
      'actions, over --render-steps steps; 0: none)',
  )
  parser.add_argument(
      '--max-wall-s',
      type=float,
      default=None,
      help='stop after the evaluation from which the next one would end '
      'later than this many seconds after the start of ppo.train '
      '(default: train to --num-timesteps)',
  )
  parser.add_argument(
      '--like-playground',
      action='store_true',
      help="walk only: the task as Playground's HumanoidWalk (no noise, "
      'latency, history, randomization, pushes or fall terminations; '
      "the 'policy' group alone), as train_compare.py's ours_off",
  )
  parser.add_argument(
      '--render-from',
      metavar='POLICY_PKL',
      default=None,
      help='skip training: render the policy saved in this '
      'policy.pkl into --out',
  )
  task, _ = parser.parse_known_args(argv)
  parser.set_defaults(**TASK_DEFAULTS.get(task.task, {}))
  args = parser.parse_args(argv)
  if args.like_playground and args.task != 'walk':
    parser.error(f'--like-playground is for --task walk, not {args.task!r}.')
  if (args.batch_size * args.num_minibatches) % args.num_envs:
    parser.error(
        '--batch-size x --num-minibatches must be a multiple of ' '--num-envs.'
    )
  if args.devices is not None:
    if args.devices < 1:
      parser.error(f'--devices must be at least 1, got {args.devices}.')
    _check_divides(parser.error, args, args.devices)
  return args


def _check_divides(error, args, devices):
  """Brax gives each device num_envs / devices worlds and batch_size /
  devices samples of each minibatch; it fails on a bare assert or a reshape
  otherwise."""
  for flag, value in (
      ('--num-envs', args.num_envs),
      ('--batch-size', args.batch_size),
  ):
    if value % devices:
      error(
          f'{flag} {value} is not a multiple of the {devices} devices '
          'trained on: Brax splits it evenly over them. Change it, or the '
          'number of devices (--devices).'
      )


def make_networks(args):
  from brax.training.agents.ppo import networks as ppo_networks  # pylint: disable=g-import-not-at-top

  value_key = 'critic' if args.obs == 'asymmetric' else 'policy'
  return functools.partial(
      ppo_networks.make_ppo_networks,
      policy_obs_key='policy',
      value_obs_key=value_key,
      policy_hidden_layer_sizes=args.policy_layers,
      value_hidden_layer_sizes=args.value_layers,
      init_noise_std=args.init_noise_std,
  )


def load_policy(path, deterministic=True):
  """Rebuilds `policy(obs, key) -> (action, extras)` from a `policy.pkl`.

  The file is one of ours (`save_policy` with `policy_config`), or one of
  `train_compare.py`'s Playground runs: that policy is given the 'policy'
  group's vector as its observation (`--task walk --like-playground`'s is
  Playground's HumanoidWalk observation, so a policy of either environment
  runs in the other).
  """
  from brax.training.agents.ppo import networks as ppo_networks  # pylint: disable=g-import-not-at-top

  with open(path, 'rb') as f:
    saved = pickle.load(f)
  config = saved['config']
  if config.get('env') == 'playground':
    policy = playground_policy(saved, deterministic)
    return lambda obs, key: policy(obs['policy'], key)
  networks = ppo_networks.make_ppo_networks(
      {k: tuple(v) for k, v in config['observation_size'].items()},
      config['action_size'],
      preprocess_observations_fn=_preprocess(config['normalize']),
      policy_obs_key='policy',
      value_obs_key=config['value_obs_key'],
      policy_hidden_layer_sizes=tuple(config['policy_layers']),
      value_hidden_layer_sizes=tuple(config['value_layers']),
  )
  make_policy = ppo_networks.make_inference_fn(networks)
  return make_policy(saved['params'], deterministic=deterministic)


def _preprocess(normalize):
  """Brax's observation preprocessing for a saved policy's `normalize`."""
  from brax.training.acme import running_statistics  # pylint: disable=g-import-not-at-top

  if normalize:
    return running_statistics.normalize
  return lambda x, unused_params: x


def playground_policy(saved, deterministic=True):
  """`policy(vector, key)` of a Playground run's saved `{'params', 'config'}`.

  Brax's default PPO networks, as `train_compare.py` trains Playground.
  """
  from brax.training.agents.ppo import networks as ppo_networks  # pylint: disable=g-import-not-at-top

  config = saved['config']
  networks = ppo_networks.make_ppo_networks(
      config['observation_size'],
      config['action_size'],
      preprocess_observations_fn=_preprocess(config['normalize']),
  )
  make_policy = ppo_networks.make_inference_fn(networks)
  return make_policy(saved['params'], deterministic=deterministic)


def _write_plot(path, rows, threshold, title):
  try:
    import matplotlib  # pylint: disable=g-import-not-at-top

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt  # pylint: disable=g-import-not-at-top
  except ImportError:
    warnings.warn('matplotlib is not installed: no returns.png.')
    return False
  fig, ax = plt.subplots(figsize=(6, 4))
  wall = [r['wall_s'] for r in rows]
  mean = np.array([r['eval_return'] for r in rows])
  std = np.array([r['eval_return_std'] for r in rows])
  ax.plot(wall, mean, marker='o', label='evaluation return')
  ax.fill_between(wall, mean - std, mean + std, alpha=0.2)
  ax.axhline(threshold, color='k', linestyle='--', label='threshold')
  ax.set_xlabel('wall-clock time since start of ppo.train [s]')
  ax.set_ylabel('episode return')
  ax.set_title(title)
  ax.legend(loc='lower right')
  fig.tight_layout()
  fig.savefig(path, dpi=100)
  plt.close(fig)
  return True


# Cameras for the rollout images: the robots' own cameras that track their
# centre of mass (MuJoCo's 'trackcom' mode); other tasks a free camera
# (`mjx-composer train`'s videos use the same).
def _cameras():
  from mjx_composer.training import video  # pylint: disable=g-import-not-at-top

  return video.CAMERAS, video.FREE_CAMERA


_ROLLOUT_COLUMNS = 6


def rollout_metrics(brax_env, policy, worlds, steps, seed):
  """The task's metrics over a rollout of `policy`, per step and world.

  Runs `steps` control steps of `worlds` worlds from a reset seeded with
  `seed` (`policy(obs, key) -> (action, extras)`, or None for zero actions:
  a baseline that holds the actuators' zero command, e.g. the Go1's home
  pose) and averages each float entry of `State.metrics` (the task's
  `get_metrics` and the environment's) and the reward over every world and
  step. A world whose episode ends continues in its next one (same-step
  auto-reset).

  Returns:
    `{name: mean}`, with `reward` among them.
  """
  from mjx_composer.adapters import brax as brax_adapter  # pylint: disable=g-import-not-at-top

  def act(state, key):
    if policy is None:
      return jnp.zeros(state.reward.shape + (brax_env.action_size,))
    return policy(state.obs, key)[0]

  def one_step(state, key):
    state = brax_env.step(state, act(state, key))
    metrics = brax_adapter.composer_state(state).metrics
    means = {
        name: jnp.mean(value)
        for name, value in metrics.items()
        if jnp.issubdtype(value.dtype, jnp.floating)
    }
    means['reward'] = jnp.mean(state.reward)
    return state, means

  @jax.jit
  def rollout(key):
    reset_key, step_key = jax.random.split(key)
    state = brax_env.reset(jax.random.split(reset_key, worlds))
    _, means = jax.lax.scan(one_step, state, jax.random.split(step_key, steps))
    return jax.tree.map(jnp.mean, means)

  return {
      name: float(value)
      for name, value in rollout(jax.random.PRNGKey(seed)).items()
  }


def write_rollout_metrics(brax_env, policy, args, out):
  """Writes `rollout_metrics.json`: the policy's and zero actions' metrics.

  Both over `args.metrics_worlds` worlds and `args.render_steps` control
  steps from the same reset (`rollout_metrics`), so that a tracking error or
  a distance can be read against a robot that does nothing. Returns the
  payload and prints it as a table.
  """
  worlds, steps = args.metrics_worlds, args.render_steps
  payload = {
      'worlds': worlds,
      'steps': steps,
      'seed': args.seed + 1,
      'policy': rollout_metrics(brax_env, policy, worlds, steps, args.seed + 1),
      'zero_actions': rollout_metrics(
          brax_env, None, worlds, steps, args.seed + 1
      ),
  }
  with open(os.path.join(out, 'rollout_metrics.json'), 'w') as f:
    json.dump(payload, f, indent=1)
  print(f'Rollout metrics ({worlds} worlds x {steps} steps, mean per step):')
  print(f'{"metric":<24}{"policy":>12}{"zero actions":>14}')
  for name, value in payload['policy'].items():
    print(f'{name:<24}{value:>12.4g}{payload["zero_actions"][name]:>14.4g}')
  return payload


def rollout_images(env, brax_env, policy, args, out):
  """Renders `policy` on `args.render_worlds` worlds into `out`.

  Runs `args.render_steps` control steps from a reset seeded with
  `args.seed + 1` and writes `rollout.png` (one row per world, six columns
  evenly spaced in time), the same six frames as
  `rollout_frames/step_NNN.png` (a grid of the worlds each, NNN the control
  step) and `rollout.gif` (every step, at real time). The camera is
  `mjx_composer.training.video.CAMERAS[args.task]`, else a fixed free camera.

  Returns:
    The paths written.
  """
  from mjx_composer.host import rendering  # pylint: disable=g-import-not-at-top
  from mjx_composer.adapters import brax as brax_adapter  # pylint: disable=g-import-not-at-top

  n = args.render_worlds
  reset = jax.jit(brax_env.reset)
  step = jax.jit(lambda s, k: brax_env.step(s, policy(s.obs, k)[0]))
  state = reset(jax.random.split(jax.random.PRNGKey(args.seed + 1), n))
  key = jax.random.PRNGKey(args.seed + 2)
  frames = []
  cameras, free_camera = _cameras()
  camera = cameras.get(args.task, free_camera)
  for _ in range(args.render_steps):
    inner = brax_adapter.composer_state(state)
    target = (
        inner.task_state.get('target')
        if isinstance(inner.task_state, dict)
        else None
    )
    frames.append(
        rendering.render(
            env, inner, height=180, width=240, camera=camera, markers=target
        )
    )
    key, sub = jax.random.split(key)
    state = step(state, sub)
  frames = np.stack(frames)  # (T, worlds, H, W, 3)
  columns = np.linspace(0, len(frames) - 1, _ROLLOUT_COLUMNS).astype(int)
  strip = rendering.image_grid(
      frames[columns]
      .transpose(1, 0, 2, 3, 4)
      .reshape((-1,) + frames.shape[2:]),
      columns=len(columns),
  )
  paths = [os.path.join(out, 'rollout.png')]
  rendering.save_image(paths[0], strip)
  grid_columns = int(np.ceil(np.sqrt(n)))
  frame_dir = os.path.join(out, 'rollout_frames')
  os.makedirs(frame_dir, exist_ok=True)
  for column in columns:
    paths.append(os.path.join(frame_dir, f'step_{column:03d}.png'))
    rendering.save_image(
        paths[-1], rendering.image_grid(frames[column], columns=grid_columns)
    )
  paths.append(os.path.join(out, 'rollout.gif'))
  rendering.save_gif(
      paths[-1],
      [rendering.image_grid(f, columns=grid_columns) for f in frames],
      fps=1.0 / env.control_timestep(),
  )
  return paths


# -- pieces shared with train_compare.py -------------------------------------


def make_brax_env(args):
  """`(env, brax_env)`: the task's `Environment` and its `BraxEnv`.

  Built with `args.task`, `args.time_limit`, `args.share_reset_forward`,
  `args.impl` and `args.auto_reset_batch` (when given), same-step
  auto-reset, and the task's observation groups (Brax sees the dict of
  groups; `make_networks` picks from it). With `args.like_playground`, the
  walk task as Playground's HumanoidWalk (`make_walk_like_playground` of
  `benchmarks/common.py`, so this needs a checkout of the repository).
  """
  # pylint: disable=g-import-not-at-top
  import mjx_composer as composer
  from mjx_composer.adapters import brax as brax_adapter
  from mjx_composer.suite.tasks import registry

  # pylint: enable=g-import-not-at-top

  if getattr(args, 'like_playground', False):
    # The benchmarks' definition, so that training and the throughput
    # comparison use the same environment (benchmarks/common.py).
    sys.path.insert(
        0,
        os.path.join(
            os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
            'benchmarks',
        ),
    )
    import common  # pylint: disable=g-import-not-at-top

    env = common.make_walk_like_playground(
        args.time_limit,
        share_reset_forward=args.share_reset_forward,
        impl=getattr(args, 'impl', None),
        auto_reset_batch=getattr(args, 'auto_reset_batch', None),
    )
    return env, brax_adapter.BraxEnv(env)
  env = registry.make_environment(
      args.task,
      time_limit=args.time_limit,
      options=composer.ExecutionOptions(
          auto_reset='same_step',
          share_reset_forward=args.share_reset_forward,
          impl=getattr(args, 'impl', None),
          auto_reset_batch=getattr(args, 'auto_reset_batch', None),
      ),
  )
  return env, brax_adapter.BraxEnv(env)


def ppo_kwargs(args, brax_env, devices):
  """The `ppo.train` arguments this script trains with, but the callbacks.

  Everything from `args` (sizes, PPO coefficients, networks, seed) plus the
  adapter's `training_kwargs`, deterministic evaluation and
  `max_devices_per_host=devices`; `progress_fn` and `policy_params_fn` are
  the caller's.
  """
  from mjx_composer.adapters import brax as brax_adapter  # pylint: disable=g-import-not-at-top

  return dict(
      num_timesteps=args.num_timesteps,
      num_envs=args.num_envs,
      batch_size=args.batch_size,
      num_minibatches=args.num_minibatches,
      unroll_length=args.unroll_length,
      num_updates_per_batch=args.num_updates_per_batch,
      learning_rate=args.learning_rate,
      entropy_cost=args.entropy_cost,
      discounting=args.discounting,
      reward_scaling=args.reward_scaling,
      max_grad_norm=args.max_grad_norm,
      normalize_observations=args.normalize,
      num_evals=args.num_evals,
      num_eval_envs=args.num_eval_envs,
      deterministic_eval=True,
      seed=args.seed,
      max_devices_per_host=devices,
      network_factory=make_networks(args),
      **brax_adapter.training_kwargs(brax_env),
  )


class CompileClock:
  """Seconds this process has spent lowering and compiling since creation.

  Sums JAX's lowering and XLA compile events (`jax.monitoring`); tracing is
  left out because nested traces report inside their callers' (it would
  count twice), so the figure is a lower bound. One listener per process
  feeds every clock.
  """

  _EVENTS = (
      '/jax/core/compile/jaxpr_to_mlir_module_duration',
      '/jax/core/compile/backend_compile_duration',
  )
  _total = 0.0  # seconds since the listener was registered
  _listening = False

  def __init__(self):
    if not CompileClock._listening:
      jax.monitoring.register_event_duration_secs_listener(CompileClock._record)
      CompileClock._listening = True
    self._start = CompileClock._total

  @staticmethod
  def _record(event, duration, **kwargs):
    del kwargs
    if event in CompileClock._EVENTS:
      CompileClock._total += duration

  @property
  def seconds(self) -> float:
    return CompileClock._total - self._start


def eval_row(step, metrics, wall_s, compile_s=0.0, previous=None):
  """One evaluation's record from Brax's `progress_fn(step, metrics)`.

  Keys: step (env steps so far), wall_s (the caller's clock: seconds since
  the start of `ppo.train`), compile_s (seconds of that spent lowering and
  compiling, a `CompileClock`'s), train_walltime_s (Brax's training time,
  without evaluating or the resets between epochs; its first update
  includes compiling), env_steps_per_s (the env steps since `previous`, the
  row before, over the training time since then: the training throughput;
  0 for the first row, and without `previous`), train_sps (Brax's
  'training/sps', which is NOT that: Brax times one training epoch but
  counts `num_resets_per_eval` epochs' steps in it, so it overstates the
  rate by that factor, 2 or 10 with Playground's settings), eval_walltime_s
  (Brax's total time spent evaluating so far, this evaluation included),
  eval_return and eval_return_std (over the evaluation episodes),
  eval_episode_length.
  """
  train_walltime = float(metrics.get('training/walltime', 0.0))
  rate = 0.0
  if previous is not None:
    seconds = train_walltime - previous['train_walltime_s']
    if seconds > 0:
      rate = (int(step) - previous['step']) / seconds
  return {
      'step': int(step),
      'wall_s': float(wall_s),
      'compile_s': float(compile_s),
      'train_walltime_s': train_walltime,
      'env_steps_per_s': rate,
      'train_sps': float(metrics.get('training/sps', 0.0)),
      'eval_walltime_s': float(metrics.get('eval/walltime', 0.0)),
      'eval_return': float(metrics['eval/episode_reward']),
      'eval_return_std': float(metrics['eval/episode_reward_std']),
      'eval_episode_length': float(metrics['eval/avg_episode_length']),
  }


def append_csv(path, row, header):
  """Appends `row` (a dict) to the CSV at `path`, writing `header` first."""
  with open(path, 'a', newline='') as f:
    writer = csv.DictWriter(f, fieldnames=list(row))
    if header:
      writer.writeheader()
    writer.writerow(row)


class StopTraining(Exception):
  """Raised by a `progress_fn` to end `ppo.train` after an evaluation."""


def next_eval_too_late(rows, max_wall_s, planned_steps=None):
  """Whether the evaluation after `rows[-1]` would end after `max_wall_s`.

  The next evaluation is expected as long after the last as the last was
  after the one before it (after the start, for the first), less the time
  that interval spent compiling (`compile_s`): the first training update
  compiles the training program, and the updates after it do not. (A
  program that compiles again later, like Brax's evaluator on Playground's
  environments, makes the estimate short by that compile.) False when
  `max_wall_s` is None, and after the last evaluation (`rows[-1]`'s step
  reaches `planned_steps`, where given): a run that has trained all its
  steps is finished, not stopped.
  """
  if max_wall_s is None or not rows:
    return False
  if planned_steps is not None and rows[-1]['step'] >= planned_steps:
    return False
  last = rows[-1]
  before = rows[-2] if len(rows) > 1 else {'wall_s': 0.0, 'compile_s': 0.0}
  interval = (last['wall_s'] - before['wall_s']) - (
      last.get('compile_s', 0.0) - before.get('compile_s', 0.0)
  )
  return last['wall_s'] + max(interval, 0.0) > max_wall_s


def policy_config(args, brax_env):
  """What `load_policy` needs to rebuild the networks, as plain data."""
  return {
      'task': args.task,
      'observation_size': brax_env.observation_size,
      'action_size': brax_env.action_size,
      'value_obs_key': 'critic' if args.obs == 'asymmetric' else 'policy',
      'normalize': args.normalize,
      'policy_layers': list(args.policy_layers),
      'value_layers': list(args.value_layers),
  }


def save_policy(path, params, config):
  """Writes `{'params': params (numpy leaves), 'config': config}`."""
  with open(path, 'wb') as f:
    pickle.dump({'params': jax.device_get(params), 'config': config}, f)


def impl_for_devices(impl, devices, fail):
  """`--impl` for training on `devices` local devices.

  MuJoCo Warp's contact buffer is shared by the whole batch, and Brax's pmap
  would split it (`sharding.check_impl`): on several devices the default is
  'jax', and an explicit 'warp' is refused through `fail(message)`.
  """
  if devices == 1:
    return impl
  if impl == 'warp':
    return fail(
        f'--impl warp trains on one device; pass --devices 1, or --impl jax '
        f'to train on {devices}.'
    )
  return 'jax'


def main(argv=None):
  args = parse_args(argv)
  # pylint: disable=g-import-not-at-top
  from brax.training.agents.ppo import train as ppo
  from mjx_composer.platform import partitioner
  from mjx_composer import platform
  # pylint: enable=g-import-not-at-top
  cache_dir = platform.configure(
      compilation_cache=False if args.no_compilation_cache else None
  )
  os.makedirs(args.out, exist_ok=True)
  device = jax.devices()[0]
  local_devices = jax.local_device_count()
  devices = args.devices or local_devices
  if devices > local_devices:
    sys.exit(
        f'--devices {devices}: this process has {local_devices} local '
        'devices.'
    )
  _check_divides(sys.exit, args, devices)
  args.impl = impl_for_devices(args.impl, devices, sys.exit)
  print(
      f'JAX {jax.__version__} on {device.platform}: {device.device_kind} x '
      f'{devices} (of {local_devices}); compilation cache: '
      f'{cache_dir or "off"}'
  )

  env, brax_env = make_brax_env(args)
  print(
      f'Task {args.task!r} (physics on impl={env.impl!r}): episodes of '
      f'{brax_env.episode_length} steps; '
      f'observations {brax_env.observation_size}, '
      f'{brax_env.action_size} actions.'
  )

  if args.render_from:
    policy = load_policy(args.render_from)
    if args.metrics_worlds > 0:
      write_rollout_metrics(brax_env, policy, args, args.out)
    if args.render_worlds > 0:
      rollout_images(env, brax_env, policy, args, args.out)
      print(
          f'Rendered {args.render_worlds} worlds of {args.render_from} into '
          f'{args.out}.'
      )
    return 0

  rows = []
  # The bar redraws in place on a terminal; in a log (a CI job, a remote
  # run) it would bury the evaluation lines, so it is left out there.
  bar = tqdm.tqdm(
      total=args.num_timesteps,
      unit='step',
      unit_scale=True,
      desc='training (first update compiles)',
      file=sys.stdout,
      disable=not sys.stdout.isatty(),
  )
  start = None
  hit = None
  # The policy of the latest evaluation, for a run stopped by --max-wall-s.
  latest = {}
  # Each evaluation is appended as it comes, so an interrupted run keeps
  # its returns.
  log_path = os.path.join(args.out, 'returns.csv')
  if os.path.exists(log_path):
    os.remove(log_path)

  def keep_params(unused_step, make_policy, params):
    latest.update(make_policy=make_policy, params=params)

  def progress(step, metrics):
    nonlocal hit
    row = eval_row(
        step,
        metrics,
        time.perf_counter() - start,
        clock.seconds,
        previous=rows[-1] if rows else None,
    )
    rows.append(row)
    append_csv(log_path, row, header=len(rows) == 1)
    if hit is None and row['eval_return'] >= args.threshold:
      hit = row
    bar.set_description(f'return {row["eval_return"]:.1f}')
    bar.update(min(int(step), args.num_timesteps) - bar.n)
    tqdm.tqdm.write(
        f'step {step:>12,}  {row["wall_s"]:8.1f}s  return '
        f'{row["eval_return"]:8.2f} ± {row["eval_return_std"]:.2f}'
        f'  ({row["env_steps_per_s"]:,.0f} env steps/s)',
        file=sys.stdout,
    )
    if (
        next_eval_too_late(rows, args.max_wall_s, args.num_timesteps)
        and 'params' in latest
    ):
      raise StopTraining

  start = time.perf_counter()
  clock = CompileClock()
  stopped_early = False
  try:
    # Brax pmaps over `devices` local devices; on several GPUs that compiles
    # with GSPMD (Shardy crashed compiling MJX's step under pmap there).
    with partitioner.scope(jax.local_devices()[:devices]):
      make_policy, params, _ = ppo.train(
          environment=brax_env,
          progress_fn=progress,
          policy_params_fn=keep_params,
          **ppo_kwargs(args, brax_env, devices),
      )
  except StopTraining:
    stopped_early = True
    make_policy, params = latest['make_policy'], latest['params']
  total = time.perf_counter() - start
  bar.close()
  if stopped_early:
    print(
        f'Stopped after {total:.1f}s (--max-wall-s {args.max_wall_s:g}), '
        f'at step {rows[-1]["step"]:,}.'
    )

  # Returns log and plot.
  with open(os.path.join(args.out, 'returns.json'), 'w') as f:
    json.dump(rows, f, indent=1)
  _write_plot(
      os.path.join(args.out, 'returns.png'),
      rows,
      args.threshold,
      f'PPO on {args.task} ({args.num_envs} worlds, ' f'{device.platform})',
  )

  # The policy, with what it takes to rebuild it.
  save_policy(
      os.path.join(args.out, 'policy.pkl'),
      params,
      policy_config(args, brax_env),
  )

  if args.metrics_worlds > 0:
    write_rollout_metrics(
        brax_env, make_policy(params, deterministic=True), args, args.out
    )
  rendered = False
  if args.render_worlds > 0:
    try:
      rollout_images(
          env, brax_env, make_policy(params, deterministic=True), args, args.out
      )
      rendered = True
    except (RuntimeError, ImportError) as e:
      warnings.warn(f'No rollout images: {e}')

  summary = {
      'task': args.task,
      'device': f'{device.platform}: {device.device_kind}',
      'devices': devices,
      'impl': env.impl,
      'jax': jax.__version__,
      'num_envs': args.num_envs,
      'num_timesteps': args.num_timesteps,
      'threshold': args.threshold,
      'time_to_threshold_s': hit['wall_s'] if hit else None,
      'steps_to_threshold': hit['step'] if hit else None,
      'final_return': rows[-1]['eval_return'],
      'best_return': max(r['eval_return'] for r in rows),
      'initial_return': rows[0]['eval_return'],
      'total_s': total,
      'stopped_early': stopped_early,
      'episode_length': brax_env.episode_length,
      'rendered': rendered,
      'compilation_cache': cache_dir,
      'args': {k: v for k, v in vars(args).items()},
  }
  with open(os.path.join(args.out, 'summary.json'), 'w') as f:
    json.dump(summary, f, indent=1, default=str)

  print(f'\n{"task":<22}{args.task}\n{"device":<22}{summary["device"]}')
  print(f'{"devices":<22}{devices}')
  print(f'{"worlds x steps":<22}{args.num_envs} x {args.num_timesteps:,}')
  print(
      f'{"return: first/final":<22}{rows[0]["eval_return"]:.2f} / '
      f'{rows[-1]["eval_return"]:.2f} (max '
      f'{brax_env.episode_length} per episode)'
  )
  if hit:
    print(
        f'{"time to threshold":<22}{hit["wall_s"]:.1f}s at step '
        f'{hit["step"]:,} (return >= {args.threshold:g})'
    )
  else:
    print(
        f'{"time to threshold":<22}not reached (return >= '
        f'{args.threshold:g})'
    )
  print(f'{"total wall-clock":<22}{total:.1f}s; outputs in {args.out}')
  return 0


if __name__ == '__main__':
  sys.exit(main())
