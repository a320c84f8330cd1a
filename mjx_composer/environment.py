"""`Environment`: a composed task compiled once, with pure `reset` and `step`.

    env = composer.Environment(task, time_limit=10.)
    state = jax.jit(env.reset)(key)                       # one world
    states = jax.jit(jax.vmap(env.reset))(keys)           # a batch
    states = jax.jit(jax.vmap(env.step))(states, actions)

Construction (host, once, `runtime.build`): runs the build-time hooks
(`initialize_episode_mjcf`, then `after_compile`), composes the entity tree
into one `MjSpec`, compiles it, puts it on the device, resolves every element
to static indices, and plans the observation updater.

`reset(key)` and `step(state, action)` are pure functions of one world. They
follow composer's order of events:

* reset: the model's default data (`qpos0`, zero velocities and time),
  kinematics (composer: a whole forward pass), the task's then each entity's
  `initialize_episode`, a forward pass with actuation disabled, and the
  first observation (timestamp 0).
* step: hooks scheduled with `Physics.schedule_before_step`, `before_step`
  (the task gets the action; its default writes `ctrl`), then `n_sub_steps`
  times (`before_substep`, `mjx.step`, `after_substep`, observation update)
  except that the last update comes after the `after_step` hooks, then
  reward, discount and termination (`episode.EpisodeRules`).

Hooks run in composer's order (`hooks.EnvironmentHooks`); episode ends and
auto-reset follow `episode` and `auto_reset`; what a world carries is
`state.State`.

Initialization failures: an `initialize_episode` hook that cannot set up the
episode (e.g. `PropPlacer` finding no collision-free pose) marks it with
`physics.fail_initialization()`. The environment then reruns every
`initialize_episode` hook with a fresh key, up to `max_reset_attempts`
attempts in all, counts failed attempts in `metrics['init_failures']`, and
sets `metrics['init_failed']` when the last attempt failed too (composer
would raise `EpisodeInitializationError`; nothing raises inside jit). Such a
world runs none of its attempts: it keeps what its reset started from, and
its first step ends the episode (reward 0, discount 0).

Keys: `reset(key)` derives every random draw of the episode, and of the
episodes that auto-reset after it, from `key` alone: the same key gives the
same trajectory, run to run.

Execution: `ExecutionOptions` (`Environment(task, options=...)`) chooses how
the worlds run (auto-reset mode, physics implementation, fused restarts,
...) without changing what they compute; e.g.
`ExecutionOptions(impl='warp')` runs the physics on MuJoCo Warp through MJX
instead of MJX's JAX implementation (`backend` says what runs where and what
Warp refuses at build).
"""

from __future__ import annotations

import inspect
from typing import Callable

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np

from mjx_composer import physics as physics_lib
from mjx_composer import task as task_lib
from mjx_composer.observation import updater as updater_lib
from mjx_composer.runtime import arguments
from mjx_composer.runtime import build as build_lib
from mjx_composer.runtime import control_flow
from mjx_composer.runtime import hooks as hooks_lib
from mjx_composer.runtime import options as options_lib
from mjx_composer.runtime import reset_forward as reset_forward_lib
from mjx_composer.runtime import state as state_lib

COMPOSER_OPTIONS = arguments.COMPOSER_OPTIONS
ExecutionOptions = options_lib.ExecutionOptions
HOOK_NAMES = hooks_lib.HOOK_NAMES
ObservationPadding = updater_lib.ObservationPadding
State = state_lib.State
StepType = state_lib.StepType


class EpisodeInitializationError(RuntimeError):
  """Raised by a task on the host when it fails to initialize an episode.

  Inside the jitted `reset` nothing can raise: initializers record failure in
  `State.metrics['init_failures']` instead (see `initializers`).
  """


