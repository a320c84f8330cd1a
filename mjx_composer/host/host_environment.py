"""Stateful host loops over a pure `Environment`: one world, or a batch.

One world, a real `dm_env.Environment` (for notebooks and dm_control ports):

    env = HostEnvironment(composer.Environment(task), seed=0)
    timestep = env.reset()
    while not timestep.last():
      timestep = env.step(action)

A batch of worlds stepped in lockstep, with its own interface (NOT a
`dm_env.Environment`: `step_type`, `reward` and `discount` are arrays):

    env = HostEnvironment(composer.Environment(task), num_worlds=64, seed=0)
    # == BatchedHostEnvironment(...)
    timestep = env.reset()                 # a BatchedTimeStep
    timestep = env.step(actions)           # actions: (64, *action_spec.shape)

Both hold the current `State`, jit `reset`/`step` themselves (vmapped for a
batch), manage the keys and return numpy arrays.

A batch can be spread over several devices (see `mjx_composer.platform.sharding`):

    env = BatchedHostEnvironment(composer.Environment(task), num_worlds=64,
                                 mesh=sharding.world_mesh())
"""

from __future__ import annotations

from typing import Any, NamedTuple

import dm_env
import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer import environment as environment_lib
from mjx_composer.platform import sharding

# numpy's and composer's seeds are non-negative; JAX takes int64 seeds.
_SEED_MAX = 2**63 - 1


def check_seed(seed):
  """Returns `seed` as an int, or raises naming `seed` and the fix.

  `jax.random.key` refuses strings, floats and integers past 64 bits deep
  inside JAX; refuse them here, with the range that works.
  """
  if isinstance(seed, (bool, np.bool_)) or not isinstance(
      seed, (int, np.integer)
  ):
    raise TypeError(
        f'seed must be an int, got {seed!r} ({type(seed).__name__}). Pass an '
        f'int in [0, 2**63), e.g. seed=0.'
    )
  if not 0 <= int(seed) <= _SEED_MAX:
    raise ValueError(
        f'seed must be in [0, 2**63) (a JAX key holds 64 bits), got {seed!r}. '
        'Pass a smaller non-negative int, e.g. seed % 2**63.'
    )
  return int(seed)


def _raise_if_initialization_failed(state, what):
  """composer's `EpisodeInitializationError` where every attempt failed.

  Inside the jitted reset nothing can raise: `metrics['init_failed']` marks
  the worlds whose last attempt failed too, and `metrics['init_failures']`
  counts their failed attempts. On the host, a reset that returns such a
  world raises as composer's environment does after its retries.
  """
  failed, failures = jax.device_get(
      (state.metrics['init_failed'], state.metrics['init_failures'])
  )
  failed = np.atleast_1d(np.asarray(failed) > 0)
  if not failed.any():
    return
  attempts = int(np.max(np.atleast_1d(failures)[failed]))
  worlds = np.flatnonzero(failed).tolist()
  where = (
      f' in world(s) {worlds[:10]}'
      if np.ndim(state.metrics['init_failed'])
      else ''
  )
  raise environment_lib.EpisodeInitializationError(
      f'{what}: all {attempts} attempt(s) to initialize the episode failed'
      f"{where}: the task's initialize_episode (e.g. a PropPlacer or an "
      'initializer) reported failure every time. Raise '
      'Environment(max_reset_attempts=...), or make the initial state '
      'easier to find (e.g. more max_attempts_per_prop, fewer props).'
  )


class BatchedTimeStep(NamedTuple):
  """What `BatchedHostEnvironment` returns: one entry per world.

  Attributes:
    step_type: int array `(num_worlds,)` of `dm_env.StepType` values.
    reward: the reward of the transition into this step, per world (0 where
      the world is at FIRST: an array cannot hold dm_env's None).
    discount: its discount, per world (1 where the world is at FIRST).
    observation: the observation, with a leading world axis. Under
      `auto_reset='same_step'`, a world at LAST already holds the first
      observation of its next episode here.
    final_observation: the last observation of the episode each world is in
      or just ended (equal to `observation` except at LAST under
      `auto_reset='same_step'`).
  """

  step_type: np.ndarray
  reward: Any
  discount: Any
  observation: Any
  final_observation: Any

  def first(self) -> np.ndarray:
    return self.step_type == dm_env.StepType.FIRST

  def mid(self) -> np.ndarray:
    return self.step_type == dm_env.StepType.MID

  def last(self) -> np.ndarray:
    return self.step_type == dm_env.StepType.LAST


