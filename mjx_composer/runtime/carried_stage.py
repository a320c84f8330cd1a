"""The control step's end-of-step forward stage, carried between physics steps.

After its last physics step a control step recomputes the position stage
of the forward pass (and the velocity stage, where its readers read it) at
the new state (`reset_forward.StepForward`), as composer's physics step
leaves it. `mjx.step` computes that stage again, first thing, at the next
physics step: a control step of `n` sub-steps thus holds two copies of it
in its program, one in the sub-step loop and one after it, and for a
humanoid that second copy is a third of the step program.

Here the stage is computed once per physics step instead, at its end, and
carried: each sub-step runs the rest of the forward pass from the stage the
data already holds (`rest_of_forward`), integrates, and computes the stage
of the new state (`StepForward` without its sensors), which the next
sub-step, the control step's readers and the next control step's first
sub-step use. The stage then has one copy in the program and runs as often
as before (`n` times a control step, and once a reset).

Where the sub-steps also leave the sensors to the control step's end
(`substep_sensors`), the last sub-step's sensors read some of what the
stage of its new state overwrites (its sites' poses, centres of mass). The
stage hands those leaves on (`Stage.run`, `Stage.sensor_inputs`), and the
control step computes the sensors after the sub-steps from them
(`Stage.sensors_of_last`): the sub-step loop holds no branch on which
sub-step is the last.

It holds where the stage a state carries is that of its integration
state whenever a physics step starts (`carries`): every reset computes it
(`Analysis.reset_forward` raises the reset's stage to it), and nothing that
runs between the stage and the physics step that uses it writes what the
stage reads (the step hooks; a step hook's write of a model field turns it
off) or reads what it writes where it would read an older value (the
`before_substep` hooks of sub-steps after the first, which `mjx.step` hands
the stage of the sub-step before). Reordering independent parts of
`mjx.forward` changes no result: the trajectory, observations and rewards
are those of `mjx.step` (`tests/runtime/test_carried_stage.py`). A `State`
edited by hand between steps (its `qpos` set outside the hooks) keeps the
stage of the state it was made from: call `Environment.reset`, or forward
the data, before stepping it.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from mujoco import mjx

from mjx_composer.runtime import data_reads
from mjx_composer.runtime import keys as keys_lib
from mjx_composer.runtime import reset_forward as reset_forward_lib
from mjx_composer.runtime import substep_sensors
from mjx_composer.platform import internals

# The end-of-step stages that can be carried.
STAGES = ('position', 'velocity')


def stage(model: mjx.Model, data: mjx.Data, name: str) -> mjx.Data:
  """`data` with stage `name` (of `STAGES`) computed, sensors skipped."""
  return reset_forward_lib.StepForward(name, sensors=False)(model, data)


@dataclasses.dataclass(frozen=True)
class Stage:
  """The stage a control step's sub-steps carry (`carries`), and what it
  hands on to the sensors of the last sub-step (module docstring).

  Attributes:
    name: one of `STAGES`.
    sensor_inputs: the `mjx.Data` leaves (`data_reads.leaf_names`) that the
      stage overwrites and the last sub-step's sensors read; empty where
      the sub-steps compute their own sensors.
  """

  name: str
  sensor_inputs: frozenset = frozenset()

  def run(self, model: mjx.Model, data: mjx.Data):
    """`(data with the stage computed, {leaf: value before it})` of the
    `sensor_inputs` leaves."""
    kept = data_reads.leaves_named(data, self.sensor_inputs)
    return stage(model, data, self.name), kept

  def sensors_of_last(self, model, data, kept, started, recomputed):
    """`data` (after `run`) with the sensors of the physics step before
    it, as `substep_sensors.sensors_of` computes them from the data before
    the stage: `kept` restores what the stage overwrote of their inputs,
    and the stage reads and writes none of their outputs (`carries`)."""
    sensed = substep_sensors.sensors_of(
        model, data_reads.with_leaves(data, kept), started, recomputed
    )
    return data_reads.with_leaves(
        data, data_reads.leaves_named(sensed, substep_sensors.OUTPUTS)
    )


@jax.named_scope('forward')
def rest_of_forward(model: mjx.Model, data: mjx.Data, name: str) -> mjx.Data:
  """`mjx.forward(model, data)` of `data` whose stage `name` is current.

  The parts of MJX's forward pass that stage `name` does not compute, in
  `mjx.forward`'s order; the stage's own parts do not depend on them, so the
  results are `mjx.forward`'s.
  """
  data = mjx.crb(model, data)
  data = mjx.tendon_armature(model, data)
  data = mjx.factor_m(model, data)
  data = mjx.collision(model, data)
  data = mjx.make_constraint(model, data)
  data = mjx.sensor_pos(model, data)
  if name == 'position':
    data = reset_forward_lib.velocity_part(model, data)
  data = mjx.passive(model, data)
  data = mjx.rne(model, data)
  data = mjx.tendon_bias(model, data)
  data = mjx.sensor_vel(model, data)
  data = mjx.fwd_actuation(model, data)
  data = mjx.fwd_acceleration(model, data)
  if not internals.data_impl(data).efc_J.size:
    return data.replace(qacc=data.qacc_smooth)
  data = mjx.solve(model, data)
  return mjx.sensor_acc(model, data)


def physics_step(model: mjx.Model, data: mjx.Data, name: str) -> mjx.Data:
  """`mjx.step(model, data)` of `data` whose stage `name` is current, without
  the stage of the new state (`stage` computes it)."""
  integrate = substep_sensors.INTEGRATORS[int(model.opt.integrator)]
  return integrate(model, rest_of_forward(model, data, name))


def carries(transitions) -> str | None:
  """The stage `transitions`' control step carries, or None (it recomputes
  its end-of-step stage after its last physics step).

  The latest of `STAGES` up to its end-of-step stage
  (`Transitions.step_forward`) that what runs between the stage and the
  physics step that uses it leaves valid: the step hooks write nothing the
  stage reads, and the `before_substep` hooks read nothing it writes
  (module docstring). None with `carry_stage='never'`, where the backend
  runs the forward pass whole, where `mjx.step` is not a forward pass and
  an integrator (`substep_sensors.INTEGRATORS`) or where a step hook
  writes a model field. Found from abstract traces with the shapes of a reset's `State`
  (`Analysis.reset_shapes`).
  """
  t = transitions
  model = t.initial.model
  end = t.step_forward.stage
  if (
      t.carry_stage == 'never'
      or end not in STAGES
      or not t.backend.staged_forward
      or int(model.opt.integrator) not in substep_sensors.INTEGRATORS
      or t.analysis.reset_shapes.step_writers
  ):
    return None
  state = t.analysis.reset_shapes.state
  data = state.data
  hooks_write = _written_by_step_hooks(t, state)
  read = None
  if t.n_sub_steps > 1:
    read = _read_by_before_substep(t, state).fields
  for name in reversed(STAGES[: STAGES.index(end) + 1]):
    stage_reads, stage_writes = _stage_io(model, data, name)
    if stage_reads & hooks_write:
      continue
    if read is not None and stage_writes & read:
      continue
    return name
  return None


def of(transitions) -> Stage | None:
  """The `Stage` that `transitions`' sub-steps carry (`carries`), or None.

  Its `sensor_inputs`, where the sub-steps leave the sensors to the control
  step's end (`Transitions.sensors_once_per_step`): what the stage writes
  and the sensors read, beyond the integration state that `sensors_of`
  takes from the step's start. Found from traces with the shapes of a
  reset's `State`.
  """
  t = transitions
  name = t.carried_stage
  if name is None:
    return None
  if not t.sensors_once_per_step:
    return Stage(name)
  model = t.initial.model
  data = t.analysis.reset_shapes.state.data
  stage_reads, stage_writes = _stage_io(model, data, name)
  # The sensors of the last sub-step are computed after the stage, from
  # what it kept: it must neither read nor write what they write.
  assert not (stage_reads | stage_writes) & substep_sensors.OUTPUTS, name
  recomputed = t.step_forward.sensor_stages

  def sensors(data, started):
    sensed = substep_sensors.sensors_of(model, data, started, recomputed)
    return data_reads.leaves_named(sensed, substep_sensors.OUTPUTS), ()

  started = jax.eval_shape(substep_sensors.IntegrationState.of, data)
  read = data_reads.reads(sensors, data, started).fields
  return Stage(name, frozenset(read & stage_writes))


def finish(model, data, name, step_forward):
  """`data` whose stage `name` is current, as `step_forward` leaves it: the
  velocity stage where `name` is the position stage and `step_forward`'s
  is the velocity stage, then `step_forward`'s sensors."""
  if name == 'position' and step_forward.stage == 'velocity':
    data = reset_forward_lib.velocity_part(model, data)
  if step_forward.sensors:
    data = mjx.sensor_pos(model, data)
    if step_forward.stage == 'velocity':
      data = mjx.sensor_vel(model, data)
  return data


