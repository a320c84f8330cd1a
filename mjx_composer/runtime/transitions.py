"""`Transitions`: one world's reset and control step, as pure functions.

`Environment` checks arguments, compiles and owns the public API; this
module is what runs on the device for one world, in composer's order:

* `reset(key)`: split the key (`keys.ResetKeys`), start from the initial
  physics (on auto-reset keeping the world's model fields, persistent
  entries and scheduled hooks), run the `initialize_episode` hooks (retried
  in one loop while an initializer reports failure), the reset's stage of
  the forward pass (`reset_forward`), then the first observation and the
  episode's start (`first_state`);
* `step(state, action)`: split the key (`keys.StepKeys`), the scheduled and
  `before_step` hooks, one `lax.scan` over the sub-steps (`before_substep`,
  `mjx.step`, `after_substep`, the sub-step's observation update), then
  `after_step`, the last observation update, reward, discount and
  termination (`end_step`).

Each expensive piece (the `initialize_episode` hooks, `mjx.step`) is traced
once and appears once in the lowered program. The auto-reset that shares
the step's forward pass is `fused_restart`; the one that restores a stored
first state instead of running the reset is `stored_restart`.

What shapes the programs (the fields the reset's and the step's hooks make
per-world, the reset's and the step's stages of the forward pass, whether
the sensors are computed once per control step) is decided by analyses of
shapes, not of values, once per environment (`runtime.analysis`); a
`Transitions` reads their answers (`Transitions.analysis`).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer import physics as physics_lib
from mjx_composer.model import kinematics as kinematics_lib
from mjx_composer.platform import backend as backend_lib
from mjx_composer.platform import shared_buffers
from mjx_composer.runtime import analysis as analysis_lib
from mjx_composer.runtime import carried_stage as carried_stage_lib
from mjx_composer.runtime import control_flow
from mjx_composer.runtime import data_reads
from mjx_composer.runtime import episode as episode_lib
from mjx_composer.runtime import fused_restart
from mjx_composer.runtime import hooks as hooks_lib
from mjx_composer.runtime import keys as keys_lib
from mjx_composer.runtime import reset_forward as reset_forward_lib
from mjx_composer.runtime import state as state_lib
from mjx_composer.runtime import stored_restart as stored_restart_lib
from mjx_composer.runtime import substep_sensors as substep_sensors_lib


def initial_physics(task, model, data, index) -> physics_lib.Physics:
  """One world before any hook: `model`, `data`, the declared initial state."""
  entity_states = {}
  for entity in task.root_entity.iter_entities():
    initial = entity.initial_state()
    if initial is not None:
      entity_states[entity.full_identifier] = initial
  return physics_lib.Physics(
      model=model,
      data=data,
      task_state=task.initial_task_state(),
      index=index,
      persistent={},
      initialization_failed=jnp.zeros((), bool),
      entity_states=entity_states,
  )


def _named_scope(method):
  """Names a step's piece in the program (profiles attribute time to it)."""
  name = method.__name__.lstrip('_')

  @functools.wraps(method)
  def scoped(*args, **kwargs):
    with jax.named_scope(name):
      return method(*args, **kwargs)

  return scoped