def _as_numbers(value, where, name, shape):
  """`value` as a float32 array, or raises naming `name` and the fix.

  numpy converts strings of digits to floats, and fails on other strings and
  dicts with a conversion error naming neither the argument nor the fix.
  """
  try:
    array = np.asarray(value)
  except ValueError:  # ragged nested sequences
    array = None
  if array is None or array.dtype.kind not in 'biuf':
    raise TypeError(
        f'{where}: `{name}` must be numbers, an array of shape {shape}, got '
        f'{type(value).__name__} {value!r:.80}. Pass a numpy array of '
        f'floats, e.g. np.zeros({shape}, np.float32).'
    )
  return array.astype(np.float32)


def _auto_reset_mode(environment) -> str:
  mode = getattr(environment, 'auto_reset', None)
  if mode is None:
    mode = getattr(environment, '_auto_reset', 'next_step')
  return mode


def _fetch(state, gather=jax.device_get):
  """The host copies of what a timestep reports (not the whole State)."""
  return gather(
      (
          state.step_type,
          state.reward,
          state.discount,
          state.observation,
          state.final_observation,
      )
  )


class _HostLoop:
  """What the single-world and the batched host environments share."""

  def __init__(self, environment, seed, num_worlds, mesh=None):
    environment_lib.check_environment(environment, type(self).__name__)
    self._env = environment
    self._num_worlds = num_worlds
    self._key = jax.random.key(check_seed(seed))
    self._auto_reset = _auto_reset_mode(environment)
    self._mesh = mesh
    if mesh is not None:
      self._reset_fn = sharding.batched_reset(environment, mesh)
      self._step_fn = sharding.batched_step(environment, mesh)
    else:
      reset, step = environment.reset, environment.step
      if num_worlds is not None:
        reset, step = jax.vmap(reset), jax.vmap(step)
      self._reset_fn = jax.jit(reset)
      self._step_fn = jax.jit(step)
    self._state = None
    self._pending_first = False

  @property
  def environment(self):
    """The pure `mjx_composer.Environment`."""
    return self._env

  @property
  def state(self):
    """The current (device) `State`; None before the first reset."""
    return self._state

  @property
  def physics(self):
    """The current `Physics` (batched for a batch of worlds)."""
    return self._env.physics(self._state)

  def _new_state(self):
    if self._env.fixed_initial_state:
      key = jax.random.split(self._key)[1]  # the first episode's, every time
    else:
      self._key, key = jax.random.split(self._key)
    if self._mesh is not None:
      key = sharding.world_keys(key, self._num_worlds, self._mesh)
    elif self._num_worlds is not None:
      key = jax.random.split(key, self._num_worlds)
    return self._reset_fn(key)

  def action_spec(self):
    """One world's action spec (a batch takes a leading world axis)."""
    return self._env.action_spec()

  def observation_spec(self):
    """One world's observation spec."""
    return self._env.observation_spec()

  def reward_spec(self):
    return self._env.reward_spec()

  def discount_spec(self):
    return self._env.discount_spec()

  def close(self):
    """Drops the state; nothing else to release."""
    self._state = None
    self._pending_first = False