class Environment:
  """A composed task, compiled once, with pure single-world reset and step.

  The arguments up to `legacy_step` are composer's, in composer's order;
  how the worlds run is `options`.

  Args:
    task: the `Task`.
    time_limit: episode length in seconds (truncation); `inf` for none.
    random_state: an int seed or `numpy.random.RandomState` for the
      build-time host hooks (`initialize_episode_mjcf`, `after_compile`).
    n_sub_steps: overrides `task.physics_steps_per_control_step` (deprecated
      in composer; here the observation updater follows it too).
    raise_exception_on_physics_error: composer's; see below.
    strip_singleton_obs_buffer_dim: drop the buffer axis of size-1 buffers.
    max_reset_attempts: how many times `reset` may run the
      `initialize_episode` hooks when they report a failed initialization
      (`Physics.fail_initialization`), each time with a fresh key.
    recompile_mjcf_every_episode: composer's; see below.
    fixed_initial_state: composer's: every episode of a world starts as its
      first did. `reset(key)` starts a world from `key` as always; its
      auto-resets then reuse that key (kept in the world's persistent
      entries), so the initial state and every random draw of the episode
      (noise, hooks) repeat, and identical actions give identical episodes.
      Every initialization attempt uses the same key, so a failure that
      only randomness causes repeats (composer's behaviour).
      `HostEnvironment` resets with its first key every time.
    delayed_observation_padding: `ObservationPadding.ZERO` or
      `INITIAL_VALUE`.
    legacy_step: composer's; see below.
    options: the `ExecutionOptions` (None: the defaults).
    **deprecated: the execution options as keyword arguments (`auto_reset`,
      `impl`, ...: `ExecutionOptions`' fields), and `observation_groups`
      (override `Task.observation_groups()` instead). They still work, with
      a `DeprecationWarning`; they cannot be combined with `options`.

  `raise_exception_on_physics_error`, `recompile_mjcf_every_episode` and
  `legacy_step` are accepted so that composer code ports. Each may be left
  out or set to the one value this batched environment implements, False;
  True raises a ValueError that says what happens instead
  (`COMPOSER_OPTIONS`).

  Raises:
    TypeError: for an unknown keyword argument, or a deprecated one together
      with `options`.
    ValueError, NotImplementedError, ImportError: for arguments, models or
      per-world fields the chosen implementation cannot run (`backend`).
  """

  def __init__(
      self,
      task,
      time_limit=float('inf'),
      random_state=None,
      n_sub_steps=None,
      raise_exception_on_physics_error=None,
      strip_singleton_obs_buffer_dim=False,
      max_reset_attempts=1,
      recompile_mjcf_every_episode=None,
      fixed_initial_state=None,
      delayed_observation_padding=ObservationPadding.ZERO,
      legacy_step=None,
      *,
      options: ExecutionOptions | None = None,
      **deprecated,
  ):
    options, observation_groups = arguments.options_from(
        options, deprecated, _ARGUMENTS
    )
    arguments.check_composer_options(
        raise_exception_on_physics_error=raise_exception_on_physics_error,
        recompile_mjcf_every_episode=recompile_mjcf_every_episode,
        fixed_initial_state=fixed_initial_state,
        legacy_step=legacy_step,
    )
    arguments.check_arguments(
        delayed_observation_padding, max_reset_attempts, time_limit
    )
    self._requested_options = options
    self._fixed_initial_state = bool(fixed_initial_state)
    # Jitted data completions of `physics`, by the state's batch rank.
    self._complete_data = {}
    self._task = task
    self._time_limit = time_limit
    if not isinstance(random_state, np.random.RandomState):
      random_state = np.random.RandomState(random_state)
    self._random_state = random_state
    self._hooks = hooks_lib.EnvironmentHooks(task)
    built = build_lib.build(
        task,
        self._hooks,
        self._random_state,
        options,
        build_lib.Arguments(
            time_limit=time_limit,
            n_sub_steps=n_sub_steps,
            strip_singleton_obs_buffer_dim=strip_singleton_obs_buffer_dim,
            delayed_observation_padding=delayed_observation_padding,
            observation_groups=observation_groups,
            max_reset_attempts=max_reset_attempts,
            fixed_initial_state=self._fixed_initial_state,
        ),
    )
    self._spec = built.spec
    self._mj_model = built.mj_model
    self._backend = built.backend
    self._options = built.options
    self._control_timestep = built.control_timestep
    self._episode = built.episode
    self._updater = built.updater
    self._transitions = built.transitions
    self._advance = built.step

  # -- properties ----------------------------------------------------------

  @property
  def task(self):
    return self._task

  @property
  def options(self) -> ExecutionOptions:
    """The `ExecutionOptions` as resolved for this environment's device.

    `impl`, `share_reset_forward` and `branches` are the ones chosen (never
    None or 'auto'); `naconmax` and `njmax` are None where they are ignored
    (on 'jax').
    """
    return self._options

  @property
  def fixed_initial_state(self) -> bool:
    """Whether every episode of a world starts as its first did."""
    return self._fixed_initial_state

  @property
  def mj_model(self) -> mujoco.MjModel:
    """The compiled host model."""
    return self._mj_model

  @property
  def impl(self) -> str:
    """The MJX implementation running the physics: 'jax' or 'warp'."""
    return self._backend.name

  @property
  def mjx_model(self) -> mjx.Model:
    """The device model shared by every world."""
    return self._transitions.initial.model

  @property
  def spec(self) -> mujoco.MjSpec:
    """The composed spec that was compiled (a copy; edits have no effect)."""
    return self._spec

  @property
  def n_sub_steps(self) -> int:
    return self._transitions.n_sub_steps

  def control_timestep(self) -> float:
    return self._control_timestep

  @property
  def time_limit(self) -> float:
    return self._time_limit

  @property
  def step_limit(self) -> float:
    """Control steps per episode before truncation (`inf` for none)."""
    return self._episode.step_limit

  @property
  def auto_reset(self) -> str:
    """'next_step' or 'same_step' (`ExecutionOptions.auto_reset`)."""
    return self._options.auto_reset

  @property
  def share_reset_forward(self) -> bool:
    """Whether restarts run as an extra iteration of the sub-step loop.

    As resolved from `ExecutionOptions.share_reset_forward` (None: the
    device's default, `Backend.default_share_reset_forward`).
    """
    return self._options.share_reset_forward

  @property
  def auto_reset_batch(self) -> int | str | None:
    """How many ended worlds reset together under `jax.vmap`, as resolved
    for the device (`ExecutionOptions.auto_reset_batch`): K, 'auto' (an
    eighth of a batch of 1,024 worlds or more) or None (the whole batch)."""
    return self._options.auto_reset_batch

  @property
  def branches(self) -> str:
    """How the step skips what runs at some steps only: 'loop' or 'cond', as
    resolved for the device (`ExecutionOptions.branches`)."""
    return self._options.branches

  @property
  def reset_forward_stage(self) -> str:
    """The stage of the forward pass a reset runs: 'none', 'position',
    'velocity' or 'full' (`ExecutionOptions.reset_forward`,
    `mjx_composer.runtime.reset_forward`). Found by tracing the readers of a
    reset's state on first use."""
    return self._transitions.reset_forward.stage

  @property
  def sensors_once_per_step(self) -> bool:
    """Whether `step` computes the sensors once per control step instead of
    at every sub-step (`ExecutionOptions.substep_sensors`,
    `mjx_composer.runtime.substep_sensors`). Found by tracing what runs
    between the sub-steps on first use."""
    return self._transitions.sensors_once_per_step

  @property
  def step_forward_stage(self) -> str:
    """The stage of the forward pass a control step runs after its last
    physics step: 'none', 'position' or 'velocity' (what its readers read
    of them, as composer's `Physics.step` leaves them current), or 'full'
    where composer's physics is dirty after the step and its readers read
    the acceleration stage (`ExecutionOptions.dirty_forward`,
    `mjx_composer.runtime.dirty_forward`). Found by tracing the step's
    hooks and readers on first use."""
    return self._transitions.step_forward.stage

  @property
  def carried_stage(self) -> str | None:
    """The stage of the forward pass ('position' or 'velocity') that each
    physics step of `step` computes at its end and the next starts from,
    or None where the control step recomputes its end-of-step stage after
    its last physics step (`ExecutionOptions.carry_stage`,
    `mjx_composer.runtime.carried_stage`). Found by tracing the step's
    hooks on first use."""
    return self._transitions.carried_stage

  @property
  def stored_restart(self) -> bool:
    """Whether an auto-reset restores a copy of the world's first state
    instead of running the reset (`ExecutionOptions.stored_restart`,
    `mjx_composer.runtime.stored_restart`). Found by tracing the reset on
    first use."""
    return self._transitions.stored_restart is not None

  @property
  def random_state(self):
    return self._random_state

  @property
  def observation_updater(self):
    return self._updater

  @property
  def per_world_model_fields(self) -> dict[str, tuple[str, ...]]:
    """`{model field: the hooks that made it per-world}`.

    From abstract traces of the `initialize_episode` and step hooks (run
    on first use: they read shapes only); fields declared with
    `ExecutionOptions(per_world_model_fields=...)` are listed as declared.
    """
    return self._transitions.per_world_model_fields()

  def add_extra_hook(self, hook_name: str, hook: Callable):
    """Registers a hook run after the task's and entities' hooks.

    Call it before tracing `reset`/`step` (jitted functions already traced
    keep their old hooks). Signatures follow the task's, with a key in place
    of the random state; device hooks must return the Physics.
    """
    self._hooks.add_extra_hook(hook_name, hook)

  # -- specs ---------------------------------------------------------------

  def action_spec(self):
    return self._task.action_spec(self._transitions.initial)

  def observation_spec(self):
    return self._updater.observation_spec()

  def reward_spec(self):
    return build_lib.reward_spec(self._task)

  def discount_spec(self):
    return build_lib.discount_spec(self._task)

  # -- physics -------------------------------------------------------------

  def initial_physics(self) -> physics_lib.Physics:
    """One world's `Physics` before any hook: the compiled model, `qpos0`."""
    return self._transitions.initial

  def physics(self, state: State) -> physics_lib.Physics:
    """The `Physics` of a state (a batch of them if the state is batched:
    its bindings then read and write every world, behind the batch axes).

    Every derived quantity of its data is the forward pass's: where the
    state comes from a reset whose stage of the forward pass skipped some
    (`reset_forward_stage`; FIRST states, and LAST ones under same-step
    auto-reset), the rest is computed here, in a jitted program, so what
    you read is what composer's reset leaves. `state.data` itself is not
    completed.
    """
    physics = self._transitions.physics(state)
    if self.reset_forward_stage == 'full':
      return physics
    batch_ndim = jnp.ndim(state.step_type)
    if batch_ndim not in self._complete_data:
      complete = self._complete_one_world
      for _ in range(batch_ndim):
        complete = jax.vmap(complete)
      self._complete_data[batch_ndim] = jax.jit(complete)
    return physics.replace(data=self._complete_data[batch_ndim](state))

  def _complete_one_world(self, state: State):
    """One world's data, its forward pass completed if it is a reset's."""
    physics = self._transitions.physics(state)
    reset = state.first()
    if self._options.auto_reset == 'same_step':
      reset = jnp.logical_or(reset, state.last())
    full = reset_forward_lib.forward('full', physics.model, physics.data)
    return control_flow.tree_select(reset, full, physics.data)

  # -- reset and step ------------------------------------------------------

  def reset(self, key) -> State:
    """Starts an episode for one world. Pure; jit and vmap it."""
    return self._transitions.begin(arguments.as_key(key))

  def step(self, state: State, action) -> State:
    """Advances one world by one control step. Pure; jit and vmap it.

    Where the world's episode ended, the step also starts the next one, as
    `ExecutionOptions.auto_reset` says (`runtime.auto_reset`: the program
    was chosen when the environment was built). `state` comes from `reset`
    or `step`: its physics starts from the stage of the forward pass its
    data holds (`carried_stage`), so a state whose positions you set by
    hand steps from them once its data is forwarded
    (`state.replace(data=env.physics(state).forward().data)`), as
    composer's physics after such a write needs `physics.forward()`.
    """
    arguments.check_one_world(state)
    return self._advance(state, self._check_action(action))

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


