"""A Brax `Env` over a composed `Environment`, for `brax.training` agents.

    from brax.training.agents.ppo import train as ppo
    from mjx_composer.adapters import brax as brax_adapter

    env = composer.Environment(
        task, time_limit=2.,
        options=composer.ExecutionOptions(auto_reset='same_step'))
    brax_env = brax_adapter.BraxEnv(env, obs_key='policy')
    make_policy, params, metrics = ppo.train(
        environment=brax_env, num_timesteps=..., num_envs=...,
        **brax_adapter.training_kwargs(brax_env))

`training_kwargs` gives `wrap_env_fn` and `episode_length`. Brax's default
training wrappers (`envs.training.wrap`) do not suit a composed environment:

* Brax's `AutoResetWrapper` caches the first state of each world and
  restores it at every episode end, so every episode of a world would replay
  the same randomization. Our `Environment` auto-resets each world itself
  (`auto_reset='same_step'`), sampling every episode's randomization afresh
  from the world's key, and the adapter passes that through unchanged.
* Brax's `EpisodeWrapper` counts steps against `episode_length`; ours counts
  them against the `Environment`'s `time_limit` and reports the end of the
  episode as truncation, not termination, so PPO does not treat it as a
  terminal state: `info['truncation'] = 1` (and `info['time_out'] = 1` for
  `bootstrap_on_timeout`).
* Brax's `randomization_fn` samples one model per world for the whole run;
  randomization here belongs to the task (per-episode, in
  `initialize_episode` and variations), so `wrap_for_training` refuses it.

So `wrap_for_training` (the `wrap_env_fn`) only checks its arguments and
returns the environment: `BraxEnv.reset` and `BraxEnv.step` vmap themselves
when given a batch of keys or actions, as Brax's wrapped environments do.
Training with `wrap_env=False` works the same way. Evaluation uses Brax's
`Evaluator` unchanged: it wraps the env in its `EvalWrapper`, which sums
`State.metrics` and the reward over each world's first episode (it stops
counting at the first `done`, so our auto-reset does not leak into it).

What a Brax `State` holds (per world; batched under vmap):

* `obs`: the selected observation (see `obs_key`), each array flattened to
  one axis as Brax's networks expect;
* `reward`, `done` (float32; `done` is 1 at the step that ends an episode,
  whose `obs` is already the next episode's first observation);
* `metrics`: the task's `get_metrics` and `diverged` for this step (Brax's
  evaluator sums them over the episode);
* `info`: `steps` (steps taken in the episode this step belongs to),
  `truncation` and `time_out` (1 where the time limit ended it),
  `episode_done`, `episode_metrics` (`sum_reward`, `length`, and each metric
  summed over the episode so far, Brax's `EpisodeWrapper` convention, used
  by `log_training_metrics`), `discount` (the task's) and `final_obs` (the
  ended episode's last observation where `done`, else `obs`);
* `pipeline_state`: the composer `State` (with its key stored as raw key
  data, so Brax can strip weak types and donate it). `composer_state(state)`
  gives it back, e.g. for `mjx_composer.host.rendering`.
"""

from __future__ import annotations

import copy
import logging
import math
from typing import Mapping, Sequence, Union

from brax.envs import base as brax_base
import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer import environment as environment_lib
from mjx_composer.platform import internals_jax

ObsKey = Union[None, str, Sequence[str]]