class HostEnvironment(_HostLoop, dm_env.Environment):
  """A stateful `dm_env.Environment` over one world of a pure `Environment`.

  It keeps dm_env's contract whatever the environment's `auto_reset` mode:
  `reset()` and the first `step()` of a fresh environment return FIRST
  (`reward` and `discount` None), and the `step()` after a LAST returns the
  FIRST of the next episode, ignoring its action. Under
  `auto_reset='same_step'` the environment has already started the next
  episode in the step that returned LAST (whose observation is the ended
  episode's last one, `State.final_observation`); this wrapper holds that
  state and emits its FIRST on the next `step()` (so between that LAST and
  that FIRST, `state` and `physics` already hold the next episode).

  `HostEnvironment(environment, num_worlds=n)` (any int n >= 1) returns a
  `BatchedHostEnvironment` instead, which is not a `dm_env.Environment`.

  Args:
    environment: the `mjx_composer.Environment`.
    num_worlds: None for this single-world environment; an int for a
      `BatchedHostEnvironment` of that many worlds.
    seed: an int seed for the episodes' keys, in [0, 2**63).
    mesh: only for a batch (see `BatchedHostEnvironment`).
  """

  def __new__(cls, environment=None, num_worlds=None, seed=0, mesh=None):
    if cls is HostEnvironment and num_worlds is not None:
      return BatchedHostEnvironment(environment, num_worlds, seed, mesh)
    return super().__new__(cls)

  def __init__(self, environment, num_worlds=None, seed=0, mesh=None):
    if num_worlds is not None:
      raise ValueError(
          f'{type(self).__name__} steps one world: use '
          'BatchedHostEnvironment(environment, num_worlds) for a batch.'
      )
    if mesh is not None:
      raise ValueError(
          'A mesh spreads a batch of worlds over devices; this '
          'HostEnvironment steps one world. Pass num_worlds for a batch.'
      )
    super().__init__(environment, seed, None)

  def reset(self) -> dm_env.TimeStep:
    """Starts an episode.

    Raises:
      EpisodeInitializationError: when every one of the environment's
        `max_reset_attempts` attempts failed, as composer's reset does.
    """
    self._state = self._new_state()
    self._pending_first = False
    _raise_if_initialization_failed(self._state, 'HostEnvironment.reset')
    return self._timestep()

  def step(self, action) -> dm_env.TimeStep:
    if self._state is None:
      return self.reset()
    if self._pending_first:
      # Same-step auto-reset: the held state is the next episode's start.
      self._state = self._state.replace(
          step_type=jnp.full_like(
              self._state.step_type, int(dm_env.StepType.FIRST)
          ),
          reward=jnp.zeros_like(self._state.reward),
          discount=jnp.ones_like(self._state.discount),
          terminated=jnp.zeros_like(self._state.terminated),
          truncated=jnp.zeros_like(self._state.truncated),
          final_observation=self._state.observation,
      )
      self._pending_first = False
      return self._timestep()
    self._state = self._step_fn(self._state, self._check_action(action))
    timestep = self._timestep()
    if timestep.last() and self._auto_reset == 'same_step':
      self._pending_first = True
    return timestep

  def _check_action(self, action):
    shape = tuple(self.action_spec().shape)
    action = _as_numbers(action, 'HostEnvironment.step', 'action', shape)
    if action.shape != shape:
      hint = ''
      if action.ndim == len(shape) + 1 and action.shape[1:] == shape:
        hint = (
            f' To step {action.shape[0]} worlds, use '
            f'HostEnvironment(environment, num_worlds={action.shape[0]}).'
        )
      raise ValueError(
          f'HostEnvironment steps one world: expected an action of shape '
          f'{shape} (its action_spec), got {action.shape}.{hint}'
      )
    return action

  def _timestep(self) -> dm_env.TimeStep:
    step_type, reward, discount, observation, final = _fetch(self._state)
    step_type = dm_env.StepType(int(step_type))
    if step_type == dm_env.StepType.FIRST:
      return dm_env.TimeStep(step_type, None, None, observation)
    if step_type == dm_env.StepType.LAST:
      # Under same-step auto-reset `observation` is already the next one.
      observation = final
    return dm_env.TimeStep(
        step_type, np.asarray(reward), np.asarray(discount), observation
    )


