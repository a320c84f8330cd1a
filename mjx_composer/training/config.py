"""The training configuration: one dataclass, per-task defaults, files, flags.

`TrainConfig`'s defaults, overridden by the task's (`defaults`), a JSON or
YAML file (`load_file`), then flags (tyro, from the field comments:
`parse_flags`); written to the run folder as JSON (`to_dict`, `from_dict`).
`ppo_kwargs` gives Brax's `ppo.train` hyper-parameters of a config.
"""

from __future__ import annotations

import dataclasses
import json
import os
from typing import Any, Literal, Mapping, Optional

from mjx_composer.suite.tasks import registry


@dataclasses.dataclass(frozen=True)
class TrainConfig:
  """A training run's settings (Brax PPO on a registered task)."""

  task: str = 'reach'  # Registered task name (`mjx-composer list`).
  imports: tuple[str, ...] = ()  # Modules registering the task (--import).
  num_timesteps: int = 10_000_000  # Env steps to train for (all worlds).
  num_envs: int = 2048  # Worlds stepped in parallel.
  num_evals: int = 11  # Evaluations, the one before training included.
  num_eval_envs: int = 256  # Worlds (one episode each) per evaluation.
  batch_size: int = 1024  # Minibatch size.
  num_minibatches: int = 32  # Minibatches per update.
  unroll_length: int = 10  # Control steps per rollout segment.
  num_updates_per_batch: int = 8  # Passes over each batch.
  learning_rate: float = 3e-3  # Adam's learning rate.
  entropy_cost: float = 0.0  # Entropy bonus coefficient.
  discounting: float = 0.95  # Discount factor.
  reward_scaling: float = 1.0  # Factor on rewards before the loss.
  max_grad_norm: Optional[float] = None  # Gradient norm clip (None: none).
  normalize: bool = False  # Normalize observations (Brax's running stats).
  init_noise_std: float = 0.5  # The policy's initial action noise.
  policy_layers: tuple[int, ...] = (64, 64)  # Policy's hidden layer sizes.
  value_layers: tuple[int, ...] = (256, 256)  # Value's hidden layer sizes.
  critic_obs: Literal['policy', 'critic'] = 'policy'  # The critic's group.
  time_limit: float = 1.0  # Episode length in seconds.
  seed: int = 0  # Random seed of the run.
  devices: Optional[int] = None  # Local devices trained on (None: all).
  impl: Optional[Literal['jax', 'warp']] = None  # Physics (None: default).
  video_every: int = 0  # An evaluation video every N evaluations (0: none).
  video_worlds: int = 4  # Worlds tiled in each video.
  video_steps: int = 50  # Control steps in each video.
  video_size: tuple[int, int] = (120, 160)  # Each world's (height, width).
  tensorboard: bool = True  # Write TensorBoard event files.
  wandb: bool = False  # Log to Weights & Biases too (needs wandb, a login).
  compilation_cache: bool = True  # Use JAX's persistent compilation cache.
  target_return: Optional[float] = None  # Report when a return reaches it.

  def replace(self, **changes) -> TrainConfig:
    """A copy with `changes` (checked as a config file's entries)."""
    return from_dict({**to_dict(self), **changes})


# What a resumed run may change; the rest would change what it trains.
RESUMABLE = frozenset(
    'num_timesteps devices video_every video_worlds video_steps video_size '
    'tensorboard wandb compilation_cache target_return'.split()
)
# `TrainConfig`'s fields that are `ppo.train` arguments, and their names there.
PPO_ARGUMENTS = {
    name: name
    for name in (
        'num_timesteps num_evals num_envs num_eval_envs batch_size seed '
        'num_minibatches unroll_length num_updates_per_batch learning_rate '
        'entropy_cost discounting reward_scaling max_grad_norm'
    ).split()
} | {'normalize': 'normalize_observations'}


def ppo_kwargs(config: TrainConfig) -> dict[str, Any]:
  """`ppo.train`'s hyper-parameter keyword arguments (not the environment,
  networks, callbacks or devices): `PPO_ARGUMENTS` of `config`."""
  return {ppo: getattr(config, f) for f, ppo in PPO_ARGUMENTS.items()}


def defaults(task: str) -> TrainConfig:
  """`TrainConfig`'s defaults overridden by the task's registered ones."""
  training = registry.entry(task).training
  where = f'The training defaults of task {task!r} (registry.register)'
  try:
    if {'task', 'imports'} & set(training):
      raise ValueError(
          'leave out task and imports, which the run sets; got '
          f'{sorted(set(training) & {"task", "imports"})}.'
      )
    return from_dict({**training, 'task': task}, where=where)
  except ValueError as e:
    message = str(e)
    raise ValueError(
        message if message.startswith(where) else f'{where}: {message}'
    ) from e