# `_stage_io`'s answers, for every environment of a model.
_STAGE_IO = data_reads.PerStructure('carried_stage.stage_io')


def _stage_io(model, data, name) -> tuple[frozenset[str], frozenset[str]]:
  """The `mjx.Data` leaves that stage `name` computes its results from, and
  those it writes: one trace of the stage answers both."""

  def compute():
    out = {}

    def computed(data, model):
      staged = stage(model, data, name)
      out['written'] = data_reads.replaced_names(data, staged)
      return data_reads.replaced(data, staged), ()

    # The model is traced as an argument: the answers depend on its
    # structure only.
    read = data_reads.reads(computed, data, model).fields
    if 'written' not in out:  # `reads` traced nothing (no dead-code pass)
      out['written'] = reset_forward_lib.written(
          name, model, data, False, after_step=True
      )
    return read, out['written']

  key = (
      name,
      data_reads.structure_key(model),
      data_reads.structure_key(data),
  )
  return _STAGE_IO(key, compute)


def _action(t):
  return jax.ShapeDtypeStruct(t.action_shape, jnp.float32)


def _written_by_step_hooks(t, state) -> frozenset[str]:
  """The `mjx.Data` leaves the step hooks that run between the stage and a
  physics step write: `after_step`, the scheduled ones, `before_step` and
  `before_substep`. `state`: a `State`'s shapes."""
  written = set()

  def note(before, after):
    written.update(data_reads.replaced_names(before, after))

  def run(state, key, action):
    keys = keys_lib.StepKeys.split(key)
    fields = tuple(state.model_fields)
    physics = t.physics(state)
    note(physics.data, t.hooks.after_step(physics, keys.after).data)
    note(state.data, t.before_step(state, action, keys).data)
    hooked = t.before_substep(physics, action, keys, 0, fields)
    note(physics.data, hooked.data)
    return ()

  jax.eval_shape(run, state, keys_lib.key_shape(), _action(t))
  return frozenset(written)


def _read_by_before_substep(t, state) -> data_reads.Reads:
  """What the `before_substep` hooks read of `mjx.Data` (beyond what they
  pass on untouched to the physics step)."""
  index = jax.ShapeDtypeStruct((), jnp.int32)

  def readers(data, state, key, action, i):
    keys = keys_lib.StepKeys.split(key)
    fields = tuple(state.model_fields)
    after = t.before_substep(
        t.physics(state.replace(data=data)), action, keys, i, fields
    ).carry(fields)
    written = data_reads.replaced(data, after.data)
    return (after.replace(data=None), written), after.data

  return data_reads.reads(
      readers, state.data, state, keys_lib.key_shape(), _action(t), index
  )
