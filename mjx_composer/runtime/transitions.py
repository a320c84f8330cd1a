"""`Transitions`: one world's reset and control step, as pure functions.

`Environment` checks arguments, compiles and owns the public API; this
module is what runs on the device for one world: the reset with its bounded
initialization attempts, and the control step with its sub-step scan. Both
are written so that each expensive piece (the `initialize_episode` hooks,
`mjx.step`) is traced once and appears once in the lowered program.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np

from mjx_composer.platform import backend
from mjx_composer.runtime import data_reads
from mjx_composer.runtime import episode as episode_lib
from mjx_composer.model import kinematics as kinematics_lib
from mjx_composer import physics as physics_lib
from mjx_composer.runtime import reset_forward as reset_forward_lib
from mjx_composer.runtime import state as state_lib
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


# The persistent entry holding a world's first key (`fixed_initial_state`).
INITIAL_KEY = 'environment/initial_key'


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
    declared_model_fields: model fields that step hooks may write.
    reset_forward_mode: 'observed' (a reset runs the stage of the forward
      pass that its readers need, `reset_forward`) or 'full'.
    action_shape: one world's action shape (the readers' analysis traces
      the step hooks).
    fixed_initial_state: every episode of a world starts from the key of its
      first (`reset(key)`), kept in its persistent entries
      (`INITIAL_KEY`), and every initialization attempt uses that episode's
      key: composer's `fixed_initial_state`.
    substep_sensors: 'read' (`step` computes the sensors once per control
      step where nothing between its sub-steps reads them,
      `sensors_once_per_step`) or 'all' (every sub-step, as `mjx.step`).
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

  @functools.cached_property
  def _initial_kinematics(self) -> kinematics_lib.ReferenceKinematics:
    data = self.initial.data
    return kinematics_lib.ReferenceKinematics(
        self.initial.index.mj_model,
        qpos=np.asarray(data.qpos),
        mocap_pos=np.asarray(data.mocap_pos),
        mocap_quat=np.asarray(data.mocap_quat),
    )

  @functools.cached_property
  def reset_forward(self) -> reset_forward_lib.ResetForward:
    """The stage of the forward pass that a reset runs.

    With `reset_forward_mode='observed'`, the cheapest stage that computes
    what the FIRST state's readers read (`_read_after_reset`);
    'full' on MuJoCo Warp, whose forward pass is one kernel sequence.
    """
    model, data = self.initial.model, self.initial.data
    if self.reset_forward_mode == 'full' or backend.is_warp(model):
      # The full pass restricts nothing: no need to trace what it writes.
      return reset_forward_lib.ResetForward(
          'full', True, frozenset(), frozenset()
      )
    read = self._read_after_reset()
    return reset_forward_lib.choose_stage(
        read.fields,
        model,
        data,
        self.initial.index.mj_model,
        sensordata=read.sensordata,
    )

  def _read_after_reset(self) -> data_reads.Reads:
    """What is read of a reset's `mjx.Data` before any physics.

    Its readers: the observables sampled at reset, the episode's start
    metrics but `diverged` (whose `qacc` checks the forward pass itself),
    and the next step's hooks before its physics (scheduled, `before_step`
    and the first `before_substep`). The data those hooks pass on
    untouched to the physics is not read by them: `mjx.step` reads only the
    integration state, which a reset's forward pass does not write.
    """
    key = jax.random.key(0)
    carry, failures = jax.eval_shape(
        lambda k: self._initialize(k, self._start(None, k)), key
    )
    action = jax.ShapeDtypeStruct(self.action_shape, jnp.float32)

    def readers(data, carry, failures, key, action):
      physics = self._restore(carry.replace(data=data))
      obs_key, next_key, step_key = jax.random.split(key, 3)
      first = self._first_state(physics, carry, failures, obs_key, next_key)
      metrics = dict(first.metrics)
      diverged = metrics.pop('diverged')
      keys = _StepKeys.split(step_key)
      fields = tuple(first.model_fields)
      before = self._before_step(first, action, keys)
      before = self._before_substep(before, action, keys, 0, fields)
      after = before.carry(fields)
      pairs = zip(jax.tree.leaves(after.data), jax.tree.leaves(data))
      written = [new for new, old in pairs if new is not old]
      read = (
          first.replace(data=None, metrics=metrics),
          after.replace(data=None),
          written,
      )
      return read, (first.data, diverged)

    return data_reads.reads(readers, carry.data, carry, failures, key, action)

  @functools.cached_property
  def sensors_once_per_step(self) -> bool:
    """Whether the sub-steps leave the sensors to the control step's end
    (in `step` and in the fused restart's loop, `_step_in_one_loop`).

    With `substep_sensors='read'`, on MJX's JAX implementation with the
    Euler or implicitfast integrator, where nothing between two sub-steps'
    physics reads what the sensor stages write (`_between_substeps`) and
    the after-substep hooks write no data but the integration state:
    `substep_sensors` explains why the control step is then the same.
    """
    if not self._may_leave_sensors_to_the_end():
      return False
    return self._sensors_once(jax.eval_shape(self.reset, jax.random.key(0)))

  def _may_leave_sensors_to_the_end(self) -> bool:
    """`sensors_once_per_step`'s conditions that need no tracing."""
    model = self.initial.model
    return not (
        self.substep_sensors == 'all'
        or self.n_sub_steps == 1
        or backend.is_warp(model)
        or int(model.opt.integrator) not in _INTEGRATORS
        or model.opt.disableflags & mjx.DisableBit.SENSOR
    )

  def _sensors_once(self, state) -> bool:
    """`sensors_once_per_step`, from the shapes of a `State` (or its
    tracers, in `step`: no second trace of the reset)."""
    if 'sensors_once_per_step' not in self.__dict__:
      # Where `cached_property` keeps its value (a frozen dataclass too).
      self.__dict__['sensors_once_per_step'] = self._decide_sensors_once(
          jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), state)
      )
    return self.__dict__['sensors_once_per_step']

  def _decide_sensors_once(self, state) -> bool:
    if not self._may_leave_sensors_to_the_end():
      return False
    read, written = self._between_substeps(state)
    allowed = set(substep_sensors_lib.ADVANCED)
    return not (read.fields & substep_sensors_lib.OUTPUTS or written - allowed)

  def _between_substeps(self, state) -> tuple[data_reads.Reads, set[str]]:
    """What the work between two sub-steps' physics reads of `mjx.Data`,
    and the data leaves the after-substep hooks write.

    That work: a sub-step's after-substep hooks and observation update,
    then the next sub-step's before-substep hooks. The data those hooks pass
    on untouched to the physics is not read by them (see
    `_read_after_reset`). `state`: a `State`'s shapes.
    """
    action = jax.ShapeDtypeStruct(self.action_shape, jnp.float32)
    index = jax.ShapeDtypeStruct((), jnp.int32)
    names = data_reads.leaf_names(state.data)
    hooks_wrote = set()

    def readers(data, state, key, action, i):
      keys = _StepKeys.split(key)
      fields = tuple(state.model_fields)
      stepped = self.physics(state.replace(data=data))
      carry, obs_state = self._after_substep(
          stepped, state.obs_state, keys, i, fields
      )
      pairs = zip(names, jax.tree.leaves(carry.data), jax.tree.leaves(data))
      hooks_wrote.update(name for name, new, old in pairs if new is not old)
      after = self._before_substep(
          self._restore(carry), action, keys, i + 1, fields
      ).carry(fields)
      pairs = zip(jax.tree.leaves(after.data), jax.tree.leaves(data))
      written = [new for new, old in pairs if new is not old]
      return (after.replace(data=None), obs_state, written), after.data

    # The key's shape, not a key: this runs inside the step's trace, where
    # `jax.random.key(0)` would stage an equation into the step's program.
    key = jax.eval_shape(lambda: jax.random.key(0))
    read = data_reads.reads(readers, state.data, state, key, action, index)
    return read, hooks_wrote

  def physics(self, state: state_lib.State) -> physics_lib.Physics:
    """The `Physics` of a `State`."""
    return self._restore(
        physics_lib.PhysicsCarry(
            data=state.data,
            task_state=state.task_state,
            entity_states=state.entity_states,
            model_fields=state.model_fields,
            persistent=state.persistent,
            initialization_failed=None,
            scheduled_hooks=state.scheduled_hooks,
        )
    )

  def per_world_model_fields(self) -> dict[str, tuple[str, ...]]:
    fields = dict(self.hooks.model_field_writers)
    for name in self.declared_model_fields:
      fields[name] = fields.get(name, ()) + (
          'Environment(per_world_model_fields=...)',
      )
    return dict(sorted(fields.items()))

  def _restore(self, carry) -> physics_lib.Physics:
    return carry.restore(self.initial.model, self.initial.index)

  # -- reset ---------------------------------------------------------------

  def reset(self, key, previous: state_lib.State | None = None):
    """A new episode; `previous` is the world's last state on auto-reset."""
    with jax.named_scope('reset'):
      key = self._episode_key(key, previous)
      init_key, obs_key, next_key = jax.random.split(key, 3)
      carry, failures = self._initialize(init_key, self._start(previous, key))
      physics = self._restore(carry)
      physics = physics.replace(
          data=self.reset_forward(physics.model, physics.data)
      )
      return self._first_state(physics, carry, failures, obs_key, next_key)

  def restart(self, stepped: state_lib.State) -> state_lib.State:
    """Same-step auto-reset: the next episode, reporting the ended one."""
    return _reporting(self.reset(stepped.key, previous=stepped), stepped)

  def _episode_key(self, key, previous):
    """The key an episode starts from: `key`, or the world's first one."""
    if self.fixed_initial_state and previous is not None:
      return previous.persistent[INITIAL_KEY]
    return key

  def _start(self, previous, key=None):
    start = self.initial.carry(())
    if previous is None:
      if self.fixed_initial_state:
        start = start.replace(persistent={**start.persistent, INITIAL_KEY: key})
      return start
    # An auto-reset keeps the world's model and persistent entries.
    return start.replace(
        model_fields=previous.model_fields,
        persistent=previous.persistent,
        scheduled_hooks=previous.scheduled_hooks,
    )

  @_named_scope
  def _first_state(self, physics, carry, failures, obs_key, next_key):
    """The FIRST `State` of an initialized, forwarded `physics`."""
    return _state(
        physics,
        tuple(carry.model_fields),
        self.updater.reset(physics, obs_key),
        self.updater,
        next_key,
        self.episode.start(physics, failures),
    )

  def _attempt(self, key, start):
    """One run of the `initialize_episode` hooks from `start`."""
    physics = self._restore(start)
    if self.hooks.has('initialize_episode'):
      # Composer runs a whole forward pass here; the hooks read poses, so
      # kinematics suffices, and keeps a second copy of the collision and
      # constraint code out of every program that contains a reset (the
      # step program does, through auto-reset). Every attempt starts from
      # the initial data, whose kinematics the host knows.
      physics = physics.replace(
          data=self._initial_kinematics.apply(physics.model, self.initial.data)
      )
      physics = self.hooks.initialize_episode(physics, key)
    base = self.initial.model
    changed = {
        f.name
        for f in dataclasses.fields(mjx.Model)
        if getattr(physics.model, f.name) is not getattr(base, f.name)
    }
    fields = sorted(changed | set(self.declared_model_fields))
    return physics.carry(fields)

  @_named_scope
  def _initialize(self, init_key, start):
    """The initialized carry and the number of failed attempts.

    With `max_reset_attempts > 1`, failed attempts are resampled with fresh
    keys; every attempt starts from the same model and persistent entries,
    so a failed attempt leaves no trace but its key. The hooks are traced
    once: the loop's body evaluates that trace.
    """
    if self.max_reset_attempts == 1 or not self.hooks.has('initialize_episode'):
      carry = self._attempt(init_key, start)
      return carry, carry.initialization_failed.astype(jnp.int32)
    attempt, shapes = episode_lib.trace_once(
        self._attempt, init_key, start, return_shapes=True
    )

    def body(loop):
      attempts, failures, _ = loop
      key = init_key
      if not self.fixed_initial_state:  # composer restores its RNG instead
        key = _select_key(
            attempts == 0, init_key, jax.random.fold_in(init_key, attempts)
        )
      carry = attempt(key, start)
      failed = carry.initialization_failed.astype(jnp.int32)
      # A per-world loop condition batches the whole carry: keep Warp's
      # batch-shared buffers (contacts) out of it (`backend.drop_shared`).
      return attempts + 1, failures + failed, backend.drop_shared(carry)

    def again(loop):
      attempts, _, carry = loop
      return jnp.logical_or(
          attempts == 0,
          jnp.logical_and(
              carry.initialization_failed, attempts < self.max_reset_attempts
          ),
      )

    placeholder = backend.drop_shared(jax.tree.map(_zeros_like_shape, shapes))
    _, failures, carry = jax.lax.while_loop(
        again,
        body,
        (jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32), placeholder),
    )
    return (
        carry.replace(data=backend.restore_shared(carry.data, start.data)),
        failures,
    )

  # -- step ----------------------------------------------------------------

  def step(self, state: state_lib.State, action) -> state_lib.State:
    """One control step; episode ends are decided, not acted on."""
    keys = _StepKeys.split(state.key)
    fields = tuple(state.model_fields)
    physics = self._before_step(state, action, keys)
    sensors_once = self._sensors_once(state)

    def substep(loop, i):
      carry, obs_state, started = loop
      physics = self._before_substep(
          self._restore(carry), action, keys, i, fields
      )
      if sensors_once:
        started = substep_sensors_lib.IntegrationState.of(physics.data)
        physics = physics.replace(
            model=substep_sensors_lib.without_sensors(physics.model)
        )
      carry, obs_state = self._after_substep(
          physics.step(), obs_state, keys, i, fields
      )
      return (carry, obs_state, started), None

    started = None
    if sensors_once:
      started = substep_sensors_lib.IntegrationState.of(physics.data)
    (carry, obs_state, started), _ = jax.lax.scan(
        substep,
        (physics.carry(fields), state.obs_state, started),
        jnp.arange(self.n_sub_steps, dtype=jnp.int32),
    )
    physics = self._restore(carry)
    if sensors_once:
      physics = physics.replace(
          data=substep_sensors_lib.sensors_of(
              physics.model, physics.data, started
          )
      )
    return self._end_step(state, physics, obs_state, keys)

  def can_fuse_restart(self) -> bool:
    """Whether `step_and_restart` applies (see there)."""
    if int(self.initial.model.opt.integrator) not in _INTEGRATORS:
      return False
    m = self.initial.index.mj_model
    if np.any(m.actuator_gaintype == mujoco.mjtGain.mjGAIN_MUSCLE) or np.any(
        m.actuator_biastype == mujoco.mjtBias.mjBIAS_MUSCLE
    ):
      return False  # a muscle's force is not zero when its parameters are
    # Actuator-level gravity compensation adds to the actuator forces.
    return not np.any(m.jnt_actgravcomp)

  def step_and_restart(self, state, action) -> state_lib.State:
    """`step`, then `restart` where the episode ended: same-step auto-reset.

    The same as `select(last, restart(stepped), stepped)` of `stepped =
    step(state, action)`, with one copy of the forward pass in the program
    instead of two: the sub-steps run `mjx.forward` then the integrator,
    and the restart is one more iteration of the same loop, whose forward
    pass runs with every actuator force masked to zero, as composer's reset
    runs `mj_forward` with actuation disabled. Needs the Euler or
    implicitfast integrator, no muscles and no actuator gravity
    compensation (`can_fuse_restart`); otherwise `Environment.step` runs
    `step` and `restart`.
    """
    return self._step_in_one_loop(state, action, None)

  def reset_or_step(self, state, action) -> state_lib.State:
    """Next-step auto-reset: `reset` where `state` is LAST, else `step`.

    With `reset_key, step_key = split(state.key)`, the same as
    `select(state.last(), reset(reset_key, previous=state),
    step(state with step_key, action))`, with one copy of the forward pass
    in the program instead of two, as in `step_and_restart`: the reset is
    one more iteration of the sub-step loop (a world that resets discards
    its sub-steps, as the select does). Same conditions
    (`can_fuse_restart`).
    """
    reset_key, step_key = jax.random.split(state.key)
    return self._step_in_one_loop(
        state.replace(key=step_key), action, (reset_key, state)
    )

  def _step_in_one_loop(self, state, action, next_step_reset):
    """The sub-steps and a reset in one loop (see the two callers).

    One `lax.while_loop` over `i`: iterations `0..n-1` are the sub-steps
    (forward pass, integrator, after-substep work); the last of them also
    ends the control step and, where some world wants a reset, prepares it
    (the `initialize_episode` hooks, randomization included); iteration `n`
    runs only where some world wants it, and forwards the prepared reset
    with actuation masked. The parts that run at one iteration only are
    loops run once or never (`episode_lib.once_or_never`), on conditions
    shared by the batch (the counter, `episode_lib.batch_any`), so nothing
    in the loop is a `lax.cond` and nothing is computed for every world at
    every sub-step but the sub-step itself and selects on the counter. The
    restart's end runs before the step's end in each iteration, so that XLA
    need not copy the restart's inputs at every sub-step (README).

    Args:
      state: the state the sub-steps start from (its key is the step's).
      action: the control step's action.
      next_step_reset: None for a same-step restart (of the stepped state,
        where it is LAST, with its key); else `(reset_key, previous)`, a
        next-step reset of `previous` (where it is LAST, with `reset_key`).
    """
    keys = _StepKeys.split(state.key)
    fields = tuple(state.model_fields)
    physics = self._before_step(state, action, keys)
    n = self.n_sub_steps
    integrate = _INTEGRATORS[int(self.initial.model.opt.integrator)]
    sensors_once = self._sensors_once(state)

    def reset_from(stepped, next_reset):
      """(key, previous state, whether it resets) of the reset iteration."""
      if next_reset is None:
        return (
            self._episode_key(stepped.key, stepped),
            stepped,
            stepped.last(),
        )
      reset_key, previous = next_reset
      return (
          self._episode_key(reset_key, previous),
          previous,
          previous.last(),
      )

    def prepare_restart(stepped, next_reset):
      """The initialized carry of the restart, and its failed attempts."""
      reset_key, previous, _ = reset_from(stepped, next_reset)
      init_key, _, _ = jax.random.split(reset_key, 3)
      return self._initialize(init_key, self._start(previous))

    def end_step(state, keys, next_reset, started, loop):
      """Ends the control step; prepares the restart where one is wanted."""
      carry, obs_state, stepped, failures = loop
      moved = self._restore(carry)
      if sensors_once:
        moved = moved.replace(
            data=substep_sensors_lib.sensors_of(
                moved.model, moved.data, started
            )
        )
      stepped = self._end_step(state, moved, obs_state, keys)
      carry, failures = episode_lib.once_or_never(
          episode_lib.batch_any(reset_from(stepped, next_reset)[2]),
          lambda _: prepare_restart(stepped, next_reset),
          (carry, failures),
      )
      return carry, obs_state, stepped, failures

    def finish_restart(ready, forwarded, failures, stepped, next_reset):
      """The restarted state where the world resets, else `stepped`."""
      reset_key, _, resets = reset_from(stepped, next_reset)
      if sensors_once:  # the loop's forward pass skipped them
        forwarded = forwarded.replace(
            data=self.reset_forward.sensors_of(forwarded.model, forwarded.data)
        )
      # What `mjx.forward` leaves with actuation disabled.
      data = forwarded.data.replace(
          act_dot=jnp.zeros_like(forwarded.data.act_dot),
          actuator_force=ready.data.actuator_force,
      )
      # What the reset's stage of the forward pass leaves (`reset`).
      data = self.reset_forward.restrict(data, ready.data)
      _, obs_key, next_key = jax.random.split(reset_key, 3)
      restarted = self._first_state(
          forwarded.replace(data=data), ready, failures, obs_key, next_key
      )
      if next_reset is None:
        restarted = _reporting(restarted, stepped)
      return episode_lib.tree_select(resets, restarted, stepped)

    def body(i, loop, operands):
      carry, obs_state, stepped, failures = loop
      state, action, keys, next_reset = operands
      # At `i = n` the carry is the prepared restart: its sub-step hooks and
      # integration are computed and dropped (selects on the shared `i`).
      ready = carry
      hooked = self._before_substep(
          self._restore(carry), action, keys, i, fields
      ).carry(fields)
      physics = self._restore(episode_lib.tree_select(i < n, hooked, carry))
      forward_model = _actuation_masked(physics.model, i == n)
      started = None
      if sensors_once:
        started = substep_sensors_lib.IntegrationState.of(physics.data)
        forward_model = substep_sensors_lib.without_sensors(forward_model)
      physics = physics.replace(data=mjx.forward(forward_model, physics.data))
      moved = physics.replace(data=integrate(physics.model, physics.data))
      moved, obs_state = self._after_substep(moved, obs_state, keys, i, fields)
      # The restart's end first: it is the last reader of `ready` and
      # `physics`, whose buffers the control step's end may then overwrite
      # in place (else XLA copies them at every iteration).
      stepped = episode_lib.once_or_never(
          i == n,
          lambda stepped: finish_restart(
              ready, physics, failures, stepped, next_reset
          ),
          stepped,
      )
      carry = episode_lib.tree_select(i < n, moved, physics.carry(fields))
      carry, obs_state, stepped, failures = episode_lib.once_or_never(
          i == n - 1,
          lambda loop: end_step(state, keys, next_reset, started, loop),
          (carry, obs_state, stepped, failures),
      )
      return carry, obs_state, stepped, failures

    start = physics.replace(initialization_failed=jnp.zeros((), bool))
    _, _, stepped, _ = episode_lib.loop_with_reset(
        n,
        body,
        lambda loop, operands: reset_from(loop[2], operands[3])[2],
        (start.carry(fields), state.obs_state, state, jnp.zeros((), jnp.int32)),
        (state, action, keys, next_step_reset),
    )
    return stepped

  # The pieces of a step, shared by `step` and `_step_in_one_loop`.

  @_named_scope
  def _before_step(self, state, action, keys):
    start = self.physics(state)
    physics = self.hooks.scheduled(start, keys.before)
    physics = self.hooks.before_step(physics, action, keys.before)
    _check_step_writes(start, physics, tuple(state.model_fields), 'before_step')
    return physics

  @_named_scope
  def _before_substep(self, physics, action, keys, i, fields):
    sub_key = jax.random.fold_in(keys.substep, i)
    start = physics
    physics = self.hooks.before_substep(
        physics, action, jax.random.fold_in(sub_key, 0)
    )
    _check_step_writes(start, physics, fields, 'before_substep')
    return physics

  @_named_scope
  def _after_substep(self, physics, obs_state, keys, i, fields):
    """After-substep hooks and observation updates: (carry, obs_state)."""
    sub_key = jax.random.fold_in(keys.substep, i)
    start = physics
    physics = self.hooks.after_substep(physics, jax.random.fold_in(sub_key, 1))
    _check_step_writes(start, physics, fields, 'after_substep')
    n = self.n_sub_steps
    if n > 1:
      # Sub-steps 1..n-1 update the observations here; the updater skips,
      # at trace time, every observable that cannot be sampled there. The
      # last sub-step's update comes after the after_step hooks, so there
      # the update is computed and discarded: a select, not a `lax.cond`,
      # which on a GPU costs a host round trip and copies of the
      # observation state at every sub-step (README, Throughput); the
      # discarded update costs one sub-step's samples.
      updated = self.updater.update(
          obs_state,
          physics,
          jax.random.fold_in(sub_key, 2),
          jnp.minimum(i + 1, n - 1),
          substep_bounds=(1, n - 1),
      )
      obs_state = jax.tree.map(
          lambda new, old: jnp.where(i < n - 1, new, old), updated, obs_state
      )
    return physics.carry(fields), obs_state

  @_named_scope
  def _end_step(self, state, physics, obs_state, keys):
    fields = tuple(state.model_fields)
    start = physics
    physics = self.hooks.after_step(physics, keys.after)
    _check_step_writes(start, physics, fields, 'after_step')
    return _state(
        physics,
        fields,
        self.updater.update(obs_state, physics, keys.obs, self.n_sub_steps),
        self.updater,
        keys.next,
        jax.named_scope('episode')(self.episode.end_of_step)(state, physics),
    )


