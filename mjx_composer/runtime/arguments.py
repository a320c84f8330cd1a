"""`Environment`'s arguments: their checks, composer's options, old spellings.

`Environment` takes composer's arguments plus `options` (`ExecutionOptions`).
This module checks the composer arguments, refuses composer's options that a
batched, jitted environment cannot honour (saying what happens instead),
turns the keyword arguments that `ExecutionOptions` replaced into options
with a `DeprecationWarning` that names the new spelling, and checks what
`reset` and `step` are called with at trace time.
"""

import dataclasses
import warnings

import jax
import jax.numpy as jnp

from mjx_composer.observation import updater as updater_lib
from mjx_composer.runtime import options as options_lib

ExecutionOptions = options_lib.ExecutionOptions
ObservationPadding = updater_lib.ObservationPadding

# The `ExecutionOptions` fields, once `Environment` keyword arguments.
OPTION_FIELDS = tuple(f.name for f in dataclasses.fields(ExecutionOptions))


COMPOSER_OPTIONS = {
    'raise_exception_on_physics_error': (
        'nothing can raise inside a jitted step: a world whose physics '
        'diverges ends its episode (LAST, discount 0) with '
        "metrics['diverged'] = 1 and is reset, and the other worlds are "
        "untouched. Read metrics['diverged'] instead."
    ),
    'recompile_mjcf_every_episode': (
        'the model is compiled once, when the Environment is built: '
        'initialize_episode_mjcf and after_compile run once, on the host '
        '(an MJCFVariator they apply with apply_variations(random_state) '
        'is applied every episode). Other per-episode changes belong in '
        'initialize_episode (variations write per-world model fields).'
    ),
    'legacy_step': (
        "a control step's hooks, observations and reward see what "
        "composer's legacy step leaves (positions, velocities and their "
        'sensors of the new state, recomputed where read), while sub-step '
        "hooks and observables sampled between sub-steps see mj_step's "
        'data (derived quantities one physics step behind the state): '
        'neither setting describes it whole.'
    ),
}


def check_composer_options(**options):
  """composer's boolean options: True, False or None; True only if we can."""
  for name, value in options.items():
    if not (value is None or isinstance(value, bool)):
      raise ValueError(f'{name} must be True, False or None, got {value!r}.')
    if value and name in COMPOSER_OPTIONS:
      raise ValueError(
          f'Environment({name}=True) is not available: '
          f'{COMPOSER_OPTIONS[name]} Pass {name}=False or leave it out.'
      )


def check_arguments(padding, max_reset_attempts, time_limit):
  if not isinstance(padding, ObservationPadding):
    raise ValueError(
        'delayed_observation_padding must be an '
        f'ObservationPadding, got {padding!r}.'
    )
  if int(max_reset_attempts) != max_reset_attempts or max_reset_attempts < 1:
    raise ValueError(
        'max_reset_attempts must be a positive integer, got '
        f'{max_reset_attempts!r}.'
    )
  if time_limit <= 0:
    raise ValueError(f'time_limit must be positive, got {time_limit}.')


def options_from(options, deprecated, arguments):
  """`(ExecutionOptions, observation_groups)` from `Environment`'s arguments.

  `deprecated` holds the keyword arguments that `ExecutionOptions` and
  `Task.observation_groups` replace; each still works, with a warning.
  `arguments`: the names of `Environment`'s arguments, for the error that
  an unknown keyword gets.
  """
  if options is not None and not isinstance(options, ExecutionOptions):
    raise TypeError(
        'Environment(options=...) takes an ExecutionOptions, got '
        f'{type(options).__name__} {options!r}.'
    )
  unknown = sorted(
      set(deprecated) - set(OPTION_FIELDS) - {'observation_groups'}
  )
  if unknown:
    raise TypeError(
        f'Environment() got unexpected keyword arguments {unknown}. Its '
        f'arguments: {", ".join(arguments)}; options=ExecutionOptions(...) '
        f'takes {", ".join(OPTION_FIELDS)}.'
    )
  observation_groups = deprecated.pop('observation_groups', None)
  if observation_groups is not None:
    warnings.warn(
        'Environment(observation_groups=...) is deprecated: override '
        "Task.observation_groups() instead (the environment uses the task's "
        'groups when given none).',
        DeprecationWarning,
        stacklevel=3,
    )
  if options is not None and deprecated:
    names = ', '.join(f'{name}=...' for name in deprecated)
    raise TypeError(
        f'Environment({names}) and options=... were both given: pass '
        f'{", ".join(deprecated)} in options=ExecutionOptions(...) only.'
    )
  for name, value in deprecated.items():
    warnings.warn(
        f'Environment({name}={value!r}) is deprecated: pass '
        f'options=ExecutionOptions({name}={value!r}).',
        DeprecationWarning,
        stacklevel=3,
    )
  if options is None:
    options = ExecutionOptions(**deprecated)
  return options, observation_groups


def check_one_world(state):
  if jnp.ndim(state.step_type):
    raise ValueError(
        f'This state holds {jnp.shape(state.step_type)[0]} worlds: step a '
        'batch with jax.vmap(env.step)(states, actions).'
    )


def as_key(key):
  key = jnp.asarray(key) if not isinstance(key, jax.Array) else key
  if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
    if key.shape == ():
      return key
  elif key.shape == (2,) and key.dtype == jnp.uint32:
    return jax.random.wrap_key_data(key)
  raise ValueError(
      'reset expects one PRNG key (jax.random.key(seed)); got an '
      f'array of shape {key.shape} and dtype {key.dtype}. For a '
      'batch, jax.vmap(env.reset)(jax.random.split(key, n)).'
  )
