"""`Environment`: a composed task compiled once, with pure `reset` and `step`.

    env = composer.Environment(task, time_limit=10.)
    state = jax.jit(env.reset)(key)                       # one world
    states = jax.jit(jax.vmap(env.reset))(keys)           # a batch
    states = jax.jit(jax.vmap(env.step))(states, actions)

Construction (host, once): runs the build-time hooks
(`initialize_episode_mjcf`, then `after_compile`), composes the entity tree
into one `MjSpec`, compiles it, puts it on the device, resolves every element
to static indices, and plans the observation updater.

`reset(key)` and `step(state, action)` are pure functions of one world. They
follow composer's order of events:

* reset: the model's default data (`qpos0`, zero velocities and time), a
  forward pass with actuation disabled, the task's then each entity's
  `initialize_episode`, another forward pass with actuation disabled, and the
  first observation (timestamp 0).
* step: `before_step` (the task gets the action; its default writes `ctrl`),
  then `n_sub_steps` times (`before_substep`, `mjx.step`, `after_substep`,
  observation update) except that the last update comes after the
  `after_step` hooks, then reward, discount and termination.

Episode ends (`step_type == LAST`):

* termination (`task.should_terminate_episode`): discount from the task;
* truncation at the time limit: LAST with the task's discount (dm_env's
  convention), `truncated=True`. The limit is counted in control steps
  (`ceil(time_limit / control_timestep)`), not by comparing float32 time;
* divergence (any non-finite qpos, qvel, qacc or act after the step): LAST with
  reward 0 and discount 0, `metrics['diverged'] = 1`. Only that world is
  affected; its next reset replaces all of its data.

Auto-reset, per world:

* `auto_reset='next_step'` (composer): the `step` after a LAST ignores the
  action and returns the FIRST state of a new episode.
* `auto_reset='same_step'` (training loops): a step that ends an episode
  returns LAST with that transition's reward and discount, the new episode's
  first observation in `observation`, and the ended episode's last
  observation in `final_observation`; the next step continues the new episode.

Per-world state that outlives an episode: on auto-reset a world keeps its
model fields (`State.model_fields`, e.g. what a variator sampled) and its
`persistent` entries, so cumulative and once-per-world randomization see the
world's current values; `reset(key)` starts a world afresh from the compiled
model.

Initialization failures: an `initialize_episode` hook that cannot set up the
episode (e.g. `PropPlacer` finding no collision-free pose) marks it with
`physics.fail_initialization()`. The environment then reruns every
`initialize_episode` hook with a fresh key, up to `max_reset_attempts`
attempts in all, counts failed attempts in `metrics['init_failures']`, and
sets `metrics['init_failed']` when the last attempt failed too (composer
would raise `EpisodeInitializationError`; nothing raises inside jit).

Keys: `reset(key)` derives every random draw of the episode, and of the
episodes that auto-reset after it, from `key` alone, so the same key gives the
same trajectory bit for bit, whatever the batch size.
"""

from __future__ import annotations

import dataclasses
import enum
import logging
import math
from typing import Any, Callable

from dm_env import specs
from flax import struct
import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np

from mjx_composer import element_index
from mjx_composer import physics as physics_lib
from mjx_composer.observation import updater as updater_lib
from mjx_composer.observation.updater import ObservationPadding  # pylint: disable=unused-import

HOOK_NAMES = (
    'initialize_episode_mjcf',
    'after_compile',
    'initialize_episode',
    'before_step',
    'before_substep',
    'after_substep',
    'after_step',
)
_BUILD_HOOKS = HOOK_NAMES[:2]
# Hooks through which the task receives the action (entities never do).
_ACTION_HOOKS = ('before_step', 'before_substep')


class StepType(enum.IntEnum):
  """dm_env's step types, as stored in `State.step_type`."""

  FIRST = 0
  MID = 1
  LAST = 2


class EpisodeInitializationError(RuntimeError):
  """Raised by a task on the host when it fails to initialize an episode.

  Inside the jitted `reset` nothing can raise: initializers record failure in
  `State.metrics['init_failures']` instead (see `initializers`).
  """


