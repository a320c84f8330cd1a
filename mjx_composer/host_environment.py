"""`HostEnvironment`: a stateful, dm_env-style wrapper for notebooks and ports.

    env = HostEnvironment(composer.Environment(task), num_worlds=None, seed=0)
    timestep = env.reset()
    while not timestep.last():
      timestep = env.step(action)

It holds the current `State` and a jitted `reset`/`step` (vmapped when
`num_worlds` is given) and returns `dm_env.TimeStep`s of numpy arrays, so code
written for dm_control's `composer.Environment` runs with few changes. For
one world, FIRST timesteps carry `reward=None` and `discount=None` as in
dm_env; for a batch, worlds step in lockstep and each auto-resets on its own
(`step_type` is then an array, and `reward`/`discount` are arrays too).
"""

import dm_env
import jax
import numpy as np


class HostEnvironment(dm_env.Environment):
  """A stateful dm_env wrapper around a pure `Environment`.

  Args:
    environment: the `mjx_composer.Environment`.
    num_worlds: None for a single world with dm_env's scalar conventions, or
      a batch size.
    seed: an int seed; world i of a batch uses `split(key(seed), n)[i]`.
  """

  def __init__(self, environment, num_worlds=None, seed=0):
    self._env = environment
    self._num_worlds = num_worlds
    self._key = jax.random.key(seed)
    if num_worlds is None:
      self._reset_fn = jax.jit(environment.reset)
      self._step_fn = jax.jit(environment.step)
    else:
      self._reset_fn = jax.jit(jax.vmap(environment.reset))
      self._step_fn = jax.jit(jax.vmap(environment.step))
    self._state = None

  @property
  def environment(self):
    return self._env

  @property
  def state(self):
    """The current (device) `State`; None before the first reset."""
    return self._state

  @property
  def physics(self):
    """The current `Physics` (batched when `num_worlds` is set)."""
    return self._env.physics(self._state)

  def reset(self) -> dm_env.TimeStep:
    self._key, key = jax.random.split(self._key)
    if self._num_worlds is not None:
      key = jax.random.split(key, self._num_worlds)
    self._state = self._reset_fn(key)
    return self._timestep()

  def step(self, action) -> dm_env.TimeStep:
    if self._state is None:
      return self.reset()
    action = np.asarray(action, dtype=np.float32)
    self._state = self._step_fn(self._state, action)
    return self._timestep()

  def _timestep(self) -> dm_env.TimeStep:
    state = jax.device_get(self._state)
    observation = state.observation
    step_type = np.asarray(state.step_type)
    if self._num_worlds is None:
      step_type = dm_env.StepType(int(step_type))
      if step_type == dm_env.StepType.FIRST:
        return dm_env.TimeStep(step_type, None, None, observation)
    return dm_env.TimeStep(
        step_type,
        np.asarray(state.reward),
        np.asarray(state.discount),
        observation,
    )

  def action_spec(self):
    return self._env.action_spec()

  def observation_spec(self):
    return self._env.observation_spec()

  def reward_spec(self):
    return self._env.reward_spec()

  def discount_spec(self):
    return self._env.discount_spec()
