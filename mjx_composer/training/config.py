"""The training configuration: one dataclass, per-task defaults, files, flags.

`TrainConfig` holds every setting of a training run (Brax PPO's
hyper-parameters, the networks, the environment, logging). A run's config is
resolved in layers, each overriding the one before:

1. the dataclass defaults (small settings that train the reach task);
2. the task's defaults, registered with it (`registry.register(...,
   training=...)`, read by `defaults`): walk and joystick use MuJoCo
   Playground's PPO settings for HumanoidWalk (`dm_control_suite_params`)
   and Go1JoystickFlatTerrain / RoughTerrain (`locomotion_params`);
3. a config file (`--config FILE`: JSON or YAML, a mapping of field names to
   values);
4. command-line flags (`--learning-rate 1e-3`, `--policy-layers 64 64`,
   `--normalize/--no-normalize`), parsed by tyro from the dataclass, its
   types and its field docs.

The resolved config is written to the run folder as JSON (`to_dict`), and
`from_dict` reads it back with the same checks as a config file.
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

  task: str = 'reach'
  """Registered task name (`mjx-composer list`)."""
  imports: tuple[str, ...] = ()
  """Modules imported before the task is built, which register it (given
  as --import MODULE; recorded, so play, export and --resume import them)."""
  num_timesteps: int = 10_000_000
  """Environment steps to train for (all worlds together)."""
  num_envs: int = 2048
  """Worlds stepped in parallel."""
  num_evals: int = 11
  """Evaluations, the one before training included (Brax's num_evals)."""
  num_eval_envs: int = 256
  """Worlds (one episode each) per evaluation."""
  batch_size: int = 1024
  """Minibatch size."""
  num_minibatches: int = 32
  """Minibatches per update."""
  unroll_length: int = 10
  """Control steps per rollout segment."""
  num_updates_per_batch: int = 8
  """Passes over each batch."""
  learning_rate: float = 3e-3
  """Adam's learning rate."""
  entropy_cost: float = 0.0
  """Entropy bonus coefficient."""
  discounting: float = 0.95
  """Discount factor."""
  reward_scaling: float = 1.0
  """Factor on rewards before the loss."""
  max_grad_norm: Optional[float] = None
  """Clip the gradient's global norm to this (None: no clipping)."""
  normalize: bool = False
  """Normalize observations with Brax's running statistics."""
  init_noise_std: float = 0.5
  """The policy's initial action noise."""
  policy_layers: tuple[int, ...] = (64, 64)
  """The policy network's hidden layer sizes."""
  value_layers: tuple[int, ...] = (256, 256)
  """The value network's hidden layer sizes."""
  critic_obs: Literal['policy', 'critic'] = 'policy'
  """Observation group the critic sees ('critic': asymmetric actor-critic)."""
  time_limit: float = 1.0
  """Episode length in seconds."""
  seed: int = 0
  """Random seed of the run."""
  devices: Optional[int] = None
  """Local devices to train on (Brax pmaps over them); None: all."""
  impl: Optional[Literal['jax', 'warp']] = None
  """Physics implementation (None: the Environment's default)."""
  video_every: int = 0
  """Write an evaluation video every N evaluations (0: none)."""
  video_worlds: int = 4
  """Worlds tiled in each video."""
  video_steps: int = 50
  """Control steps in each video."""
  video_size: tuple[int, int] = (120, 160)
  """(height, width) of each world's frame in a video."""
  tensorboard: bool = True
  """Write TensorBoard event files (needs tensorboardX)."""
  wandb: bool = False
  """Log to Weights & Biases too (needs wandb, and a login)."""
  compilation_cache: bool = True
  """Use JAX's persistent compilation cache."""
  target_return: Optional[float] = None
  """Report the time to the first evaluation whose return reaches this."""

  def replace(self, **changes) -> TrainConfig:
    """A copy with `changes` (checked as a config file's entries)."""
    return from_dict({**to_dict(self), **changes})


def field_names() -> tuple[str, ...]:
  """`TrainConfig`'s field names, in declaration order."""
  return tuple(f.name for f in dataclasses.fields(TrainConfig))


def defaults(task: str) -> TrainConfig:
  """The config of `task` before any file or flag: its registered defaults.

  `TrainConfig`'s defaults overridden by the task's registry entry's
  `training` (`registry.register(..., training=...)`).

  Raises:
    UnknownTaskError: for a task that is not registered.
    ValueError: for training defaults that are not `TrainConfig` fields or
      values of the wrong kind, naming the task and the setting.
  """
  training = registry.entry(task).training
  where = f'The training defaults of task {task!r} (registry.register)'
  if 'task' in training or 'imports' in training:
    raise ValueError(
        f'{where}: leave out task and imports, which the run sets; got '
        f'{sorted(set(training) & {"task", "imports"})}.'
    )
  try:
    return from_dict({**training, 'task': task}, where=where)
  except ValueError as e:
    message = str(e)
    raise ValueError(
        message if message.startswith(where) else f'{where}: {message}'
    ) from e


def _check_keys(values: Mapping[str, Any], where: str) -> None:
  unknown = sorted(set(values) - set(field_names()))
  if unknown:
    raise ValueError(
        f'{where}: unknown setting(s) {unknown}; the settings are '
        f'{", ".join(field_names())}.'
    )


def _convert(name: str, value, default):
  """`value` as the type of field `name` (lists to tuples, ints to floats)."""
  if isinstance(value, list):
    value = tuple(value)
  if value is None:
    return value
  if isinstance(default, bool) or name in ('normalize',):
    if not isinstance(value, bool):
      raise ValueError(f'{name} must be true or false, got {value!r}.')
    return value
  if isinstance(default, float) and isinstance(value, int):
    return float(value)
  if name == 'imports':
    if not isinstance(value, tuple) or not all(
        isinstance(v, str) and v for v in value
    ):
      raise ValueError(f'{name} must be a list of module names, got {value!r}.')
  elif isinstance(default, tuple):
    if not isinstance(value, tuple) or not all(
        isinstance(v, int) and not isinstance(v, bool) for v in value
    ):
      raise ValueError(f'{name} must be a list of integers, got {value!r}.')
  return value


def from_dict(values: Mapping[str, Any], where: str = 'config') -> TrainConfig:
  """A `TrainConfig` from a mapping of (some of) its fields.

  Args:
    values: field names to values; missing fields take the defaults.
    where: what the values came from, for error messages.

  Raises:
    ValueError: for an unknown field, or a value of the wrong kind.
  """
  if not isinstance(values, Mapping):
    raise ValueError(
        f'{where}: expected a mapping of setting names to values, got '
        f'{type(values).__name__}.'
    )
  _check_keys(values, where)
  base = TrainConfig()
  converted = {
      name: _convert(name, value, getattr(base, name))
      for name, value in values.items()
  }
  config = dataclasses.replace(base, **converted)
  check(config)
  return config


def to_dict(config: TrainConfig) -> dict[str, Any]:
  """The config as JSON-ready data (tuples as lists)."""
  return {
      k: list(v) if isinstance(v, tuple) else v
      for k, v in dataclasses.asdict(config).items()
  }


def check(config: TrainConfig) -> None:
  """Raises ValueError naming the setting for settings Brax would fail on."""
  positive = (
      'num_timesteps',
      'num_envs',
      'num_evals',
      'num_eval_envs',
      'batch_size',
      'num_minibatches',
      'unroll_length',
      'num_updates_per_batch',
      'video_worlds',
      'video_steps',
  )
  for name in positive:
    value = getattr(config, name)
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
      raise ValueError(f'{name} must be a positive integer, got {value!r}.')
  if config.video_every < 0:
    raise ValueError(
        f'video_every must be >= 0 (0: no videos), got {config.video_every}.'
    )
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
        f"critic_obs must be 'policy' or 'critic', got {config.critic_obs!r}."
    )