def install_jax_compat():
  """Gives JAX >= 0.10 back `jax.device_put_replicated` for Brax 0.14.

  `BraxEnv` calls it when it is built (importing this module changes
  nothing); call it yourself before using Brax's training code without a
  `BraxEnv`.

  Brax 0.14.2 (the latest release) replicates its training state with
  `jax.device_put_replicated`, which JAX 0.10 removed (google/brax#671), so
  `ppo.train` fails before its first step. This installs JAX's documented
  drop-in replacement, only where the function is missing.
  """
  try:
    jax.device_put_replicated  # pylint: disable=pointless-statement
    return
  except AttributeError:
    pass

  def device_put_replicated(x, devices):
    # The axis is named like Brax's pmap axis ('i') and weak types are
    # stripped, so that arrays replicated here and those Brax's pmapped
    # training returns have the same type and sharding: otherwise every
    # jitted function they reach (the evaluator, the training epoch) compiles
    # twice.
    global _pending_eval_sharding
    mesh = jax.sharding.Mesh(np.array(devices), ('i',))
    sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec('i'))
    # On one device, what Brax unpmaps from this state (the policy's
    # parameters) keeps this mesh in its type, and so does every state its
    # evaluator's unroll returns; the evaluator's first state must match
    # (`wrap_for_training`, which Brax calls for the evaluator next).
    _pending_eval_sharding = (
        jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec())
        if len(devices) == 1
        else None
    )

    def put(y):
      y = jnp.asarray(y)
      y = jnp.stack([y.astype(y.dtype)] * len(devices))
      return jax.device_put(y, sharding)

    return jax.tree.map(put, x)

  logging.info(
      'mjx_composer.adapters.brax: installed jax.device_put_replicated for '
      'Brax (removed in JAX 0.10, google/brax#671).'
  )
  internals_jax.install_device_put_replicated(device_put_replicated)


# The sharding for the evaluator's environment's states, set by our
# `device_put_replicated` and taken by the next `wrap_for_training` (see there).
_pending_eval_sharding = None

# Keys that Brax's own AutoResetWrapper adds to `info`.
_BRAX_AUTO_RESET_KEYS = ('first_pipeline_state', 'first_obs')