_INTEGRATORS = {  # what `mjx.step` runs after `mjx.forward`
    int(mujoco.mjtIntegrator.mjINT_EULER): mjx.euler,
    int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST): mjx.implicit,
}


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class _StepKeys:
  """A control step's keys, one per use."""

  before: jax.Array
  substep: jax.Array
  after: jax.Array
  obs: jax.Array
  next: jax.Array

  @classmethod
  def split(cls, key):
    return cls(*jax.random.split(key, 5))


def _actuation_masked(model, masked):
  """`model`, where `masked`, with every actuator force zero.

  Zero gains and biases make a (non-muscle) actuator's force zero, and zero
  force ranges keep it there through the clamps, so the forward pass
  computes what it does with actuation disabled: `qfrc_actuator` is zero.
  """
  if not model.nu:
    return model

  def zero_where_masked(x):
    return jnp.where(masked, jnp.zeros_like(x), x)

  fields = ['actuator_gainprm', 'actuator_biasprm', 'actuator_forcerange']
  if model.ntendon:
    fields.append('tendon_actfrcrange')
  return model.replace(
      **{name: zero_where_masked(getattr(model, name)) for name in fields}
  )


def _reporting(restarted, stepped):
  """The restarted `State`, reporting how the ended episode's step ended."""
  return restarted.replace(
      step_type=stepped.step_type,
      reward=stepped.reward,
      discount=stepped.discount,
      terminated=stepped.terminated,
      truncated=stepped.truncated,
      final_observation=stepped.final_observation,
      metrics=stepped.metrics,
  )