class BatchedHostEnvironment(_HostLoop):
  """A stateful loop over a batch of worlds stepped in lockstep.

  This is NOT a `dm_env.Environment`: `reset()` and `step(actions)` return a
  `BatchedTimeStep` whose `step_type`, `reward` and `discount` are arrays
  with one entry per world, and every world auto-resets on its own, as the
  pure environment's `auto_reset` mode says:

  * `'next_step'`: the step after a world's LAST returns that world's FIRST
    (its action is ignored); FIRST worlds report reward 0 and discount 1.
  * `'same_step'`: the step that ends a world's episode returns LAST with
    that transition's reward and discount, the next episode's first
    observation in `observation` and the ended episode's last observation in
    `final_observation`; the next step continues the new episode (no FIRST).

  For a dm_env loop over one world use `HostEnvironment` (`num_worlds=None`).

  Args:
    environment: the `mjx_composer.Environment`.
    num_worlds: the batch size, an int >= 1.
    seed: an int seed; world i's first episode uses `split(key, n)[i]` of a
      key split from `key(seed)`.
    mesh: None (the default): the batch runs on JAX's default device. A mesh
      from `mjx_composer.platform.sharding.world_mesh`, or a sequence of devices to
      build one over: the batch is split over its devices along the world
      axis (`num_worlds` must be a multiple of their number), each device
      stepping its own worlds (`sharding.batched_step`). A world's episodes
      do not depend on the mesh. The timesteps returned hold every world, so
      with several processes (`jax.distributed`) every process passes every
      world's actions and gets every world's timestep (an all-gather each
      step; for throughput use `sharding.batched_step` directly).
  """

  def __init__(self, environment, num_worlds, seed=0, mesh=None):
    if (
        isinstance(num_worlds, bool)
        or not isinstance(num_worlds, (int, np.integer))
        or num_worlds < 1
    ):
      raise ValueError(
          f'num_worlds must be a positive int (the batch size), got '
          f'{num_worlds!r}. Use num_worlds=None (the default) for one world '
          'as a dm_env.Environment.'
      )
    if mesh is not None:
      if not isinstance(mesh, jax.sharding.Mesh):
        mesh = sharding.world_mesh(mesh)
      sharding.check_num_worlds(int(num_worlds), mesh)
    super().__init__(environment, seed, int(num_worlds), mesh)

  @property
  def num_worlds(self) -> int:
    return self._num_worlds

  @property
  def mesh(self) -> jax.sharding.Mesh | None:
    """The mesh the worlds are split over; None on the default device."""
    return self._mesh

  def reset(self) -> BatchedTimeStep:
    """Starts a new episode in every world.

    Raises:
      EpisodeInitializationError: when, in some world, every one of the
        environment's `max_reset_attempts` attempts failed (as composer's
        reset does). The auto-resets inside `step` cannot raise: they report
        it in `metrics['init_failed']`.
    """
    self._state = self._new_state()
    _raise_if_initialization_failed(self._state, 'BatchedHostEnvironment.reset')
    return self._timestep()

  def step(self, actions) -> BatchedTimeStep:
    """Steps every world; `actions` has shape `(num_worlds, *action_shape)`.

    On a fresh environment this resets instead (the actions are ignored).
    """
    if self._state is None:
      return self.reset()
    actions = self._check_actions(actions)
    if self._mesh is not None:
      actions = sharding.put_worlds(actions, self._mesh)
    self._state = self._step_fn(self._state, actions)
    return self._timestep()

  def _check_actions(self, actions):
    shape = tuple(self.action_spec().shape)
    batch_shape = (self._num_worlds,) + shape
    actions = _as_numbers(
        actions, 'BatchedHostEnvironment.step', 'actions', batch_shape
    )
    if actions.shape != batch_shape:
      if actions.shape == shape:
        got = f"{actions.shape}, the shape of one world's action"
      else:
        got = f'{actions.shape}'
      raise ValueError(
          f'This host environment steps {self._num_worlds} worlds at once: '
          f'expected actions of shape {batch_shape} (num_worlds, '
          f'*action_spec().shape), one row per world, got {got}. To give '
          'every world the same action, pass '
          f'np.broadcast_to(action, {batch_shape}).'
      )
    return actions

  def _timestep(self) -> BatchedTimeStep:
    gather = jax.device_get if self._mesh is None else sharding.gather_worlds
    step_type, reward, discount, observation, final = _fetch(
        self._state, gather
    )
    return BatchedTimeStep(
        step_type=np.asarray(step_type),
        reward=np.asarray(reward),
        discount=np.asarray(discount),
        observation=observation,
        final_observation=final,
    )