class BraxEnv(brax_base.Env):
  """A composed `Environment` as a Brax `Env`.

  Args:
    environment: an `mjx_composer.Environment` built with
      `auto_reset='same_step'`.
    obs_key: which observation Brax sees. None: the whole observation: with
      observation groups, the dict of groups (each flattened), for
      `make_ppo_networks(policy_obs_key=..., value_obs_key=...)`; without
      them, every observable concatenated into one array (Brax's networks
      would otherwise look for a 'state' entry that is not there). A string:
      one entry (a flattened group such as 'policy', or an observable) as an
      array; a non-empty sequence of distinct strings: those entries
      concatenated into one array. Checked against the observation spec
      when the adapter is built.
    episode_length: the number of steps Brax's evaluator unrolls. Defaults to
      the environment's time limit in control steps; required if that is
      infinite.
    rescale_actions: map Brax's actions in [-1, 1] linearly onto the action
      spec's bounds (unbounded dimensions pass through). Off by default: the
      bundled tasks' controls already range over [-1, 1].
  """

  def __init__(
      self,
      environment,
      obs_key: ObsKey = None,
      episode_length: int | None = None,
      rescale_actions: bool = False,
  ):
    environment_lib.check_environment(
        environment,
        'BraxEnv',
        build=(
            'composer.Environment(task, options=composer.ExecutionOptions('
            "auto_reset='same_step'))"
        ),
        needs=" built with auto_reset='same_step'",
    )
    install_jax_compat()
    auto_reset = environment.auto_reset
    if auto_reset != 'same_step':
      raise ValueError(
          "BraxEnv needs an Environment built with auto_reset='same_step' "
          f'(got {auto_reset!r}): Brax trains on the transition into each '
          'LAST step and must see the next episode start in the same step.'
      )
    self._env = environment
    self._obs_key, self._concatenate_all = _check_obs_key(environment, obs_key)
    spec = environment.action_spec()
    if len(spec.shape) != 1:
      raise ValueError(
          f'Brax needs a flat action; the action spec has shape '
          f'{spec.shape}.'
      )
    if environment.reward_spec().shape != ():
      raise ValueError(
          'Brax needs a scalar reward; the task has a reward of '
          f'shape {environment.reward_spec().shape}.'
      )
    self._action_size = int(spec.shape[0])
    self._rescale = None
    if rescale_actions:
      low = np.asarray(spec.minimum, np.float32)
      high = np.asarray(spec.maximum, np.float32)
      bounded = np.abs(high - low) < 1e9
      self._rescale = (
          np.where(bounded, (high + low) / 2, 0.0),
          np.where(bounded, (high - low) / 2, 1.0),
      )
    if episode_length is None:
      if math.isinf(environment.time_limit):
        raise ValueError(
            'The environment has no time limit: pass '
            "episode_length for Brax's evaluator."
        )
      episode_length = environment.step_limit
    if (
        isinstance(episode_length, (bool, np.bool_))
        or not isinstance(episode_length, (int, float, np.integer, np.floating))
        or not math.isfinite(episode_length)
        or int(episode_length) != episode_length
        or episode_length < 1
    ):
      raise ValueError(
          'episode_length must be a positive number of control steps, got '
          f"{episode_length!r}: pass the number of steps Brax's evaluator "
          'should unroll, or leave it out to use the time limit.'
      )
    self._episode_length = int(episode_length)
    self._abstract_state_cache = None
    self._reset_sharding = None
    # A replication before this environment existed was not Brax's for it.
    global _pending_eval_sharding
    _pending_eval_sharding = None

  # -- Brax's Env interface ------------------------------------------------

  @property
  def environment(self):
    """The wrapped `mjx_composer.Environment`."""
    return self._env

  @property
  def episode_length(self) -> int:
    """Control steps in an episode (pass it to `ppo.train`)."""
    return self._episode_length

  @property
  def observation_size(self):
    """An int for an array observation; a dict of shapes for a dict."""
    obs = self._abstract_state().obs
    if isinstance(obs, Mapping):
      return {k: tuple(v.shape) for k, v in obs.items()}
    return int(obs.shape[-1])

  @property
  def action_size(self) -> int:
    return self._action_size

  @property
  def backend(self) -> str:
    return 'mjx'

  @property
  def dt(self) -> float:
    return self._env.control_timestep()

  @property
  def mj_model(self):
    return self._env.mj_model

  def reset(self, rng: jax.Array) -> brax_base.State:
    """Resets one world, or a batch if `rng` is a batch of keys."""
    if _key_batch_ndim(rng):
      state = jax.vmap(self.reset)(rng)
      # Only where the keys carry no mesh (the evaluator's plain `jit`s),
      # never inside Brax's pmapped training.
      if (
          self._reset_sharding is not None
          and not jax.typeof(rng).sharding.mesh.axis_names
      ):
        state = jax.lax.with_sharding_constraint(state, self._reset_sharding)
      return state
    return self._wrap(self._env.reset(rng), first=True)

  def step(self, state: brax_base.State, action: jax.Array) -> brax_base.State:
    """Steps one world, or a batch if `action` has a leading batch axis."""
    if any(key in state.info for key in _BRAX_AUTO_RESET_KEYS):
      raise ValueError(
          "BraxEnv was wrapped by Brax's AutoResetWrapper, which would "
          "replay each world's first episode. Pass **training_kwargs(env) "
          '(wrap_env_fn=wrap_for_training) or wrap_env=False to ppo.train.'
      )
    action = jnp.asarray(action)
    self._check_action_shape(state, action)
    if action.ndim > 1:
      return jax.vmap(self.step)(state, action)
    if self._rescale is not None:
      center, half = self._rescale
      action = center + half * action
    previous = composer_state(state)
    stepped = self._env.step(previous, action)
    return self._wrap(stepped, first=False, previous=state)

  # -- helpers -------------------------------------------------------------

  def _check_action_shape(self, state, action):
    """Refuses actions whose batch is not the state's, naming the fix.

    A state's reward has its batch shape: `()` for one world.
    """
    batch = tuple(jnp.shape(state.reward))
    expected = batch + (self._action_size,)
    if tuple(action.shape) == expected:
      return
    if not batch:
      held = "one world's (reset with one key)"
    else:
      held = f'a batch of shape {batch} (reset with that batch of keys)'
    hint = ''
    if not batch and action.ndim == 2:
      n = action.shape[0]
      hint = (
          f' To step {n} worlds, reset with {n} keys '
          f'(jax.random.split(key, {n})) and step that batched state.'
      )
    elif batch and tuple(action.shape) == (self._action_size,):
      hint = (
          ' To give every world the same action, pass '
          f'jnp.broadcast_to(action, {expected}).'
      )
    raise ValueError(
        f'BraxEnv.step: `action` has shape {tuple(action.shape)}, but `state` '
        f"is {held}: pass actions of shape {expected}, the state's batch "
        f'shape then action_size {self._action_size}.{hint}'
    )

  def _abstract_state(self):
    # Shapes only (no compile); observation_size asks for them.
    if self._abstract_state_cache is None:
      self._abstract_state_cache = jax.eval_shape(
          self.reset, jax.random.PRNGKey(0)
      )
    return self._abstract_state_cache

  def select_observation(self, observation):
    """The part of a composer observation that Brax sees, flattened."""
    key = self._obs_key
    if key is None:
      if self._concatenate_all:
        return jnp.concatenate([_flat(v) for v in jax.tree.leaves(observation)])
      if isinstance(observation, Mapping):
        return {k: _flat(v) for k, v in observation.items()}
      return _flat(observation)
    if not isinstance(observation, Mapping):
      raise ValueError(
          f'obs_key={key!r} selects from a dict, but the '
          'observation is an array.'
      )
    keys = [key] if isinstance(key, str) else list(key)
    missing = [k for k in keys if k not in observation]
    if missing:
      raise ValueError(
          f'obs_key: no observation {missing}; the observation '
          f'has {sorted(observation)}.'
      )
    return jnp.concatenate([_flat(observation[k]) for k in keys])

  def _step_metrics(self, state):
    # episode_return/episode_length are running totals: Brax's evaluator sums
    # metrics over steps, so it gets only the per-step ones.
    return {
        k: jnp.asarray(v, jnp.float32)
        for k, v in state.metrics.items()
        if k not in ('episode_return', 'episode_length')
    }

  def _wrap(self, state, first, previous=None) -> brax_base.State:
    done = state.last().astype(jnp.float32)
    truncation = jnp.asarray(state.truncated, jnp.float32)
    metrics = self._step_metrics(state)
    steps = jnp.asarray(state.metrics['episode_length'], jnp.float32)
    if first:
      summed = {k: jnp.zeros((), jnp.float32) for k in metrics}
    else:
      # Restart the sums at the first step of each episode.
      keep = 1.0 - previous.info['episode_done']
      summed = {
          k: keep * previous.info['episode_metrics'][k] + v
          for k, v in metrics.items()
      }
    episode_metrics = {
        'sum_reward': jnp.asarray(state.metrics['episode_return'], jnp.float32),
        'length': steps,
        **summed,
    }
    info = {
        'steps': steps,
        'truncation': truncation,
        'time_out': truncation,
        'episode_done': done,
        'episode_metrics': episode_metrics,
        'discount': jnp.asarray(state.discount, jnp.float32),
        'final_obs': self.select_observation(state.final_observation),
    }
    raw = state.replace(key=jax.random.key_data(state.key))
    return brax_base.State(
        pipeline_state=raw,
        obs=self.select_observation(state.observation),
        reward=jnp.asarray(state.reward, jnp.float32),
        done=done,
        metrics=metrics,
        info=info,
    )