def _state(physics, fields, obs_state, updater, key, episode_fields):
  """The `State` of `physics` with its observation and episode fields."""
  observation = updater.get_observation(obs_state)
  return state_lib.State(
      data=physics.data,
      task_state=physics.task_state,
      entity_states=physics.entity_states,
      model_fields={f: getattr(physics.model, f) for f in fields},
      persistent=physics.persistent,
      obs_state=obs_state,
      observation=observation,
      final_observation=observation,
      key=key,
      scheduled_hooks=physics.scheduled_hooks,
      **episode_fields,
  )


def _check_step_writes(before, after, fields, hook_names):
  """Step hooks may update, not add, per-world fields and persistent entries."""
  changed = [
      f.name
      for f in dataclasses.fields(mjx.Model)
      if getattr(after.model, f.name) is not getattr(before.model, f.name)
  ]
  undeclared = sorted(set(changed) - set(fields))
  if undeclared:
    raise ValueError(
        f'The {hook_names} hooks wrote model fields {undeclared} that are not '
        'per-world. Declare them with Environment(..., '
        f'per_world_model_fields={tuple(undeclared)!r}), or write them in '
        'initialize_episode.'
    )
  if after.scheduled_hooks != before.scheduled_hooks:
    raise ValueError(
        f'The {hook_names} hooks scheduled a hook: call '
        'physics.schedule_before_step from initialize_episode.'
    )
  shapes = lambda tree: jax.tree.map(
      lambda x: (jnp.shape(x), jnp.result_type(x)), tree
  )
  for name, old, new in (
      ('persistent', before.persistent, after.persistent),
      ('entity state', before.entity_states, after.entity_states),
  ):
    if jax.tree.structure(old) != jax.tree.structure(new) or shapes(
        old
    ) != shapes(new):
      raise ValueError(
          f'The {hook_names} hooks added, removed or reshaped {name} '
          f'entries (before: {shapes(old)}, after: {shapes(new)}). Create '
          f'every {name} entry with its final shape and dtype (persistent '
          'entries in initialize_episode, entity state in '
          'Entity.initial_state); step hooks may only update it.'
      )


def _select_key(pred, on_true, on_false):
  data = jnp.where(
      pred, jax.random.key_data(on_true), jax.random.key_data(on_false)
  )
  return jax.random.wrap_key_data(data, impl=jax.random.key_impl(on_true))


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