def check_devices(config: TrainConfig, devices: int) -> None:
  """Raises ValueError unless Brax can split the batch over `devices`."""
  for name in ('num_envs', 'batch_size'):
    value = getattr(config, name)
    if value % devices:
      raise ValueError(
          f'{name} {value} is not a multiple of the {devices} devices '
          'trained on: Brax splits it evenly over them. Change it, or the '
          'number of devices (--devices).'
      )


def load_file(path: str) -> dict[str, Any]:
  """The settings in a JSON (.json) or YAML (.yaml, .yml) config file.

  Raises:
    ValueError: for a missing or unreadable file, or an unknown extension.
  """
  if not os.path.isfile(path):
    raise ValueError(f'Config file {path!r} does not exist.')
  ext = os.path.splitext(path)[1].lower()
  with open(path) as f:
    text = f.read()
  try:
    if ext == '.json':
      values = json.loads(text)
    elif ext in ('.yaml', '.yml'):
      import yaml  # pylint: disable=g-import-not-at-top

      values = yaml.safe_load(text)
    else:
      raise ValueError(
          f'Config file {path!r}: use a .json, .yaml or .yml file.'
      )
  except (json.JSONDecodeError, ImportError) as e:
    raise ValueError(f'Config file {path!r} could not be read: {e}') from e
  except Exception as e:  # yaml.YAMLError, without importing yaml here
    if type(e).__module__.startswith('yaml'):
      raise ValueError(f'Config file {path!r} could not be read: {e}') from e
    raise
  _check_keys(values or {}, f'Config file {path!r}')
  return dict(values or {})


def parse_flags(
    argv: list[str], default: TrainConfig, prog: str = 'mjx-composer train'
) -> TrainConfig:
  """`default` overridden by command-line flags (tyro, from the dataclass)."""
  import tyro  # pylint: disable=g-import-not-at-top

  config = tyro.cli(
      TrainConfig,
      default=default,
      args=argv,
      prog=prog,
      description=(
          'Train a registered task with Brax PPO. Usage: mjx-composer train '
          'TASK [--import MODULE ...] [--config FILE] [--run-dir DIR | '
          '--resume RUN] [settings]; '
          "settings' defaults below are TASK's."
      ),
  )
  check(config)
  return config