def _check_obs_key(environment, obs_key):
  """`(obs_key, concatenate_all)`, or an error naming `obs_key` and the fix.

  `concatenate_all` is True where `obs_key=None` meets an observation that
  is not an array or a dict of observation groups (the observables of a
  task without groups): Brax's networks need one array there.
  """
  spec = environment.observation_spec()
  is_dict = isinstance(spec, Mapping)
  if obs_key is None:
    if not is_dict:
      return None, not hasattr(spec, 'shape')  # A list of dicts: concatenate.
    observable_keys = set(environment.observation_updater.keys)
    if all(
        k in observable_keys and not isinstance(v, Mapping)
        for k, v in spec.items()
    ):
      return None, True  # No groups: the observables, concatenated.
    nested = [k for k, v in spec.items() if isinstance(v, Mapping)]
    if nested:
      raise ValueError(
          f'BraxEnv(obs_key=None): observation group(s) {nested} are not '
          'flattened (their observation is a dict of observables), which '
          "Brax's networks cannot take. Declare them with "
          'ObservationGroup(..., flatten=True), or pass obs_key naming the '
          'flattened groups or observables to use.'
      )
    return None, False
  if isinstance(obs_key, str):
    keys = [obs_key]
  elif isinstance(obs_key, Sequence) and all(
      isinstance(k, str) for k in obs_key
  ):
    keys = list(obs_key)
  else:
    raise TypeError(
        f'BraxEnv: obs_key must be None, a string or a sequence of strings, '
        f"got {obs_key!r}. Pass e.g. obs_key='policy'."
    )
  if not keys:
    raise ValueError(
        'BraxEnv: obs_key=[] selects no observation. Pass None for the whole '
        'observation, or name at least one entry.'
    )
  duplicated = sorted({k for k in keys if keys.count(k) > 1})
  if duplicated:
    raise ValueError(
        f'BraxEnv: obs_key={obs_key!r} names {duplicated} more than once, '
        'which would feed the same values twice. Name each entry once.'
    )
  if not is_dict:
    raise ValueError(
        f'BraxEnv: obs_key={obs_key!r} selects from a dict, but the '
        'observation is an array: pass obs_key=None.'
    )
  missing = [k for k in keys if k not in spec]
  if missing:
    raise ValueError(
        f'BraxEnv: obs_key: no observation {missing}; the observation has '
        f'{sorted(spec)}. Pass some of those.'
    )
  nested = [k for k in keys if isinstance(spec[k], Mapping)]
  if nested:
    raise ValueError(
        f'BraxEnv: obs_key={obs_key!r}: group(s) {nested} are not flattened '
        '(their observation is a dict of observables), so they cannot be '
        'one array for Brax. Declare them with ObservationGroup(..., '
        'flatten=True).'
    )
  return obs_key, False