@struct.dataclass
class State:
  """One world's state, carried between `step` calls (batched under vmap).

  Attributes:
    data: the world's `mjx.Data`.
    task_state: the per-world task state (`Task.initial_task_state`).
    model_fields: per-world values of the model fields that hooks or
      variations write (`{field name: value}`); every other model field is the
      environment's shared constant.
    obs_state: the observation updater's ring buffers and counters.
    observation: the observation of this timestep.
    reward: the reward of the transition into this timestep (0 at FIRST).
    discount: its discount (1 at FIRST).
    step_type: a `StepType` value (int32).
    terminated: the episode ended by termination or divergence.
    truncated: the episode ended at the time limit.
    final_observation: the last observation of the episode that ended at this
      step (equal to `observation` except under same-step auto-reset).
    metrics: per-world scalars: `episode_return` and `episode_length` (of the
      episode this step belongs to), `diverged`, and the task's metrics.
    key: the world's PRNG key for what comes next.
    steps: control steps taken in the current episode.
    episode_return: the current episode's return so far.
    persistent: per-world entries that survive auto-resets
      (`Physics.get_persistent`).
  """

  data: mjx.Data
  task_state: Any
  model_fields: dict
  obs_state: Any
  observation: Any
  reward: jax.Array
  discount: jax.Array
  step_type: jax.Array
  terminated: jax.Array
  truncated: jax.Array
  final_observation: Any
  metrics: dict
  key: jax.Array
  steps: jax.Array
  episode_return: jax.Array
  persistent: dict

  def first(self):
    return self.step_type == StepType.FIRST

  def mid(self):
    return self.step_type == StepType.MID

  def last(self):
    return self.step_type == StepType.LAST


def _tree_select(pred, on_true, on_false):
  return jax.tree.map(lambda a, b: jnp.where(pred, a, b), on_true, on_false)


def _select_reset(done, reset_fn, operands, stepped):
  """`reset_fn(*operands)` where `done`, else `stepped`.

  For one world this is a select. Under `jax.vmap` a select would compute the
  reset of every world at every step; the batching rule instead computes the
  batch's resets only when some world is done (`lax.cond` on `any(done)`),
  then selects per world. Results are the same either way.
  """

  def select(done, operands, stepped):
    return _tree_select(done, reset_fn(*operands), stepped)

  select_or_skip = jax.custom_batching.custom_vmap(select)

  @select_or_skip.def_vmap
  def _batched(axis_size, in_batched, done, operands, stepped):
    def batch(x, is_batched):
      return (
          x if is_batched else jnp.broadcast_to(x, (axis_size,) + jnp.shape(x))
      )

    done, operands, stepped = jax.tree.map(
        batch, (done, operands, stepped), tuple(in_batched)
    )
    out = jax.lax.cond(
        jnp.any(done),
        lambda: jax.vmap(select)(done, operands, stepped),
        lambda: stepped,
    )
    return out, jax.tree.map(lambda _: True, out)

  return select_or_skip(done, operands, stepped)


def _is_overridden(obj, name, base_cls) -> bool:
  method = getattr(type(obj), name, None)
  return method is not None and method is not getattr(base_cls, name, None)