@dataclasses.dataclass(frozen=True)
class Transitions:
  """Reset and step of one world (see `Environment` for their contract).

  Attributes:
    initial: the `Physics` every world starts from (`initial_physics`).
    hooks: the `hooks.EnvironmentHooks`.
    updater: the observation `Updater`.
    episode: the `episode.EpisodeRules`.
    n_sub_steps: physics steps per control step.
    max_reset_attempts: initialization attempts per reset.
    declared_model_fields: model fields made per-world whatever the hooks
      write (`ExecutionOptions.per_world_model_fields`); those that the
      hooks write are found (`Analysis.reset_shapes`).
    reset_forward_mode: 'observed' (a reset runs the stage of the forward
      pass that its readers need, `reset_forward`) or 'full'.
    action_shape: one world's action shape (the readers' analysis traces
      the step hooks).
    fixed_initial_state: every episode of a world starts from the key of its
      first (`reset(key)`), kept in its persistent entries
      (`keys.INITIAL_KEY`), and every initialization attempt uses that episode's
      key: composer's `fixed_initial_state`.
    substep_sensors: 'read' (`step` computes the sensors once per control
      step where nothing between its sub-steps reads them,
      `sensors_once_per_step`) or 'all' (every sub-step, as `mjx.step`).
    dirty_forward: 'composer' (a control step after which composer's
      physics is dirty and a binding read runs its forward pass ends with
      the full forward pass of the new state where its readers read the
      acceleration stage, `step_forward`, `runtime.dirty_forward`) or
      'never' (the acceleration stage keeps the step's values).
    carry_stage: 'auto' (`step`'s physics steps compute the end-of-step
      stage at their end and start from it, where `carried_stage.carries`
      allows) or 'never'.
    stored_restart_mode: 'auto' (an auto-reset restores a copy of the
      world's first state where `stored_restart.plan` allows) or 'never'.
  """

  initial: physics_lib.Physics
  hooks: object
  updater: object
  episode: episode_lib.EpisodeRules
  n_sub_steps: int
  max_reset_attempts: int
  declared_model_fields: tuple
  reset_forward_mode: str = 'full'
  action_shape: tuple = ()
  fixed_initial_state: bool = False
  substep_sensors: str = 'all'
  dirty_forward: str = 'composer'
  carry_stage: str = 'auto'
  stored_restart_mode: str = 'auto'

  @functools.cached_property
  def backend(self) -> backend_lib.Backend:
    """The `Backend` of the MJX implementation the worlds run on, asked for
    what it supports (found once, from the initial model)."""
    return backend_lib.of(self.initial.model)

  # -- what the analyses of shapes decided (`runtime.analysis`) -------------

  @functools.cached_property
  def analysis(self) -> analysis_lib.Analysis:
    """The analyses of shapes that decide what the programs compute, each
    run once, on first use (`analysis.Analysis`)."""
    return analysis_lib.Analysis(self)

  @property
  def reset_forward(self) -> reset_forward_lib.ResetForward:
    """The stage of the forward pass that a reset runs
    (`Analysis.reset_forward`)."""
    return self.analysis.reset_forward

  @property
  def step_forward(self) -> reset_forward_lib.StepForward:
    """What a control step recomputes after its last physics step
    (`Analysis.step_forward`)."""
    return self.analysis.step_forward

  @property
  def carried_stage(self) -> str | None:
    """The end-of-step stage that `step`'s sub-steps compute and carry
    (`Analysis.carried_stage`), or None."""
    return self.analysis.carried_stage

  @property
  def carried(self) -> carried_stage_lib.Stage | None:
    """`carried_stage` with what it hands on to the last sub-step's sensors
    (`Analysis.carried`), or None."""
    return self.analysis.carried

  @property
  def sensors_once_per_step(self) -> bool:
    """Whether the sub-steps leave the sensors to the control step's end
    (`Analysis.sensors_once_per_step`)."""
    return self.analysis.sensors_once_per_step

  @property
  def step_model_fields(self) -> tuple[str, ...]:
    """The model fields per-world whatever the `initialize_episode` hooks
    write (`Analysis.step_model_fields`)."""
    return self.analysis.step_model_fields

  def per_world_model_fields(self) -> dict[str, tuple[str, ...]]:
    """`{model field: what made it per-world}`
    (`Analysis.per_world_model_fields`)."""
    return self.analysis.per_world_model_fields()

  @functools.cached_property
  def _initial_kinematics(self) -> kinematics_lib.ReferenceKinematics:
    data = self.initial.data
    return kinematics_lib.ReferenceKinematics(
        self.initial.index.mj_model,
        qpos=np.asarray(data.qpos),
        mocap_pos=np.asarray(data.mocap_pos),
        mocap_quat=np.asarray(data.mocap_quat),
    )

  # -- a world's fields and its `Physics` ----------------------------------

  def physics(self, state: state_lib.State) -> physics_lib.Physics:
    """The `Physics` of a `State`."""
    return state.restore(self.initial.model, self.initial.index)

  def restore(self, carry: physics_lib.WorldFields) -> physics_lib.Physics:
    """The `Physics` of a `PhysicsCarry` (or a `State`)."""
    return carry.restore(self.initial.model, self.initial.index)

  # -- reset ---------------------------------------------------------------

  def reset(self, key, previous: state_lib.State | None = None):
    """A new episode; `previous` is the world's last state on auto-reset."""
    with jax.named_scope('reset'):
      key = self.episode_key(key, previous)
      keys = keys_lib.ResetKeys.split(key)
      carry, failures = self.initialize(
          keys.init, self.start_carry(previous, key)
      )
      physics = self.restore(carry)
      physics = physics.replace(
          data=self.reset_forward(physics.model, physics.data)
      )
      return self.first_state(physics, carry, failures, keys)

  def begin(self, key) -> state_lib.State:
    """A world's first episode: `reset(key)`, with the copy of its first
    state that its auto-resets restore where they may (`stored_restart`)."""
    plan = self.stored_restart
    return self.reset(key) if plan is None else plan.first(self.reset, key)

  def restart(self, stepped: state_lib.State) -> state_lib.State:
    """Same-step auto-reset: the next episode, reporting the ended one."""
    return episode_lib.reporting(
        self.reset(stepped.key, previous=stepped), stepped
    )

  @property
  def stored_restart(self) -> stored_restart_lib.Plan | None:
    """How an auto-reset restores the world's first state, or None where it
    runs the reset (`Analysis.stored_restart`)."""
    return self.analysis.stored_restart

  def episode_key(self, key, previous):
    """The key an episode starts from: `key`, or the world's first one."""
    if self.fixed_initial_state and previous is not None:
      return previous.persistent[keys_lib.INITIAL_KEY]
    return key

  def start_carry(self, previous, key=None) -> physics_lib.PhysicsCarry:
    """What an episode's initialization starts from.

    The initial physics; on auto-reset (`previous`, the world's last state)
    with the world's model fields, persistent entries and scheduled hooks.
    """
    start = self.initial.carry(())
    if previous is None:
      if self.fixed_initial_state:
        start = start.replace(
            persistent={**start.persistent, keys_lib.INITIAL_KEY: key}
        )
      return start
    # An auto-reset keeps the world's model and persistent entries.
    return start.replace(
        model_fields=previous.model_fields,
        persistent=previous.persistent,
        scheduled_hooks=previous.scheduled_hooks,
    )

  @_named_scope
  def first_state(self, physics, carry, failures, keys):
    """The FIRST `State` of an initialized, forwarded `physics`.

    `keys`: the reset's `keys.ResetKeys`.
    """
    obs_state = self.updater.reset(physics, keys.obs)
    return _state(
        physics,
        tuple(carry.model_fields),
        obs_state,
        keys.next,
        self.episode.start(
            physics, failures, self.updater.get_observation(obs_state)
        ),
    )

  def _attempt(self, key, start, writers=None, step_fields=None):
    """One run of the `initialize_episode` hooks from `start`.

    `writers`: as in `hooks.EnvironmentHooks.initialize_episode`.
    `step_fields`: the model fields per-world whatever these hooks write
    (default `step_model_fields`).
    """
    if step_fields is None:
      step_fields = self.step_model_fields
    physics = self.restore(start)
    if self.hooks.initializes():
      # The MJCF variations composer applies in `initialize_episode_mjcf`,
      # before it compiles the episode's model and resets its data.
      physics = self.hooks.episode_variations(physics, key, writers)
      # Composer runs a whole forward pass here; the hooks read poses, so
      # kinematics suffices, and keeps a second copy of the collision and
      # constraint code out of every program that contains a reset (the
      # step program does, through auto-reset). Every attempt starts from
      # the initial data, whose kinematics the host knows.
      # As in composer's reset context, a hook's read of what a write made
      # stale sees the new state: the read runs the forward pass's stage
      # that computes it (`Physics.forward_stale_reads`). The reset wrote
      # the initial velocities and controls and computed only positions;
      # where the episode's masses vary, not even the centres of mass and
      # composite inertias, which few hooks read (as a write of masses
      # would, `mark_written('body_mass')` makes a read compute them).
      kinematics = self._initial_kinematics
      stale = ['qvel', 'act', 'ctrl']
      if kinematics.com_varies(physics.model):
        stale.append('body_mass')
      physics = physics.replace(
          data=kinematics.apply(physics.model, self.initial.data, com=False),
          forward_stale_reads=True,
      ).mark_written(*stale)
      physics = self.hooks.initialize_episode(physics, key, writers)
      # A hook that drew a NaN (or an infinity) into the state fails the
      # attempt, as an initializer that finds no valid pose does.
      physics = physics.fail_initialization(
          episode_lib.nonfinite_initial_state(physics.data)
      )
    changed = physics_lib.changed_model_fields(
        self.initial.model, physics.model
    )
    fields = sorted(set(changed) | set(step_fields))
    return physics.carry(fields)

  @_named_scope
  def initialize(self, init_key, start):
    """The initialized carry and the number of failed attempts.

    With `max_reset_attempts > 1`, failed attempts are resampled with fresh
    keys; every attempt starts from the same model and persistent entries,
    so a failed attempt leaves no trace but its key. The hooks are traced
    once: the loop's body evaluates that trace.
    """
    if not self.hooks.initializes():
      carry = self._attempt(init_key, start)
      return carry, carry.initialization_failed.astype(jnp.int32)
    if self.max_reset_attempts == 1:
      carry = self._attempt(init_key, start)
      return (
          self._fall_back(carry, start),
          carry.initialization_failed.astype(jnp.int32),
      )
    attempt, shapes = control_flow.trace_once(
        self._attempt, init_key, start, return_shapes=True
    )

    def body(loop):
      attempts, failures, _ = loop
      key = keys_lib.ResetKeys.attempt(
          init_key, attempts, resample=not self.fixed_initial_state
      )
      carry = attempt(key, start)
      failed = carry.initialization_failed.astype(jnp.int32)
      # A per-world loop condition batches the whole carry: keep Warp's
      # batch-shared buffers (contacts) out of it
      # (`shared_buffers.drop_shared`).
      return attempts + 1, failures + failed, shared_buffers.drop_shared(carry)

    def again(loop):
      attempts, _, carry = loop
      return jnp.logical_or(
          attempts == 0,
          jnp.logical_and(
              carry.initialization_failed, attempts < self.max_reset_attempts
          ),
      )

    placeholder = shared_buffers.drop_shared(
        jax.tree.map(_zeros_like_shape, shapes)
    )
    _, failures, carry = jax.lax.while_loop(
        again,
        body,
        (jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32), placeholder),
    )
    carry = carry.replace(
        data=shared_buffers.restore_shared(carry.data, start.data)
    )
    return self._fall_back(carry, start), failures

  def _fall_back(self, carry, start):
    """`carry`, or where its last attempt failed too, what the reset started
    from: an invalid draw (a negative mass, a NaN) or a failed initializer
    is never run.

    A world whose every attempt failed keeps `start`: its data, task and
    entity state, and the model it had before the reset (the compiled
    values on `Environment.reset`, the previous episode's on an
    auto-reset), so that neither the reset's forward pass nor any step
    computes with the failed attempt's values. The persistent entries that
    `start` lacks (created by the attempt, e.g. a variator's schedule) keep
    what the attempt wrote; `start`'s own entries are restored. The flag
    stays set: `metrics['init_failed']` reports the world and its first
    step ends the episode (`EpisodeRules.end_of_step`), so an auto-reset
    resamples it. A per-world select: other worlds are untouched.
    """
    fields = tuple(carry.model_fields)
    physics = self.restore(start)
    # What an attempt's hooks start from: `start`'s kinematics (its centres
    # of mass are left to the reset's forward pass, as `_attempt` does).
    physics = physics.replace(
        data=self._initial_kinematics.apply(
            physics.model, self.initial.data, com=False
        )
    )
    nominal = physics.carry(fields)
    nominal = nominal.replace(
        persistent={**carry.persistent, **nominal.persistent},
        initialization_failed=carry.initialization_failed,
    )
    nominal = dataclasses.replace(
        nominal, scheduled_hooks=carry.scheduled_hooks
    )
    return control_flow.tree_select(carry.initialization_failed, nominal, carry)

  # -- step ----------------------------------------------------------------

  def step(self, state: state_lib.State, action) -> state_lib.State:
    """One control step; episode ends are decided, not acted on.

    A non-finite action runs as zeros and ends the episode
    (`episode.checked_action`).
    """
    action, action_nonfinite = episode_lib.checked_action(action)
    keys = keys_lib.StepKeys.split(state.key)
    fields = tuple(state.model_fields)
    physics = self.before_step(state, action, keys)
    sensors_once = self.sensors_once_per_step
    carried = self.carried

    def substep(loop, i):
      carry, obs_state, started, kept = loop
      physics = self.before_substep(
          self.restore(carry), action, keys, i, fields
      )
      model = physics.model
      if sensors_once:
        started = substep_sensors_lib.IntegrationState.of(physics.data)
        physics = physics.replace(
            model=substep_sensors_lib.without_sensors(model)
        )
      if carried is None:
        moved = physics.step()
      else:
        moved = physics.replace(
            data=carried_stage_lib.physics_step(
                physics.model, physics.data, carried.name
            )
        )
      carry, obs_state = self.after_substep(moved, obs_state, keys, i, fields)
      if carried is not None:
        data, kept = self.end_substep(model, carry.data)
        carry = carry.replace(data=data)
      return (carry, obs_state, started, kept), None

    started = None
    if sensors_once:
      started = substep_sensors_lib.IntegrationState.of(physics.data)
    kept = {}
    if carried is not None:
      kept = data_reads.leaves_named(physics.data, carried.sensor_inputs)
    (carry, obs_state, started, kept), _ = jax.lax.scan(
        substep,
        (physics.carry(fields), state.obs_state, started, kept),
        jnp.arange(self.n_sub_steps, dtype=jnp.int32),
    )
    physics = self.after_physics(self.restore(carry), started, kept)
    return self.end_step(state, physics, obs_state, keys, action_nonfinite)

  @_named_scope
  def end_substep(self, model, data):
    """A sub-step's data (after its hooks) with the carried stage of its
    new state (`carried_stage`), and the values the stage overwrote of the
    inputs of the sub-step's sensors (`carried_stage.Stage.run`), for
    `after_physics` where the sub-step is the control step's last."""
    return self.carried.run(model, data)

  @_named_scope
  def after_physics(self, physics, started, kept=None):
    """`physics` after a control step's last sub-step, as its readers see it.

    The sensors of that sub-step where the sub-steps skipped them
    (`sensors_once_per_step`; `started`, its `IntegrationState`), then the
    stage of the forward pass the step recomputes at the new state
    (`step_forward`); the sensor stages that stage recomputes are not
    computed before it. Where the sub-steps carried a stage
    (`carried_stage`), they computed it: the sensors come from what it
    kept of their inputs (`kept`, from `end_substep`), and what
    `step_forward` computes beyond the stage follows
    (`carried_stage.finish`).
    """
    data = physics.data
    step_forward = self.step_forward
    carried = self.carried
    if self.sensors_once_per_step:
      if carried is None:
        data = substep_sensors_lib.sensors_of(
            physics.model, data, started, step_forward.sensor_stages
        )
      else:
        data = carried.sensors_of_last(
            physics.model, data, kept, started, step_forward.sensor_stages
        )
    if carried is not None:
      data = carried_stage_lib.finish(
          physics.model, data, carried.name, step_forward
      )
      return physics.replace(data=data)
    return physics.replace(data=step_forward(physics.model, data))

  def can_fuse_restart(self) -> bool:
    """Whether `step_and_restart` and `reset_or_step` apply
    (`fused_restart.can_fuse`)."""
    return fused_restart.can_fuse(self)

  def step_and_restart(
      self, state, action, conditional=False
  ) -> state_lib.State:
    """`step`, then `restart` where the episode ended: same-step auto-reset,
    with one copy of the forward pass in the program instead of two
    (`fused_restart.step_and_restart`, whose `conditional` suits a CPU).
    Needs `can_fuse_restart`."""
    return fused_restart.step_and_restart(self, state, action, conditional)

  def reset_or_step(self, state, action, conditional=False) -> state_lib.State:
    """Next-step auto-reset: `reset` where `state` is LAST, else `step`,
    with one copy of the forward pass in the program instead of two
    (`fused_restart.reset_or_step`, whose `conditional` suits a CPU).
    Needs `can_fuse_restart`."""
    return fused_restart.reset_or_step(self, state, action, conditional)

  # The pieces of a step, shared by `step` and `fused_restart`.

  @_named_scope
  def before_step(self, state, action, keys):
    """The scheduled and `before_step` hooks: the `Physics` they leave."""
    start = self.physics(state)
    physics = self.hooks.scheduled(start, keys.before)
    physics = self.hooks.before_step(physics, action, keys.before)
    hooks_lib.check_step_writes(
        start, physics, tuple(state.model_fields), 'before_step'
    )
    return physics

  @_named_scope
  def before_substep(self, physics, action, keys, i, fields):
    """Sub-step `i`'s `before_substep` hooks."""
    sub_keys = keys.of_substep(i)
    start = physics
    physics = self.hooks.before_substep(physics, action, sub_keys.before())
    hooks_lib.check_step_writes(start, physics, fields, 'before_substep')
    return physics

  @_named_scope
  def after_substep(self, physics, obs_state, keys, i, fields):
    """After-substep hooks and observation updates: (carry, obs_state)."""
    sub_keys = keys.of_substep(i)
    start = physics
    physics = self.hooks.after_substep(physics, sub_keys.after())
    hooks_lib.check_step_writes(start, physics, fields, 'after_substep')
    n = self.n_sub_steps
    if n > 1:
      # Sub-steps 1..n-1 update the observations here; the updater skips,
      # at trace time, every observable that cannot be sampled there. The
      # last sub-step's update comes after the after_step hooks, so there
      # the update is computed and discarded: a select, not a `lax.cond`,
      # which on a GPU costs a host round trip and copies of the
      # observation state at every sub-step; the discarded update costs
      # one sub-step's samples.
      updated = self.updater.update(
          obs_state,
          physics,
          sub_keys.obs(),
          jnp.minimum(i + 1, n - 1),
          substep_bounds=(1, n - 1),
      )
      obs_state = jax.tree.map(
          lambda new, old: jnp.where(i < n - 1, new, old), updated, obs_state
      )
    return physics.carry(fields), obs_state

  @_named_scope
  def end_step(self, state, physics, obs_state, keys, action_nonfinite):
    """The `after_step` hooks, the last observation update and how the step
    ended (`EpisodeRules.end_of_step`; `action_nonfinite` from
    `episode.checked_action`): the stepped `State`."""
    fields = tuple(state.model_fields)
    start = physics
    physics = self.hooks.after_step(physics, keys.after)
    hooks_lib.check_step_writes(start, physics, fields, 'after_step')
    obs_state = self.updater.update(
        obs_state, physics, keys.obs, self.n_sub_steps
    )
    return _state(
        physics,
        fields,
        obs_state,
        keys.next,
        jax.named_scope('episode')(self.episode.end_of_step)(
            state,
            physics,
            self.updater.get_observation(obs_state),
            action_nonfinite,
        ),
        stored_first=state.stored_first,
    )


def _state(physics, fields, obs_state, key, episode_fields, stored_first=None):
  """The `State` of `physics` with its observation state and the episode's
  fields (`EpisodeRules.start` or `end_of_step`: the observation included),
  and the world's copy of its first state (`stored_restart`)."""
  return state_lib.State(
      **physics.world_fields(fields),
      obs_state=obs_state,
      key=key,
      stored_first=stored_first,
      **episode_fields,
  )


def _zeros_like_shape(shape):
  if jnp.issubdtype(shape.dtype, jax.dtypes.prng_key):
    return jax.random.wrap_key_data(
        jnp.zeros(
            shape.shape + jax.random.key_data(jax.random.key(0)).shape,
            jnp.uint32,
        ),
        impl=jax.random.key_impl(jax.random.key(0)),
    )
  return jnp.zeros(shape.shape, shape.dtype)