def composer_state(state: brax_base.State):
  """The composer `State` inside a Brax `State` made by `BraxEnv`."""
  raw = state.pipeline_state
  return raw.replace(key=jax.random.wrap_key_data(raw.key))


def wrap_for_training(
    env: BraxEnv,
    episode_length: int | None = None,
    action_repeat: int = 1,
    randomization_fn=None,
    **unused_kwargs,
) -> BraxEnv:
  """`ppo.train`'s `wrap_env_fn`: checks the arguments, returns `env` as is.

  `BraxEnv` already batches itself, auto-resets each world with fresh
  per-episode randomization, and reports truncation (see the module
  docstring), so none of Brax's training wrappers is applied.

  Raises:
    ValueError: if `randomization_fn` is given, `action_repeat` is not 1, or
      `episode_length` differs from the environment's.
  """
  if not isinstance(env, BraxEnv):
    raise TypeError(f'wrap_for_training wraps a BraxEnv, got {type(env)}.')
  if randomization_fn is not None:
    raise ValueError(
        'randomization_fn is not supported: Brax samples it once per run. '
        'Randomize in the task (initialize_episode, variations), which '
        'resamples every episode.'
    )
  if action_repeat != 1:
    raise ValueError(
        f"action_repeat={action_repeat} is not supported: set the task's "
        'control timestep instead (physics steps per control step).'
    )
  if episode_length is not None and episode_length != env.episode_length:
    raise ValueError(
        f"episode_length={episode_length} differs from the environment's "
        f'{env.episode_length} control steps (its time_limit): pass '
        'episode_length=env.episode_length, or change the time_limit.'
    )
  global _pending_eval_sharding
  sharding, _pending_eval_sharding = _pending_eval_sharding, None
  if sharding is None:
    return env
  # Brax's PPO and SAC wrap the evaluator's environment right after they
  # replicate the training state over one device. Their evaluator compiles
  # its unroll for the type of its first state, which comes from a plain
  # `jit` of `reset` (no mesh), and gets back states typed with the
  # training mesh, so it compiled the unroll a second time: states placed
  # like those keep it to one compile.
  placed = copy.copy(env)
  placed._reset_sharding = sharding  # pylint: disable=protected-access
  return placed


def training_kwargs(env: BraxEnv) -> dict:
  """The `ppo.train` (or `sac.train`) arguments a `BraxEnv` needs."""
  return {
      'wrap_env_fn': wrap_for_training,
      'episode_length': env.episode_length,
  }


def _flat(x):
  x = jnp.asarray(x)
  if not jnp.issubdtype(x.dtype, jnp.floating):
    x = x.astype(jnp.float32)
  return jnp.reshape(x, (-1,))


def _key_batch_ndim(rng) -> int:
  """Batch axes of a key array (typed keys or raw uint32 key data)."""
  rng = jnp.asarray(rng) if not isinstance(rng, jax.Array) else rng
  if jnp.issubdtype(rng.dtype, jax.dtypes.prng_key):
    return rng.ndim
  return rng.ndim - 1
