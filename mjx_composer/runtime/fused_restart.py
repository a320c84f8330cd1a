"""The auto-reset fused into the sub-step loop: one forward pass per program.

`Transitions.step` then `Transitions.restart` (or `reset`) holds two copies
of MuJoCo's forward pass in the step program: the sub-steps', and the
reset's. Here they are one: the sub-steps run `mjx.forward` then the
integrator in a `lax.while_loop`, and the reset is one more iteration of
that loop, whose forward pass runs with every actuator force masked to zero
(`actuation_masked`), as composer's reset runs `mj_forward` with actuation
disabled. Two entry points:

* `step_and_restart` (same-step auto-reset): `step`, then `restart` where
  the episode ended;
* `reset_or_step` (next-step auto-reset): `reset` where the state is LAST,
  else `step`.

Both compute what the composition they replace computes, in another
arrangement of the same operations: where XLA compiles the two programs'
arithmetic alike, the states are bit-identical (the tests' swing task,
`tests/runtime/test_transitions.py`); where it fuses a model's forward pass
differently (the humanoid's contacts and constraint solver on a CPU), they
agree to float rounding, which the solver's accelerations amplify. They
need an integrator that `mjx.step` runs after `mjx.forward`
(`substep_sensors.INTEGRATORS`), no muscles and no actuator gravity
compensation (`can_fuse`).

The loop, over `i` (`control_flow.loop_with_reset`): iterations `0..n-1`
are the sub-steps (before-substep hooks, forward pass, integrator,
after-substep hooks and observation update); after them the control step
ends and, where some world wants a reset, the reset is prepared (the
`initialize_episode` hooks, randomization included); then, only where some
world wants it, the reset's forward pass runs, with actuation masked.
Where the sub-steps carry the end-of-step stage (`carried_stage`: each
forward pass runs from the stage its data holds, and each sub-step
computes the stage of its new state), the reset takes two iterations: `n`
computes the prepared reset's stage, with the same copy of the stage the
sub-steps use, and `n + 1` runs the rest of its forward pass (the stage
runs at every iteration: after the reset's forward pass it is computed
again, of the same state); else it is iteration `n`.

The iterations run in two phases, the sub-steps and the reset's, each a
loop whose body is the iteration alone; the step's end, the reset's
preparation and its end run between them. Where a stage is carried, each
phase's loop is followed by `Transitions.after_physics` (the sensors the
loop skipped, the end-of-step stage), one copy for the stepped state and
the reset's. The ends run in loops run once or never
(`control_flow.once_or_never`; conditionals, `control_flow.run_if`, in a
program for a CPU) on conditions shared by the batch (the phase,
`control_flow.batch_any`). The world's model is not in the inner loop's
carry: the model fields that no step hook writes are the same through a
phase (the reset's preparation replaces them between the phases), so XLA
computes what the forward pass derives from them alone (the model's
gathers) once a phase, not at every sub-step. The physics, which runs at
every iteration but `n` where a stage is carried, is a conditional on the
counter (`control_flow.run_unless`). Nothing is computed for every world at
every sub-step but the sub-step itself and selects on the counter.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np

from mjx_composer.runtime import carried_stage
from mjx_composer.runtime import control_flow
from mjx_composer.runtime import data_reads
from mjx_composer.runtime import episode as episode_lib
from mjx_composer.runtime import keys as keys_lib
from mjx_composer.runtime import state as state_lib
from mjx_composer.runtime import substep_sensors


def can_fuse(transitions) -> bool:
  """Whether the restart of `transitions`' model fuses exactly.

  The masked forward pass equals the forward pass with actuation disabled
  only where zero gains, biases and force ranges make every actuator force
  zero, and the loop's integrator must be `mjx.step`'s.
  """
  if int(transitions.initial.model.opt.integrator) not in (
      substep_sensors.INTEGRATORS
  ):
    return False
  m = transitions.initial.index.mj_model
  if np.any(m.actuator_gaintype == mujoco.mjtGain.mjGAIN_MUSCLE) or np.any(
      m.actuator_biastype == mujoco.mjtBias.mjBIAS_MUSCLE
  ):
    return False  # a muscle's force is not zero when its parameters are
  # Actuator-level gravity compensation adds to the actuator forces.
  return not np.any(m.jnt_actgravcomp)


def step_and_restart(
    transitions, state, action, conditional=False
) -> state_lib.State:
  """`step`, then `restart` where the episode ended (same-step auto-reset).

  The same as `select(last, restart(stepped), stepped)` of `stepped =
  step(state, action)`. `conditional`: the parts that run at one iteration
  are `control_flow.run_if`s, not loops run once or never
  (`control_flow.branch_once`: for a program compiled for a CPU).
  """
  return _FusedLoop(transitions, state, conditional).run(state, action, None)


def reset_or_step(
    transitions, state, action, conditional=False
) -> state_lib.State:
  """`reset` where `state` is LAST, else `step` (next-step auto-reset).

  With `reset_key, step_key = keys.next_step_keys(state.key)`, the same as
  `select(state.last(), reset(reset_key, previous=state), step(state with
  step_key, action))`: a world that resets discards its sub-steps, as the
  select does. `conditional`: as for `step_and_restart`.
  """
  reset_key, step_key = keys_lib.next_step_keys(state.key)
  return _FusedLoop(transitions, state, conditional).run(
      state.replace(key=step_key), action, (reset_key, state)
  )


def actuation_masked(model, masked):
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


class _Loop(NamedTuple):
  """What the fused loop carries (`control_flow.loop_with_reset`).

  Attributes:
    carry: the world's `PhysicsCarry` (the sub-steps', then the prepared
      restart's) without the model fields that no step hook writes, which
      are the loop's invariants (`_FusedLoop._split`).
    obs_state: the observation state.
    started: the `IntegrationState` the last sub-step started from, where
      the sensors are computed once per control step (else None).
    kept: what the carried stage overwrote of the last sub-step's sensor
      inputs (`carried_stage.Stage.run`).
    stepped: the `State` returned: the stepped one, then the restarted one
      where the world restarts.
    failures: the restart's failed initialization attempts.
    before: the leaves of the prepared restart's data that the restart's
      end reads (`_FusedLoop._finish_restart`).
  """

  carry: Any
  obs_state: Any
  started: Any
  kept: dict
  stepped: Any
  failures: Any
  before: dict


class _Operands(NamedTuple):
  """What the fused loop reads and never changes.

  Attributes:
    state: the state the control step starts from.
    action: the action the step runs.
    keys: the step's `keys.StepKeys`.
    next_reset: None for a same-step restart (of the stepped state, where
      it is LAST, with its key), else `(reset_key, previous)`, a next-step
      reset of `previous` (where it is LAST, with `reset_key`).
    action_nonfinite: whether the given action was not finite
      (`episode.checked_action`).
  """

  state: Any
  action: Any
  keys: Any
  next_reset: Any
  action_nonfinite: Any


class _FusedLoop:
  """One control step's loop of sub-steps and a restart (module docstring):
  a `_Loop` over `_Operands`, with the world's invariant model fields."""

  def __init__(self, transitions, state, conditional):
    self._t = transitions
    self._conditional = conditional
    self._n = transitions.n_sub_steps
    self._fields = tuple(state.model_fields)
    # The model fields that some step hook writes: the others stay the same
    # through the sub-steps, and through the restart's iterations.
    self._written = frozenset(transitions.analysis.reset_shapes.step_writers)
    # What the restart's end reads of the prepared restart's data: what
    # `mjx.forward` with actuation disabled leaves of the actuator forces,
    # and what the reset's stage of the forward pass leaves of its data.
    self._before = transitions.reset_forward.read_before() | {'actuator_force'}
    self._integrate = substep_sensors.INTEGRATORS[
        int(transitions.initial.model.opt.integrator)
    ]
    self._carried = transitions.carried
    # The iteration whose forward pass is the restart's: the one after the
    # sub-steps, or where they carry a stage, the one after the iteration
    # that computes the prepared restart's stage.
    self._restart_at = self._n + (self._carried is not None)
    # Where a stage is carried, `Transitions.after_physics` is exact for the
    # restart too (`_after_physics`): both phases end with its one copy.
    self._closes = self._carried is not None

  def run(self, state, action, next_reset):
    """The loop from `state` (whose key is the step's)."""
    t = self._t
    action, action_nonfinite = episode_lib.checked_action(action)
    keys = keys_lib.StepKeys.split(state.key)
    physics = t.before_step(state, action, keys)
    start = physics.replace(initialization_failed=jnp.zeros((), bool))
    carry, fixed = self._split(start.carry(self._fields))
    started = None
    if t.sensors_once_per_step:
      started = substep_sensors.IntegrationState.of(physics.data)
    kept = {}
    if self._carried is not None:
      kept = data_reads.leaves_named(physics.data, self._carried.sensor_inputs)
    loop = control_flow.loop_with_reset(
        self._n,
        self.body,
        self._end_step,
        self._prepare_restart,
        self._finish_restart,
        _Loop(
            carry=carry,
            obs_state=state.obs_state,
            started=started,
            kept=kept,
            stepped=state,
            failures=jnp.zeros((), jnp.int32),
            before=data_reads.leaves_named(physics.data, self._before),
        ),
        fixed,
        _Operands(state, action, keys, next_reset, action_nonfinite),
        extra=self._restart_at - self._n + 1,
        conditional=self._conditional,
        close=self._after_physics if self._closes else None,
    )
    return loop.stepped

  def _split(self, carry):
    """`(carry, fixed)`: `carry` without the model fields that no step hook
    writes, and those fields, which stay the same through each phase of
    the loop."""
    fields = carry.model_fields
    fixed = {k: v for k, v in fields.items() if k not in self._written}
    written = {k: v for k, v in fields.items() if k in self._written}
    return carry.replace(model_fields=written), fixed

  @staticmethod
  def _merge(carry, fixed):
    """The whole `PhysicsCarry` of a `_split` one."""
    return carry.replace(model_fields={**fixed, **carry.model_fields})

  def body(self, i, loop, fixed, operands):
    """Iteration `i` of the loop (`body`, as the lowered program names it)."""
    t, n, fields = self._t, self._n, self._fields
    carry = self._merge(loop.carry, fixed)
    obs_state, started, kept = loop.obs_state, loop.started, loop.kept
    action, keys = operands.action, operands.keys
    # From `i = n` the carry is the prepared restart: its sub-step hooks and
    # integration are computed and dropped (selects on the shared `i`).
    hooked = t.before_substep(t.restore(carry), action, keys, i, fields).carry(
        fields
    )
    physics = t.restore(control_flow.tree_select(i < n, hooked, carry))
    if t.sensors_once_per_step:
      started = substep_sensors.IntegrationState.of(physics.data)
    carry, obs_state = self._physics_step(i, physics, obs_state, keys)
    if self._carried is not None:
      # The stage of the sub-step's new state, or at `i = n` of the
      # prepared restart, whose forward pass the next iteration runs from
      # it; after that forward pass it is computed again, of the same
      # state (the loop ends there), cheaper than a branch at every
      # iteration.
      data, kept = t.end_substep(t.restore(carry).model, carry.data)
      carry = carry.replace(data=data)
    return loop._replace(
        carry=self._split(carry)[0],
        obs_state=obs_state,
        started=started,
        kept=kept,
    )

  def _physics_step(self, i, physics, obs_state, keys):
    """`(carry, obs_state)` after iteration `i`'s physics: the forward pass
    (with actuation masked at the restart's), then at a sub-step the
    integrator and the `after_substep` hooks and observation update.

    Where the sub-steps carry a stage, the forward pass starts from it
    (`carried_stage.rest_of_forward`), and the iteration that computes the
    prepared restart's stage (`i = n`) runs none of this.
    """
    t, fields = self._t, self._fields

    def run(loop):
      carry, obs_state = loop
      physics = t.restore(carry)
      model = actuation_masked(physics.model, i == self._restart_at)
      if t.sensors_once_per_step:
        model = substep_sensors.without_sensors(model)
      if self._carried is None:
        data = mjx.forward(model, physics.data)
      else:
        data = carried_stage.rest_of_forward(
            model, physics.data, self._carried.name
        )
      forwarded = physics.replace(data=data)
      moved = forwarded.replace(data=self._integrate(physics.model, data))
      moved, obs_state = t.after_substep(moved, obs_state, keys, i, fields)
      return (
          control_flow.tree_select(i < self._n, moved, forwarded.carry(fields)),
          obs_state,
      )

    start = (physics.carry(fields), obs_state)
    if self._carried is None:
      return run(start)
    # It runs at every iteration but one: a conditional reads `i` once where
    # a loop run once reads it twice, and leaves the carry fewer copies.
    return control_flow.run_unless(i == self._n, run, start)

  def _reset_from(self, stepped, next_reset):
    """(key, previous state, whether it resets) of the reset iteration."""
    if next_reset is None:
      return (
          self._t.episode_key(stepped.key, stepped),
          stepped,
          stepped.last(),
      )
    reset_key, previous = next_reset
    return (
        self._t.episode_key(reset_key, previous),
        previous,
        previous.last(),
    )

  def _after_physics(self, loop, fixed, operands):
    """The loop after a phase's iterations, its data as
    `Transitions.after_physics` leaves it: the stepped state's, then the
    restart's.

    Where the sub-steps carry a stage, that is the restart's data as its
    forward pass leaves it, with the sensors the loop skipped: the restart's
    last iteration integrates nothing and computes the stage of the state
    its forward pass ran from, so the integration state it started from and
    what the stage overwrote (`started`, `kept`) are of that state, and
    what `after_physics` computes again at the new state (the velocity
    stage, the position and velocity sensors) has the values the forward
    pass computed. One copy in the program for both phases' ends.
    """
    del operands
    t = self._t
    moved = t.after_physics(
        t.restore(self._merge(loop.carry, fixed)), loop.started, loop.kept
    )
    return loop._replace(carry=loop.carry.replace(data=moved.data))

  def _end_step(self, loop, fixed, operands):
    """The loop with the stepped `State`, and whether the world restarts."""
    t = self._t
    moved = t.restore(self._merge(loop.carry, fixed))
    if not self._closes:
      moved = t.after_physics(moved, loop.started, loop.kept)
    stepped = t.end_step(
        operands.state,
        moved,
        loop.obs_state,
        operands.keys,
        operands.action_nonfinite,
    )
    resets = self._reset_from(stepped, operands.next_reset)[2]
    return loop._replace(stepped=stepped), resets

  def _prepare_restart(self, loop, fixed, operands):
    """The loop and its invariants for the restart's iterations: the
    initialized carry of the restart, its failed attempts, and what its
    end reads of it."""
    del fixed  # the restart's model replaces the step's
    t = self._t
    reset_key, previous, _ = self._reset_from(loop.stepped, operands.next_reset)
    keys = keys_lib.ResetKeys.split(reset_key)
    carry, failures = t.initialize(keys.init, t.start_carry(previous))
    before = data_reads.leaves_named(carry.data, self._before)
    carry, fixed = self._split(carry)
    return (
        loop._replace(carry=carry, failures=failures, before=before),
        fixed,
    )

  def _finish_restart(self, loop, fixed, operands):
    """The loop with the restarted state where the world resets."""
    t = self._t
    stepped, next_reset, before = loop.stepped, operands.next_reset, loop.before
    reset_key, _, resets = self._reset_from(stepped, next_reset)
    whole = self._merge(loop.carry, fixed)
    forwarded = t.restore(whole)
    if t.sensors_once_per_step and not self._closes:
      # The loop's forward pass skipped them (`_after_physics` computes
      # them where a stage is carried).
      forwarded = forwarded.replace(
          data=t.reset_forward.sensors_of(forwarded.model, forwarded.data)
      )
    # What `mjx.forward` leaves with actuation disabled.
    data = forwarded.data.replace(
        act_dot=jnp.zeros_like(forwarded.data.act_dot),
        actuator_force=before['actuator_force'],
    )
    # What the reset's stage of the forward pass leaves (`Transitions.reset`).
    data = t.reset_forward.restrict(data, data_reads.with_leaves(data, before))
    restarted = t.first_state(
        forwarded.replace(data=data),
        whole,
        loop.failures,
        keys_lib.ResetKeys.split(reset_key),
    )
    if next_reset is None:
      restarted = episode_lib.reporting(restarted, stepped)
    return loop._replace(
        stepped=control_flow.tree_select(resets, restarted, stepped)
    )
