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
auto-reset follow `episode`; what a world carries is `state.State`.

Initialization failures: an `initialize_episode` hook that cannot set up the
episode (e.g. `PropPlacer` finding no collision-free pose) marks it with
`physics.fail_initialization()`. The environment then reruns every
`initialize_episode` hook with a fresh key, up to `max_reset_attempts`
attempts in all, counts failed attempts in `metrics['init_failures']`, and
sets `metrics['init_failed']` when the last attempt failed too (composer
would raise `EpisodeInitializationError`; nothing raises inside jit).

Keys: `reset(key)` derives every random draw of the episode, and of the
episodes that auto-reset after it, from `key` alone: the same key gives the
same trajectory, run to run.

Physics backend: `Environment(impl='warp')` runs the physics on MuJoCo Warp
through MJX instead of MJX's JAX implementation; `backend` says what runs
where and what Warp refuses at build.
"""

from __future__ import annotations

import logging
from typing import Callable

from dm_env import specs
import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np

from mjx_composer.platform import backend
from mjx_composer.model import element_index
from mjx_composer.runtime import episode as episode_lib
from mjx_composer.runtime import hooks as hooks_lib
from mjx_composer.model import model_checks
from mjx_composer import physics as physics_lib
from mjx_composer.runtime import reset_forward as reset_forward_lib
from mjx_composer.runtime import state as state_lib
from mjx_composer.runtime import transitions as transitions_lib
from mjx_composer.observation import updater as updater_lib

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

  Args:
    task: the `Task`.
    time_limit: episode length in seconds (truncation); `inf` for none.
    random_state: an int seed or `numpy.random.RandomState` for the
      build-time host hooks (`initialize_episode_mjcf`, `after_compile`).
    n_sub_steps: overrides `task.physics_steps_per_control_step` (deprecated
      in composer; here the observation updater follows it too).
    strip_singleton_obs_buffer_dim: drop the buffer axis of size-1 buffers.
    delayed_observation_padding: `ObservationPadding.ZERO` or `INITIAL_VALUE`.
    auto_reset: 'next_step' (composer) or 'same_step' (see `episode`).
    per_world_model_fields: model field names (e.g. 'geom_rgba', 'opt') that
      step hooks may write per world, in addition to those that
      `initialize_episode` hooks write (which are found automatically).
    observation_groups: groups for the observation updater (e.g.
      `{'policy': ..., 'critic': ...}`, see `observation.updater`); defaults
      to `task.observation_groups()`.
    max_reset_attempts: how many times `reset` may run the
      `initialize_episode` hooks when they report a failed initialization
      (`Physics.fail_initialization`), each time with a fresh key.
    share_reset_forward: reset worlds (an ended episode's restart with
      same-step auto-reset, a LAST state's reset with next-step) in one more
      iteration of the sub-step loop, so that the step program holds one
      copy of the forward pass (`Transitions.step_and_restart`,
      `Transitions.reset_or_step`).
      Measured (README): on one H100 (stop 28) reach's step program
      compiled in about half the time; on one H100 (stop 33) the walk
      task's first call took 12-20 s less and it ran at 0.962-0.965 of the
      separate restart's throughput. False runs the sub-steps as a
      `lax.scan` of `mjx.step` and the restart separately.
      Results are bit-identical either way. Default (None): True on a CPU
      with impl='jax', where runs are short and compiling dominates; False
      elsewhere (and with `auto_reset_batch`). impl='warp' refuses True
      (`backend`).
    auto_reset_batch: under `jax.vmap`, how many worlds' auto-resets are
      computed together. None (default): at a step in which any world's
      episode ends, the reset of the whole batch is computed and selected
      per world. An integer K: the worlds that end are gathered into
      batches of K, reset and scattered back (`episode.select_reset`), so
      a step in which a few of many worlds end pays for K resets, not for
      all: for tasks whose episodes end often (falls) on large batches.
      The results are the same to float rounding. Needs impl='jax' (None
      then resolves to 'jax') and refuses `share_reset_forward=True`,
      which runs the reset inside the sub-step loop.
    impl: which MJX implementation runs the physics: 'jax' (MJX's XLA
      implementation), 'warp' (MuJoCo Warp kernels through JAX's FFI, on a
      CUDA GPU or the CPU; `pip install 'mjx-composer[warp]'`), or None:
      'warp' on a CUDA GPU where MuJoCo Warp is installed (unless
      `share_reset_forward=True`), falling back to 'jax' with a logged
      warning when Warp refuses the environment; 'jax' everywhere else
      (`backend.default_impls`). On 'warp', a model feature or a per-world
      model field that MuJoCo Warp cannot run is refused here, with what to
      do (`backend`); building then traces `reset` once to find the
      per-world fields.
    naconmax: impl='warp' or None (ignored where None builds on 'jax'): the
      contacts MuJoCo Warp holds for all the worlds of one batch (one buffer
      shared by the batch). Default:
      `backend.DEFAULT_CONTACTS_PER_WORLD` (64) per world for
      `backend.DEFAULT_WORLDS` (8,192) worlds. Contacts beyond it are
      dropped and flagged in `backend.overflow(state.data)` and
      `metrics['overflow']`.
    njmax: impl='warp' or None (ignored where None builds on 'jax'):
      constraint rows per world. Default: `backend.default_njmax`, the
      larger of MuJoCo Warp's estimate and the rows MJX's JAX
      implementation allocates. Rows beyond it are dropped and flagged in
      `backend.overflow(state.data)` and `metrics['overflow']`.

    reset_forward: 'observed' (default): a reset runs only the stage of
      the forward pass whose results something reads before the next
      physics step (the observables sampled at reset, the start metrics,
      the next step's hooks before its physics; `mjx.step` recomputes the
      rest): 'none', 'position' (kinematics, centres of mass, position
      sensors, ...), 'velocity' (also velocities and velocity sensors) or
      'full' (`mjx_composer.runtime.reset_forward`; `reset_forward_stage` says
      which). The other derived fields of the reset's `State.data` (e.g.
      `contact`, `qacc`, `efc_*`) keep their values from before the
      forward pass (`physics(state)` completes them). Observations,
      rewards and trajectories are the same as with 'full', which computes
      everything as composer's reset does.
    substep_sensors: 'read' (default): where nothing between a control
      step's sub-steps reads the sensors (the sub-step hooks, the
      observables sampled at sub-steps), the sub-steps skip MuJoCo's sensor
      stage and the control step computes the sensors once, after its last
      sub-step, as its `mjx.step` would have; a fused restart
      (`share_reset_forward`) computes the sensors its reset's stage of the
      forward pass computes once, too (`mjx_composer.runtime.substep_sensors`;
      `sensors_once_per_step` says whether). 'all': every sub-step
      computes them, as `mjx.step` does.
    fixed_initial_state: composer's: every episode of a world starts as its
      first did. `reset(key)` starts a world from `key` as always; its
      auto-resets then reuse that key (kept in the world's persistent
      entries), so the initial state and every random draw of the episode
      (noise, hooks) repeat, and identical actions give identical episodes.
      Every initialization attempt uses the same key, so a failure that
      only randomness causes repeats (composer's behaviour).
      `HostEnvironment` resets with its first key every time.
    raise_exception_on_physics_error, recompile_mjcf_every_episode,
      legacy_step: composer's options, accepted so that composer code ports.
      Each may be left out or set to the one value this batched environment
      implements, False; True raises a ValueError that says what happens
      instead (`COMPOSER_OPTIONS`).

  Raises:
    ValueError, NotImplementedError, ImportError: for arguments, models or
      per-world fields the chosen implementation cannot run (`backend`).
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
      share_reset_forward=None,
      auto_reset_batch=None,
      impl=None,
      naconmax=None,
      njmax=None,
      reset_forward='observed',
      substep_sensors='read',
      raise_exception_on_physics_error=None,
      recompile_mjcf_every_episode=None,
      fixed_initial_state=None,
      legacy_step=None,
  ):
    _check_composer_options(
        raise_exception_on_physics_error=raise_exception_on_physics_error,
        recompile_mjcf_every_episode=recompile_mjcf_every_episode,
        fixed_initial_state=fixed_initial_state,
        legacy_step=legacy_step,
    )
    self._fixed_initial_state = bool(fixed_initial_state)
    if reset_forward not in ('observed', 'full'):
      raise ValueError(
          f"reset_forward must be 'observed' or 'full', got {reset_forward!r}."
      )
    self._reset_forward = reset_forward
    if substep_sensors not in ('read', 'all'):
      raise ValueError(
          f"substep_sensors must be 'read' or 'all', got {substep_sensors!r}."
      )
    self._substep_sensors = substep_sensors
    # Jitted data completions of `physics`, by the state's batch rank.
    self._complete_data = {}
    _check_auto_reset_batch(auto_reset_batch, share_reset_forward, impl)
    self._auto_reset_batch = auto_reset_batch
    _check_arguments(
        delayed_observation_padding,
        auto_reset,
        max_reset_attempts,
        time_limit,
        per_world_model_fields,
    )
    self._task = task
    self._time_limit = time_limit
    self._auto_reset = auto_reset
    if not isinstance(random_state, np.random.RandomState):
      random_state = np.random.RandomState(random_state)
    self._random_state = random_state
    self._hooks = hooks_lib.EnvironmentHooks(task)

    # Build-time hooks, then compile once.
    self._hooks.initialize_episode_mjcf(self._random_state)
    spec, handles = task.root_entity.compose()
    self._spec = spec
    try:
      self._mj_model = spec.compile()
    except Exception as e:
      raise ValueError(f'The composed model failed to compile: {e}') from e
    model_checks.check_compiled_model(self._mj_model)
    handle_names = {
        key: (original, kind, composed.name)
        for key, (original, kind, composed) in handles.items()
    }
    index = element_index.ElementIndex(self._mj_model, handle_names)
    # This process's first device: MJX's default, `jax.devices()[0]`, is
    # another process's on every host but the first.
    device = jax.local_devices()[0]
    # The fused restart and the chunked reset run on 'jax' only.
    candidates = backend.resolve_impl(
        impl,
        device,
        share_reset_forward=share_reset_forward or auto_reset_batch is not None,
    )
    random_state = self._random_state.get_state()
    for i, candidate in enumerate(candidates):
      try:
        self._build_physics(
            candidate,
            impl,
            device,
            index,
            time_limit=time_limit,
            n_sub_steps=n_sub_steps,
            strip_singleton_obs_buffer_dim=strip_singleton_obs_buffer_dim,
            delayed_observation_padding=delayed_observation_padding,
            per_world_model_fields=per_world_model_fields,
            observation_groups=observation_groups,
            max_reset_attempts=max_reset_attempts,
            share_reset_forward=share_reset_forward,
            naconmax=naconmax,
            njmax=njmax,
        )
        break
      except backend.WarpUnsupportedError as e:
        if i + 1 == len(candidates):
          raise
        # impl=None: the default tries Warp first on a CUDA GPU. Rebuild on
        # the next implementation, its build-time hooks drawing from the
        # same random state as if it had been the only one tried.
        logging.warning(
            'impl=None: MuJoCo Warp cannot run this environment, so it runs '
            'on impl=%r. %s',
            candidates[i + 1],
            e,
        )
        self._random_state.set_state(random_state)

  def _build_physics(
      self,
      impl,
      requested_impl,
      device,
      index,
      *,
      time_limit,
      n_sub_steps,
      strip_singleton_obs_buffer_dim,
      delayed_observation_padding,
      per_world_model_fields,
      observation_groups,
      max_reset_attempts,
      share_reset_forward,
      naconmax,
      njmax,
  ):
    """Puts the compiled model on `device` with `impl` and plans the steps.

    `requested_impl` is the `impl` argument of `__init__` (None for the
    default), which decides whether Warp's buffer sizes may be ignored.

    Runs the `after_compile` hooks on the device model, then builds the
    episode rules, the observation updater and the transitions.

    Raises:
      backend.WarpUnsupportedError: on 'warp', a model feature or per-world
        field that MuJoCo Warp cannot run.
    """
    task = self._task
    self._impl = impl
    backend.check_buffer_arguments(
        self._impl, naconmax, njmax, requested=requested_impl
    )
    backend.check_share_reset_forward(self._impl, share_reset_forward)
    backend.check_per_world_fields(
        self._impl,
        {
            name: ('Environment(per_world_model_fields=...)',)
            for name in per_world_model_fields
        },
    )
    if share_reset_forward is None:
      share_reset_forward = self._auto_reset_batch is None and (
          backend.default_share_reset_forward(self._impl, device)
      )
    self._share_reset_forward = bool(share_reset_forward)
    mjx_model, data0 = backend.put(
        self._mj_model, self._impl, device, naconmax=naconmax, njmax=njmax
    )
    compiled = self._hooks.after_compile(
        physics_lib.Physics(mjx_model, data0, index=index), self._random_state
    )
    physics = transitions_lib.initial_physics(
        task, compiled.model, data0, index
    )

    if n_sub_steps is not None:
      logging.warning('n_sub_steps is deprecated: set the task timesteps.')
      n_sub_steps = int(n_sub_steps)
    else:
      n_sub_steps = task.physics_steps_per_control_step
    self._control_timestep = float(self._mj_model.opt.timestep) * n_sub_steps
    self._episode = episode_lib.EpisodeRules(
        task,
        episode_lib.step_limit(time_limit, self._control_timestep),
        self.reward_spec().shape,
        self.discount_spec().shape,
    )
    if observation_groups is None:
      observation_groups = task.observation_groups()
    self._updater = updater_lib.Updater(
        task.observables,
        n_sub_steps,
        strip_singleton_buffer_dim=strip_singleton_obs_buffer_dim,
        pad_with_initial_value=(
            delayed_observation_padding == ObservationPadding.INITIAL_VALUE
        ),
        groups=observation_groups or None,
        physics=physics,
    )
    self._transitions = transitions_lib.Transitions(
        initial=physics,
        hooks=self._hooks,
        updater=self._updater,
        episode=self._episode,
        n_sub_steps=n_sub_steps,
        max_reset_attempts=int(max_reset_attempts),
        declared_model_fields=tuple(per_world_model_fields),
        reset_forward_mode=self._reset_forward,
        action_shape=tuple(task.action_spec(physics).shape),
        fixed_initial_state=self._fixed_initial_state,
        substep_sensors=self._substep_sensors,
    )
    if self._impl == 'warp':
      # Hooks make fields per-world when reset is traced: trace it now.
      jax.eval_shape(self.reset, jax.random.key(0))
      backend.check_per_world_fields(self._impl, self.per_world_model_fields)

  # -- properties ----------------------------------------------------------

  @property
  def task(self):
    return self._task

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
    return self._impl

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
    """'next_step' or 'same_step' (see `episode`)."""
    return self._auto_reset

  @property
  def share_reset_forward(self) -> bool:
    """Whether restarts run as an extra iteration of the sub-step loop.

    As resolved from the constructor's argument (None: the device's
    default, `backend.default_share_reset_forward`).
    """
    return self._share_reset_forward

  @property
  def auto_reset_batch(self) -> int | None:
    """How many ended worlds reset together under `jax.vmap` (None: all)."""
    return self._auto_reset_batch

  @property
  def reset_forward_stage(self) -> str:
    """The stage of the forward pass a reset runs: 'none', 'position',
    'velocity' or 'full' (`Environment(reset_forward=...)`,
    `mjx_composer.runtime.reset_forward`). Found by tracing the readers of a reset's
    state on first use."""
    return self._transitions.reset_forward.stage

  @property
  def sensors_once_per_step(self) -> bool:
    """Whether `step` computes the sensors once per control step instead of
    at every sub-step (`Environment(substep_sensors=...)`,
    `mjx_composer.runtime.substep_sensors`). Found by tracing what runs between the
    sub-steps on first use."""
    return self._transitions.sensors_once_per_step

  def _fuses_restart(self) -> bool:
    """Whether `step` runs the restart in the sub-step loop."""
    return self._share_reset_forward and self._transitions.can_fuse_restart()

  @property
  def random_state(self):
    return self._random_state

  @property
  def observation_updater(self):
    return self._updater

  @property
  def per_world_model_fields(self) -> dict[str, tuple[str, ...]]:
    """`{model field: the hooks that made it per-world}`.

    Filled in as `reset` and `step` are traced; fields declared with
    `Environment(per_world_model_fields=...)` are listed as declared.
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
    spec = self._task.get_reward_spec()
    if spec is not None:
      return spec
    return specs.Array(shape=(), dtype=np.float32, name='reward')

  def discount_spec(self):
    spec = self._task.get_discount_spec()
    if spec is not None:
      return spec
    return specs.BoundedArray(
        shape=(), dtype=np.float32, minimum=0.0, maximum=1.0, name='discount'
    )

  # -- physics -------------------------------------------------------------

  def initial_physics(self) -> physics_lib.Physics:
    """One world's `Physics` before any hook: the compiled model, `qpos0`."""
    return self._transitions.initial

  def physics(self, state: State) -> physics_lib.Physics:
    """The `Physics` of a state (a batch of them if the state is batched).

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
    if self._auto_reset == 'same_step':
      reset = jnp.logical_or(reset, state.last())
    full = reset_forward_lib.forward('full', physics.model, physics.data)
    return episode_lib.tree_select(reset, full, physics.data)

  # -- reset and step ------------------------------------------------------

  def reset(self, key) -> State:
    """Starts an episode for one world. Pure; jit and vmap it."""
    return self._transitions.reset(_as_key(key))

  def step(self, state: State, action) -> State:
    """Advances one world by one control step. Pure; jit and vmap it."""
    _check_one_world(state)
    action = self._check_action(action)
    transitions = self._transitions
    fuse = self._fuses_restart()
    if self._auto_reset == 'next_step':
      if fuse:
        return transitions.reset_or_step(state, action)
      reset_key, step_key = jax.random.split(state.key)
      stepped = transitions.step(state.replace(key=step_key), action)
      return episode_lib.select_reset(
          state.last(),
          transitions.reset,
          (reset_key, state),
          stepped,
          chunk=self._auto_reset_batch,
      )
    if fuse:
      return transitions.step_and_restart(state, action)
    stepped = transitions.step(state, action)
    return episode_lib.select_reset(
        stepped.last(),
        transitions.restart,
        (stepped,),
        stepped,
        chunk=self._auto_reset_batch,
    )

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
COMPOSER_OPTIONS = {
    'raise_exception_on_physics_error': (
        'nothing can raise inside a jitted step: a world whose physics '
        'diverges ends its episode (LAST, discount 0) with '
        "metrics['diverged'] = 1 and is reset, and the other worlds are "
        "untouched. Read metrics['diverged'] instead."
    ),
    'recompile_mjcf_every_episode': (
        'the model is compiled once, when the Environment is built: '
        'initialize_episode_mjcf and after_compile run once, on the host. '
        'Per-episode changes belong in initialize_episode (variations write '
        'per-world model fields).'
    ),
    'legacy_step': (
        "mjx.step is MuJoCo's mj_step: composer's legacy_step=False "
        'semantics (derived quantities in an observation lag the state by '
        'one physics step).'
    ),
}


def _check_composer_options(**options):
  """composer's boolean options: True, False or None; True only if we can."""
  for name, value in options.items():
    if not (value is None or isinstance(value, bool)):
      raise ValueError(f'{name} must be True, False or None, got {value!r}.')
    if value and name in COMPOSER_OPTIONS:
      raise ValueError(
          f'Environment({name}=True) is not available: '
          f'{COMPOSER_OPTIONS[name]} Pass {name}=False or leave it out.'
      )