class Environment:
  """A composed task, compiled once, with pure single-world reset and step.

  Args:
    task: the `Task`.
    time_limit: episode length in seconds (truncation); `inf` for none.
    random_state: an int seed or `numpy.random.RandomState` for the
      build-time host hooks (`initialize_episode_mjcf`, `after_compile`).
    n_sub_steps: overrides `task.physics_steps_per_control_step` (deprecated
      in composer; here the observation updater follows it too).
    strip_singleton_obs_buffer_dim: drop the buffer axis of size-1 buffers.
    delayed_observation_padding: `ObservationPadding.ZERO` or `INITIAL_VALUE`.
    auto_reset: 'next_step' (composer) or 'same_step' (see module docstring).
    per_world_model_fields: model field names (e.g. 'geom_rgba', 'opt') that
      step hooks may write per world, in addition to those that
      `initialize_episode` hooks write (which are found automatically).
    observation_groups: optional groups passed to the observation updater
      (e.g. `{'policy': ..., 'critic': ...}`), see `observation.updater`.
    max_reset_attempts: how many times `reset` may run the
      `initialize_episode` hooks when they report a failed initialization
      (`Physics.fail_initialization`), each time with a fresh key.
  """

  def __init__(
      self,
      task,
      time_limit=float('inf'),
      random_state=None,
      n_sub_steps=None,
      strip_singleton_obs_buffer_dim=False,
      delayed_observation_padding=ObservationPadding.ZERO,
      auto_reset='next_step',
      per_world_model_fields=(),
      observation_groups=None,
      max_reset_attempts=1,
  ):
    if not isinstance(delayed_observation_padding, ObservationPadding):
      raise ValueError(
          'delayed_observation_padding must be an '
          'ObservationPadding, got '
          f'{delayed_observation_padding!r}.'
      )
    if auto_reset not in ('next_step', 'same_step'):
      raise ValueError(
          "auto_reset must be 'next_step' or 'same_step', got "
          f'{auto_reset!r}.'
      )
    if int(max_reset_attempts) != max_reset_attempts or max_reset_attempts < 1:
      raise ValueError(
          'max_reset_attempts must be a positive integer, got '
          f'{max_reset_attempts!r}.'
      )
    if time_limit <= 0:
      raise ValueError(f'time_limit must be positive, got {time_limit}.')
    unknown = set(per_world_model_fields) - element_index.MODEL_FIELDS
    if unknown:
      raise ValueError(
          f'Unknown mjx.Model fields {sorted(unknown)} in '
          'per_world_model_fields.'
      )
    self._task = task
    self._time_limit = time_limit
    self._auto_reset = auto_reset
    self._max_reset_attempts = int(max_reset_attempts)
    self._random_state = (
        random_state
        if isinstance(random_state, np.random.RandomState)
        else np.random.RandomState(random_state)
    )
    self._extra_hooks = {name: [] for name in HOOK_NAMES}
    self._declared_model_fields = tuple(per_world_model_fields)

    # Build-time hooks, then compile once.
    self._call_host_hooks('initialize_episode_mjcf', self._random_state)
    spec, handles = task.root_entity.compose()
    self._spec = spec
    try:
      self._mj_model = spec.compile()
    except Exception as e:
      raise ValueError(f'The composed model failed to compile: {e}') from e
    handle_names = {
        key: (original, kind, composed.name)
        for key, (original, kind, composed) in handles.items()
    }
    self._index = element_index.ElementIndex(self._mj_model, handle_names)
    self._mjx_model = mjx.put_model(self._mj_model)
    self._data0 = mjx.make_data(self._mjx_model)

    physics = self._make_physics(
        self._mjx_model, self._data0, task.initial_task_state()
    )
    result = self._call_host_hooks('after_compile', physics, self._random_state)
    if isinstance(result, physics_lib.Physics):
      self._mjx_model = result.model

    physics_timestep = float(self._mj_model.opt.timestep)
    if n_sub_steps is not None:
      logging.warning('n_sub_steps is deprecated: set the task timesteps.')
      self._n_sub_steps = int(n_sub_steps)
    else:
      self._n_sub_steps = task.physics_steps_per_control_step
    self._control_timestep = physics_timestep * self._n_sub_steps
    self._step_limit = (
        math.inf
        if math.isinf(time_limit)
        else max(1, math.ceil(time_limit / self._control_timestep - 1e-9))
    )

    self._updater = updater_lib.Updater(
        task.observables,
        self._n_sub_steps,
        strip_singleton_buffer_dim=strip_singleton_obs_buffer_dim,
        pad_with_initial_value=(
            delayed_observation_padding == ObservationPadding.INITIAL_VALUE
        ),
        groups=observation_groups,
        physics=self._host_physics(),
    )

  # -- properties ----------------------------------------------------------

  @property
  def task(self):
    return self._task

  @property
  def mj_model(self) -> mujoco.MjModel:
    """The compiled host model."""
    return self._mj_model

  @property
  def mjx_model(self) -> mjx.Model:
    """The device model shared by every world."""
    return self._mjx_model

  @property
  def spec(self) -> mujoco.MjSpec:
    """The composed spec that was compiled (a copy; edits have no effect)."""
    return self._spec

  @property
  def n_sub_steps(self) -> int:
    return self._n_sub_steps

  def control_timestep(self) -> float:
    return self._control_timestep

  @property
  def time_limit(self) -> float:
    return self._time_limit

  @property
  def random_state(self):
    return self._random_state

  @property
  def observation_updater(self):
    return self._updater

  def add_extra_hook(self, hook_name: str, hook: Callable):
    """Registers a hook run after the task's and entities' hooks.

    Call it before tracing `reset`/`step` (jitted functions already traced
    keep their old hooks). Signatures follow the task's, with a key in place
    of the random state; device hooks must return the Physics.
    """
    if hook_name not in HOOK_NAMES:
      raise ValueError(
          f'{hook_name!r} is not a valid hook name. Valid hook '
          f'names: {HOOK_NAMES}'
      )
    if not callable(hook):
      raise ValueError(f'{hook!r} is not a callable.')
    self._extra_hooks[hook_name].append(hook)

  # -- specs ---------------------------------------------------------------

  def action_spec(self):
    return self._task.action_spec(self._host_physics())

  def observation_spec(self):
    return self._updater.observation_spec()

  def reward_spec(self):
    spec = self._task.get_reward_spec()
    return (
        spec
        if spec is not None
        else specs.Array(shape=(), dtype=np.float32, name='reward')
    )

  def discount_spec(self):
    spec = self._task.get_discount_spec()
    return (
        spec
        if spec is not None
        else specs.BoundedArray(
            shape=(),
            dtype=np.float32,
            minimum=0.0,
            maximum=1.0,
            name='discount',
        )
    )

  # -- physics -------------------------------------------------------------

  def _make_physics(
      self, model, data, task_state, persistent=None, initialization_failed=None
  ):
    return physics_lib.Physics(
        model=model,
        data=data,
        task_state=task_state,
        index=self._index,
        persistent={} if persistent is None else persistent,
        initialization_failed=initialization_failed,
    )

  def _host_physics(self):
    return self._make_physics(
        self._mjx_model, self._data0, self._task.initial_task_state()
    )

  def physics(self, state: State) -> physics_lib.Physics:
    """The `Physics` of a state (a batch of them if the state is batched)."""
    model = (
        self._mjx_model.replace(**state.model_fields)
        if state.model_fields
        else self._mjx_model
    )
    return self._make_physics(
        model, state.data, state.task_state, state.persistent
    )

  # -- hooks ---------------------------------------------------------------

  def _call_host_hooks(self, name, *args):
    """Runs a build-time hook on the task, entities and extra hooks."""
    result = None
    participants = [self._task] + list(self._task.root_entity.iter_entities())
    for owner in participants:
      out = getattr(owner, name)(*args)
      if name == 'after_compile' and isinstance(out, physics_lib.Physics):
        args = (out,) + args[1:]
        result = out
    for hook in self._extra_hooks[name]:
      out = hook(*args)
      if name == 'after_compile' and isinstance(out, physics_lib.Physics):
        args = (out,) + args[1:]
        result = out
    return result

  def _device_hooks(self, name):
    """The (owner, callable, takes_action) list for a device hook, in order."""
    from mjx_composer import entity as entity_lib  # pylint: disable=g-import-not-at-top
    from mjx_composer import task as task_lib  # pylint: disable=g-import-not-at-top

    hooks = []
    if _is_overridden(self._task, name, task_lib.Task) or name == 'before_step':
      hooks.append(
          (
              type(self._task).__name__,
              getattr(self._task, name),
              name in _ACTION_HOOKS,
          )
      )
    for entity in self._task.root_entity.iter_entities():
      if _is_overridden(entity, name, entity_lib.Entity):
        hooks.append(
            (
                f'{type(entity).__name__}({entity.name!r})',
                getattr(entity, name),
                False,
            )
        )
    for hook in self._extra_hooks[name]:
      hooks.append(
          (getattr(hook, '__name__', repr(hook)), hook, name in _ACTION_HOOKS)
      )
    return hooks

  def _run_hooks(self, name, physics, key, action=None):
    """Runs a device hook for the task, then entities, then extra hooks."""
    for i, (owner, hook, takes_action) in enumerate(self._device_hooks(name)):
      hook_key = jax.random.fold_in(key, i)
      args = (
          (physics, action, hook_key) if takes_action else (physics, hook_key)
      )
      result = hook(*args)
      if not isinstance(result, physics_lib.Physics):
        raise TypeError(
            f'{owner}.{name} returned {type(result).__name__}: device hooks '
            'are pure and must return the (new) Physics.'
        )
      physics = result
    return physics

  def _per_world_fields(
      self, before: mjx.Model, after: mjx.Model, allowed, hook_names
  ):
    """Model fields that hooks changed; raises if any is not allowed."""
    changed = [
        f.name
        for f in dataclasses.fields(mjx.Model)
        if getattr(after, f.name) is not getattr(before, f.name)
    ]
    if allowed is not None:
      bad = sorted(set(changed) - set(allowed))
      if bad:
        raise ValueError(
            f'The {hook_names} hooks wrote model fields {bad} that are not '
            'per-world. Declare them with Environment(..., '
            f'per_world_model_fields={tuple(bad)!r}), or write them in '
            'initialize_episode.'
        )
    return changed

  # -- reset ---------------------------------------------------------------

  def reset(self, key) -> State:
    """Starts an episode for one world. Pure; jit and vmap it."""
    key = _as_key(key)
    return self._reset(key)

  def _reset(self, key, previous: State | None = None) -> State:
    """A new episode; `previous` is the world's last state on auto-reset."""
    init_key, obs_key, next_key = jax.random.split(key, 3)
    base = self._mjx_model
    start_model, persistent = base, {}
    if previous is not None:
      if previous.model_fields:
        start_model = base.replace(**previous.model_fields)
      persistent = previous.persistent
    has_init_hooks = bool(self._device_hooks('initialize_episode'))
    not_failed = jnp.zeros((), bool)

    def attempt(attempt_key, persistent):
      physics = self._make_physics(
          start_model,
          self._data0,
          self._task.initial_task_state(),
          persistent,
          not_failed,
      )
      if has_init_hooks:
        physics = _forward_without_actuation(physics)
        physics = self._run_hooks('initialize_episode', physics, attempt_key)
      return physics

    physics = attempt(init_key, persistent)
    changed = self._per_world_fields(base, physics.model, None, None)
    model_fields = sorted(set(changed) | set(self._declared_model_fields))
    failures = physics.initialization_failed.astype(jnp.int32)
    if has_init_hooks and self._max_reset_attempts > 1:
      # Resample failed initializations with fresh keys. Under vmap the loop
      # runs while any world still fails; finished worlds keep their result.
      def carry_of(physics):
        return (
            physics.data,
            physics.task_state,
            {f: getattr(physics.model, f) for f in model_fields},
            physics.persistent,
            physics.initialization_failed,
        )

      def retry(carry):
        # Every attempt starts from the same model and persistent entries:
        # a failed attempt leaves no trace (a Sequence does not move on, a
        # once-per-world draw is not marked done), only a fresh key.
        attempts, failures, _ = carry
        physics = attempt(jax.random.fold_in(init_key, attempts), persistent)
        return (
            attempts + 1,
            failures + physics.initialization_failed.astype(jnp.int32),
            carry_of(physics),
        )

      def should_retry(carry):
        attempts, _, (*_, failed) = carry
        return jnp.logical_and(failed, attempts < self._max_reset_attempts)

      _, failures, (data, task_state, fields, persistent_out, failed) = (
          jax.lax.while_loop(
              should_retry,
              retry,
              (jnp.ones((), jnp.int32), failures, carry_of(physics)),
          )
      )
      physics = self._make_physics(
          base.replace(**fields), data, task_state, persistent_out, failed
      )
    physics = _forward_without_actuation(physics)
    obs_state = self._updater.reset(physics, obs_key)
    observation = self._updater.get_observation(obs_state)
    diverged = _diverged(physics.data)
    metrics = {
        'diverged': diverged.astype(jnp.float32),
        'episode_return': jnp.zeros((), jnp.float32),
        'episode_length': jnp.zeros((), jnp.int32),
        'init_failures': failures.astype(jnp.float32),
        'init_failed': physics.initialization_failed.astype(jnp.float32),
    }
    metrics.update(self._task_metrics(physics))
    return State(
        data=physics.data,
        task_state=physics.task_state,
        model_fields={f: getattr(physics.model, f) for f in model_fields},
        obs_state=obs_state,
        observation=observation,
        reward=jnp.zeros(self.reward_spec().shape, jnp.float32),
        discount=jnp.ones(self.discount_spec().shape, jnp.float32),
        step_type=jnp.asarray(StepType.FIRST, jnp.int32),
        terminated=jnp.zeros((), bool),
        truncated=jnp.zeros((), bool),
        final_observation=observation,
        metrics=metrics,
        key=next_key,
        steps=jnp.zeros((), jnp.int32),
        episode_return=jnp.zeros((), jnp.float32),
        persistent=physics.persistent,
    )

  def _task_metrics(self, physics):
    return {
        name: jnp.asarray(value, jnp.float32)
        for name, value in self._task.get_metrics(physics).items()
    }

  # -- step ----------------------------------------------------------------

  def step(self, state: State, action) -> State:
    """Advances one world by one control step. Pure; jit and vmap it."""
    action = self._check_action(action)
    if self._auto_reset == 'next_step':
      reset_key, step_key = jax.random.split(state.key)
      stepped = self._step(state.replace(key=step_key), action)
      return _select_reset(
          state.last(), self._reset, (reset_key, state), stepped
      )

    def restart(stepped):
      restarted = self._reset(stepped.key, previous=stepped)
      return restarted.replace(
          step_type=stepped.step_type,
          reward=stepped.reward,
          discount=stepped.discount,
          terminated=stepped.terminated,
          truncated=stepped.truncated,
          final_observation=stepped.final_observation,
          metrics=stepped.metrics,
      )

    stepped = self._step(state, action)
    return _select_reset(stepped.last(), restart, (stepped,), stepped)

  def _check_action(self, action):
    action = jnp.asarray(action)
    spec = self.action_spec()
    if action.shape != spec.shape:
      raise ValueError(
          f'Expected an action of shape {spec.shape} for one world (the '
          f"task's action_spec), got {action.shape}. To step a batch, "
          'jax.vmap(env.step) over states and actions.'
      )
    if not jnp.issubdtype(action.dtype, jnp.floating):
      action = action.astype(jnp.float32)
    return action

  def _step(self, state: State, action) -> State:
    keys = jax.random.split(state.key, 5)
    before_key, substep_key, after_key, obs_key, next_key = keys
    physics = self.physics(state)
    allowed = tuple(state.model_fields)
    base_model = physics.model
    physics = self._run_hooks('before_step', physics, before_key, action)
    n = self._n_sub_steps

    def substep(physics, i):
      sub_key = jax.random.fold_in(substep_key, i)
      physics = self._run_hooks(
          'before_substep', physics, jax.random.fold_in(sub_key, 0), action
      )
      physics = physics.step()
      physics = self._run_hooks(
          'after_substep', physics, jax.random.fold_in(sub_key, 1)
      )
      self._per_world_fields(
          base_model, physics.model, allowed, 'before_substep/after_substep'
      )
      _check_persistent(
          state.persistent, physics.persistent, 'before_substep/after_substep'
      )
      return physics, jax.random.fold_in(sub_key, 2)

    def scanned_substep(carry, i):
      data, task_state, model_fields, persistent, obs_state = carry
      model = base_model.replace(**model_fields) if model_fields else base_model
      physics, update_key = substep(
          self._make_physics(model, data, task_state, persistent), i
      )
      # Sub-steps 1..n-1 update the observations inside the scan; the updater
      # skips, at trace time, every observable that cannot be sampled there.
      obs_state = self._updater.update(
          obs_state, physics, update_key, i + 1, substep_bounds=(1, n - 1)
      )
      model_fields = {f: getattr(physics.model, f) for f in model_fields}
      return (
          physics.data,
          physics.task_state,
          model_fields,
          physics.persistent,
          obs_state,
      ), None

    self._per_world_fields(base_model, physics.model, allowed, 'before_step')
    _check_persistent(state.persistent, physics.persistent, 'before_step')
    obs_state = state.obs_state
    if n > 1:
      carry = (
          physics.data,
          physics.task_state,
          {f: getattr(physics.model, f) for f in allowed},
          physics.persistent,
          obs_state,
      )
      (data, task_state, model_fields, persistent, obs_state), _ = jax.lax.scan(
          scanned_substep, carry, jnp.arange(n - 1, dtype=jnp.int32)
      )
      model = base_model.replace(**model_fields) if model_fields else base_model
      physics = self._make_physics(model, data, task_state, persistent)
    # The last sub-step runs outside the scan: its observation update comes
    # after the after_step hooks (composer's order) and needs no branch.
    physics, _ = substep(physics, n - 1)
    physics = self._run_hooks('after_step', physics, after_key)
    self._per_world_fields(base_model, physics.model, allowed, 'after_step')
    _check_persistent(state.persistent, physics.persistent, 'after_step')
    obs_state = self._updater.update(obs_state, physics, obs_key, n)
    observation = self._updater.get_observation(obs_state)

    diverged = _diverged(physics.data)
    reward = jnp.asarray(self._task.get_reward(physics), jnp.float32)
    discount = jnp.asarray(self._task.get_discount(physics), jnp.float32)
    reward = jnp.where(diverged, jnp.zeros_like(reward), reward)
    discount = jnp.where(diverged, jnp.zeros_like(discount), discount)
    steps = state.steps + 1
    terminated = jnp.logical_or(
        jnp.asarray(self._task.should_terminate_episode(physics), bool),
        diverged,
    )
    truncated = jnp.logical_and(
        jnp.logical_not(terminated), steps >= self._step_limit
    )
    last = jnp.logical_or(terminated, truncated)
    episode_return = state.episode_return + jnp.sum(reward)
    metrics = {
        'diverged': diverged.astype(jnp.float32),
        'episode_return': episode_return,
        'episode_length': steps,
        'init_failures': state.metrics['init_failures'],
        'init_failed': state.metrics['init_failed'],
    }
    # A diverged world's task metrics are NaN-laden: report zeros instead.
    metrics.update(
        {
            k: jnp.where(diverged, 0.0, v)
            for k, v in self._task_metrics(physics).items()
        }
    )
    return State(
        data=physics.data,
        task_state=physics.task_state,
        model_fields={f: getattr(physics.model, f) for f in allowed},
        obs_state=obs_state,
        observation=observation,
        reward=reward,
        discount=discount,
        step_type=jnp.where(last, StepType.LAST, StepType.MID).astype(
            jnp.int32
        ),
        terminated=terminated,
        truncated=truncated,
        final_observation=observation,
        metrics=metrics,
        key=next_key,
        steps=steps,
        episode_return=episode_return,
        persistent=physics.persistent,
    )


def _check_persistent(before, after, hook_names):
  """Step hooks may update persistent entries but not add or reshape them."""
  shapes = lambda tree: jax.tree.map(
      lambda x: (jnp.shape(x), jnp.result_type(x)), tree
  )
  if jax.tree.structure(before) != jax.tree.structure(after) or shapes(
      before
  ) != shapes(after):
    raise ValueError(
        f'The {hook_names} hooks added, removed or reshaped persistent '
        f'entries (before: {shapes(before)}, after: {shapes(after)}). Create '
        'every persistent entry in initialize_episode, with its final shape '
        'and dtype; step hooks may only update it.'
    )


def _forward_without_actuation(physics):
  """`mj_forward` with actuation disabled, as composer's reset context does."""
  opt = physics.model.opt
  model = physics.model.replace(
      opt=opt.replace(disableflags=opt.disableflags | mjx.DisableBit.ACTUATION)
  )
  data = mjx.forward(model, physics.data)
  return physics.replace(data=data)


def _diverged(data) -> jax.Array:
  fields = [data.qpos, data.qvel, data.qacc, data.act]
  return jnp.logical_not(
      jnp.all(jnp.stack([jnp.all(jnp.isfinite(f)) for f in fields]))
  )


def _as_key(key):
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