# composer's `Environment` options that only False (or leaving them out) can
# mean here, and what happens instead of True.


# `Environment`'s arguments as its signature names them (composer's, in
# composer's order, and `options`), for error messages.
_ARGUMENTS = tuple(
    name
    for name, parameter in inspect.signature(Environment).parameters.items()
    if parameter.kind != inspect.Parameter.VAR_KEYWORD
)


def check_environment(
    value, owner, build='composer.Environment(task)', needs=''
):
  """Refuses anything but an `Environment` handed to a wrapper (`owner`).

  The message names what to pass: a wrapper's `.environment`, or, for a
  `Task`, `owner(<build>)`; `needs` says how the environment must be built
  (e.g. " built with auto_reset='same_step'").
  """
  if isinstance(value, Environment):
    return
  name = type(value).__name__
  if isinstance(getattr(value, 'environment', None), Environment):
    got = (
        f'a {name}, which wraps one: pass its `.environment`, '
        f'{owner}({name}.environment)'
    )
  elif isinstance(value, task_lib.Task):
    got = f'a Task: build its environment first, {owner}({build})'
  else:
    got = f'{name} {value!r:.80}'
  raise TypeError(
      f'{owner}: `environment` must be an mjx_composer.Environment{needs}, '
      f'got {got}.'
  )