def _check_arguments(
    padding, auto_reset, max_reset_attempts, time_limit, model_fields
):
  if not isinstance(padding, ObservationPadding):
    raise ValueError(
        'delayed_observation_padding must be an '
        f'ObservationPadding, got {padding!r}.'
    )
  if auto_reset not in episode_lib.AUTO_RESET_MODES:
    raise ValueError(
        f"auto_reset must be 'next_step' or 'same_step', got {auto_reset!r}."
    )
  if int(max_reset_attempts) != max_reset_attempts or max_reset_attempts < 1:
    raise ValueError(
        'max_reset_attempts must be a positive integer, got '
        f'{max_reset_attempts!r}.'
    )
  if time_limit <= 0:
    raise ValueError(f'time_limit must be positive, got {time_limit}.')
  unknown = set(model_fields) - element_index.MODEL_FIELDS
  if unknown:
    raise ValueError(
        f'Unknown mjx.Model fields {sorted(unknown)} in per_world_model_fields.'
    )


def _check_auto_reset_batch(batch, share_reset_forward, impl):
  if batch is None:
    return
  if isinstance(batch, bool) or int(batch) != batch or batch < 1:
    raise ValueError(
        f'auto_reset_batch must be a positive integer or None, got {batch!r}.'
    )
  if share_reset_forward:
    raise ValueError(
        'auto_reset_batch gathers the worlds that end into a separate, '
        'smaller reset; share_reset_forward=True runs the reset of the whole '
        'batch inside the sub-step loop instead. Set one of them.'
    )
  if impl == 'warp':
    raise ValueError(
        "auto_reset_batch needs impl='jax': MuJoCo Warp's contact buffer is "
        'shared by the whole batch, so a subset of worlds cannot be gathered '
        "and reset on its own. Use impl='jax' (or leave auto_reset_batch "
        'unset).'
    )


def _check_one_world(state):
  if jnp.ndim(state.step_type):
    raise ValueError(
        f'This state holds {jnp.shape(state.step_type)[0]} worlds: step a '
        'batch with jax.vmap(env.step)(states, actions).'
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