def _check_keys(values: Mapping[str, Any], where: str) -> None:
  names = [f.name for f in dataclasses.fields(TrainConfig)]
  unknown = sorted(set(values) - set(names))
  if unknown:
    raise ValueError(
        f'{where}: unknown setting(s) {unknown}; the settings are '
        f'{", ".join(names)}.'
    )


def _convert(name: str, value, default):
  """`value` as the type of field `name` (lists to tuples, ints to floats)."""
  value = tuple(value) if isinstance(value, list) else value
  if value is None:
    return value
  if isinstance(default, bool) and not isinstance(value, bool):
    raise ValueError(f'{name} must be true or false, got {value!r}.')
  if isinstance(default, float) and type(value) is int:
    return float(value)
  kind = str if name == 'imports' else int
  if isinstance(default, tuple) and (
      not isinstance(value, tuple)
      or not all(type(v) is kind and v != '' for v in value)
  ):
    what = 'module names' if kind is str else 'integers'
    raise ValueError(f'{name} must be a list of {what}, got {value!r}.')
  return value


def from_dict(values: Mapping[str, Any], where: str = 'config') -> TrainConfig:
  """A checked `TrainConfig` of (some of) its fields from `where`."""
  if not isinstance(values, Mapping):
    raise ValueError(f'{where}: expected a mapping of settings to values.')
  _check_keys(values, where)
  base = TrainConfig()
  config = dataclasses.replace(
      base, **{k: _convert(k, v, getattr(base, k)) for k, v in values.items()}
  )
  check(config)
  return config


def to_dict(config: TrainConfig) -> dict[str, Any]:
  """The config as JSON-ready data (tuples as lists)."""
  return json.loads(json.dumps(dataclasses.asdict(config)))


def check(config: TrainConfig) -> None:
  """Raises ValueError naming the setting for settings Brax would fail on."""
  for name in (
      'num_timesteps num_envs num_evals num_eval_envs batch_size '
      'num_minibatches unroll_length num_updates_per_batch video_worlds '
      'video_steps'
  ).split():
    value = getattr(config, name)
    if type(value) is not int or value < 1:
      raise ValueError(f'{name} must be a positive integer, got {value!r}.')
  if config.video_every < 0:
    raise ValueError(f'video_every must be >= 0, got {config.video_every}.')
  if (config.batch_size * config.num_minibatches) % config.num_envs:
    raise ValueError(
        f'batch_size x num_minibatches ({config.batch_size} x '
        f'{config.num_minibatches}) must be a multiple of num_envs '
        f'({config.num_envs}): Brax splits each rollout into minibatches.'
    )
  if config.devices is not None and config.devices < 1:
    raise ValueError(f'devices must be at least 1, got {config.devices}.')
  if config.critic_obs not in ('policy', 'critic'):
    raise ValueError(
        f'critic_obs: policy or critic, not {config.critic_obs!r}.'
    )


def load_file(path: str) -> dict[str, Any]:
  """The settings of a JSON or YAML config file (else ValueError)."""
  ext = os.path.splitext(path)[1].lower()
  if ext not in ('.json', '.yaml', '.yml'):
    raise ValueError(f'Config file {path!r}: use a .json, .yaml or .yml file.')
  try:
    with open(path) as f:
      if ext == '.json':
        values = json.load(f)
      else:
        import yaml  # pylint: disable=g-import-not-at-top

        values = yaml.safe_load(f)
  except Exception as e:  # missing, unreadable, bad JSON or YAML, no yaml
    raise ValueError(f'Config file {path!r} could not be read: {e}') from e
  _check_keys(values or {}, f'Config file {path!r}')
  return dict(values or {})


def parse_flags(argv: list[str], default: TrainConfig) -> TrainConfig:
  """`default` overridden by command-line flags (tyro, from the dataclass)."""
  import tyro  # pylint: disable=g-import-not-at-top

  config = tyro.cli(
      TrainConfig,
      default=default,
      args=argv,
      prog='mjx-composer train',
      description=(
          'Train a registered task with Brax PPO. Usage: mjx-composer train '
          'TASK [--import MODULE ...] [--config FILE] [--run-dir DIR | '
          '--resume RUN] [settings]. On several hosts, each runs it with '
          '--distributed (jax.distributed.initialize; under SLURM or Open '
          'MPI JAX finds the rest), elsewhere with --coordinator HOST:PORT '
          "--num-processes N --process-id I. The settings' defaults below "
          "are TASK's."
      ),
  )
  check(config)
  return config
