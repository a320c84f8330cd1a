"""The analyses of shapes that decide what an environment's programs compute.

A `Transitions` runs one world's reset and step; what those programs hold
is decided here, once per environment, by abstract traces that read shapes
only (`jax.eval_shape`, and the readers' jaxprs, `data_reads`), never
values:

* `reset_shapes`: the shapes of a reset's carry and `State`, and the model
  fields that the `initialize_episode` hooks and the step hooks make
  per-world (`per_world_model_fields`, `step_model_fields`);
* `reset_forward`: the stage of the forward pass a reset runs (the
  cheapest that computes what the first state's readers read;
  `runtime.reset_forward`);
* `sensors_once_per_step`: whether the sub-steps leave the sensors to the
  control step's end (`runtime.substep_sensors`);
* `step_forward`: what a control step recomputes after its last physics
  step (`reset_forward.after_step`, `runtime.dirty_forward`);
* `carried_stage`: whether the control step computes that stage at the end
  of every physics step and carries it to the next, instead of recomputing
  it after its last (`runtime.carried_stage`), and `carried`, what it hands
  on to the sensors of the last sub-step;
* `stored_restart`: whether an auto-reset restores a copy of the world's
  first state instead of running the reset (`runtime.stored_restart`).

Each runs on first use (building stays cheap for an environment that is
never traced) or all at once (`analyse`), and answers the same whenever it
runs, whichever program is traced first. The backend decides some without
tracing: a forward pass that cannot run stage by stage
(`Backend.staged_forward`) is always whole.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp

from mjx_composer.runtime import carried_stage as carried_stage_lib
from mjx_composer.runtime import data_reads
from mjx_composer.runtime import keys as keys_lib
from mjx_composer.runtime import reset_forward as reset_forward_lib
from mjx_composer.runtime import stored_restart as stored_restart_lib
from mjx_composer.runtime import substep_sensors as substep_sensors_lib

# Where the declared per-world model fields come from, in
# `per_world_model_fields`.
DECLARED = 'ExecutionOptions(per_world_model_fields=...)'


@dataclasses.dataclass(frozen=True)
class ResetShapes:
  """What an abstract trace of a reset finds (`Analysis.reset_shapes`).

  Attributes:
    carry: the shapes of the initialized `PhysicsCarry`.
    failures: the shape of the failed attempts' count.
    state: the shapes of the reset's `State`.
    writers: `{model field: the initialize_episode hooks that write it}`.
    physics_drawn: whether the physics an initialization attempt leaves
      (its data, whether it failed) may depend on its key (dead-code
      elimination of the attempt's jaxpr; True where it cannot tell).
    step_writers: `{model field: the step hooks that write it}`
      (`hooks.EnvironmentHooks.step_model_field_writers`).
  """

  carry: Any
  failures: Any
  state: Any
  writers: dict
  physics_drawn: bool = True
  step_writers: dict = dataclasses.field(default_factory=dict)


class Analysis:
  """The analyses of shapes of one `Transitions` (module docstring).

  Args:
    transitions: the `Transitions` whose programs they shape; its pieces
      (hooks, first state, step pieces) are what they trace.
  """

  def __init__(self, transitions):
    self._t = transitions

  def analyse(self) -> 'Analysis':
    """Runs every analysis now (each otherwise runs on first use).

    `reset_shapes` (the reset's `initialize_episode` hooks and the step
    hooks, traced abstractly), `reset_forward`, `sensors_once_per_step`,
    `step_forward`, `carried_stage` and `carried` (their readers' jaxprs),
    `stored_restart` (the reset's jaxpr). They read
    shapes only, so they answer the same whenever they run; running them at
    build keeps their traces out of the first trace of `reset` or `step`. Raises what tracing
    those hooks raises.
    """
    for analysis in (
        'reset_shapes',
        'reset_forward',
        'sensors_once_per_step',
        'step_forward',
        'carried_stage',
        'carried',
        'stored_restart',
    ):
      getattr(self, analysis)
    return self

  @functools.cached_property
  def reset_shapes(self) -> ResetShapes:
    """The shapes of a reset (`ResetShapes`), from abstract traces of its
    `initialize_episode` hooks and of its first state, and of the step
    hooks on that state: the model fields that step hooks write are
    per-world from the reset on (traced again with them, where the reset's
    hooks do not write them too)."""
    shapes = self._reset_shapes(self._t.declared_model_fields)
    step_writers = self._t.hooks.step_model_field_writers(
        self._t.physics(shapes.state),
        shapes.state.key,
        jax.ShapeDtypeStruct(self._t.action_shape, jnp.float32),
    )
    if set(step_writers) - set(shapes.carry.model_fields):
      shapes = self._reset_shapes(
          tuple(sorted(set(self._t.declared_model_fields) | set(step_writers)))
      )
    return dataclasses.replace(shapes, step_writers=step_writers)

  @functools.cached_property
  def step_model_fields(self) -> tuple[str, ...]:
    """The model fields per-world whatever the `initialize_episode` hooks
    write: the declared ones and those the step hooks write."""
    return tuple(
        sorted(
            set(self._t.declared_model_fields)
            | set(self.reset_shapes.step_writers)
        )
    )

  def _reset_shapes(self, step_fields) -> ResetShapes:
    """`reset_shapes` with `step_fields` per-world (see `_attempt`)."""
    writers = {}

    def initialize(key):
      carry = self._t._attempt(
          key, self._t.start_carry(None, key), writers, step_fields
      )
      return carry, carry.initialization_failed.astype(jnp.int32)

    attempt, (carry, failures) = jax.make_jaxpr(initialize, return_shape=True)(
        keys_lib.key_shape()
    )

    def first(carry, failures, key):
      physics = self._t.restore(carry)
      return self._t.first_state(
          physics, carry, failures, keys_lib.ResetKeys.split(key)
      )

    state = jax.eval_shape(first, carry, failures, keys_lib.key_shape())
    physics = (carry.data, carry.initialization_failed, failures)
    return ResetShapes(
        carry,
        failures,
        state,
        writers,
        physics_drawn=data_reads.depends_on_inputs(
            attempt, (carry, failures), physics
        ),
    )

  def per_world_model_fields(self) -> dict[str, tuple[str, ...]]:
    """`{model field: what made it per-world}`: the `initialize_episode`
    and step hooks that write it, and `DECLARED` for
    `declared_model_fields`."""
    fields = dict(self.reset_shapes.writers)
    for name, labels in self.reset_shapes.step_writers.items():
      fields[name] = fields.get(name, ()) + labels
    for name in self._t.declared_model_fields:
      fields[name] = fields.get(name, ()) + (DECLARED,)
    return dict(sorted(fields.items()))

  @functools.cached_property
  def reset_forward(self) -> reset_forward_lib.ResetForward:
    """The stage of the forward pass that a reset runs.

    With `reset_forward_mode='observed'`, the cheapest stage that computes
    what the FIRST state's readers read (`_read_after_reset`), and at least
    the stage the control step carries (`carried_stage`); 'full' on MuJoCo
    Warp, whose forward pass is one kernel sequence.
    """
    model, data = self._t.initial.model, self._t.initial.data
    if (
        self._t.reset_forward_mode == 'full'
        or not self._t.backend.staged_forward
    ):
      # The full pass restricts nothing: no need to trace what it writes.
      return reset_forward_lib.ResetForward(
          'full', True, frozenset(), frozenset()
      )
    read = self._read_after_reset()
    chosen = reset_forward_lib.choose_stage(
        read.fields,
        model,
        data,
        self._t.initial.index.mj_model,
        sensordata=read.sensordata,
    )
    if self.carried_stage is None:
      return chosen
    return chosen.at_least(
        self.carried_stage, model, data, self._t.initial.index.mj_model
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
    shapes = self.reset_shapes
    action = jax.ShapeDtypeStruct(self._t.action_shape, jnp.float32)

    def readers(data, carry, failures, key, action):
      physics = self._t.restore(carry.replace(data=data))
      reset_keys = keys_lib.ResetKeys.split(key)
      first = self._t.first_state(physics, carry, failures, reset_keys)
      metrics = dict(first.metrics)
      diverged = metrics.pop('diverged')
      keys = keys_lib.StepKeys.split(first.key)
      fields = tuple(first.model_fields)
      before = self._t.before_step(first, action, keys)
      before = self._t.before_substep(before, action, keys, 0, fields)
      after = before.carry(fields)
      written = data_reads.replaced(data, after.data)
      read = (
          first.replace(data=None, metrics=metrics),
          after.replace(data=None),
          written,
      )
      return read, (first.data, diverged)

    return data_reads.reads(
        readers,
        shapes.carry.data,
        shapes.carry,
        shapes.failures,
        keys_lib.key_shape(),
        action,
    )

  @functools.cached_property
  def sensors_once_per_step(self) -> bool:
    """Whether the sub-steps leave the sensors to the control step's end
    (in `step` and in the fused restart's loop): with
    `substep_sensors='read'`, where `substep_sensors.once_per_step` finds
    that nothing between two sub-steps' physics needs them."""
    if self._t.substep_sensors == 'all':
      return False
    return substep_sensors_lib.once_per_step(self._t)

  @functools.cached_property
  def step_forward(self) -> reset_forward_lib.StepForward:
    """What a control step recomputes after its last physics step, so that
    its readers see the position and velocity stages of the new state, as
    after composer's `Physics.step`, and the acceleration stage too where
    composer's physics is dirty after it (`reset_forward.after_step`)."""
    return reset_forward_lib.after_step(self._t)

  @functools.cached_property
  def carried_stage(self) -> str | None:
    """The stage of the forward pass the control step computes at the end
    of every physics step and carries to the next (`step_forward`'s), or
    None where it recomputes it after its last (`carried_stage.carries`)."""
    return carried_stage_lib.carries(self._t)

  @functools.cached_property
  def carried(self) -> carried_stage_lib.Stage | None:
    """`carried_stage` with what it hands on to the last sub-step's sensors
    (`carried_stage.of`), or None."""
    return carried_stage_lib.of(self._t)

  @functools.cached_property
  def stored_restart(self) -> stored_restart_lib.Plan | None:
    """How an auto-reset restores a copy of the world's first state, or None
    where it runs the reset (`stored_restart.plan`)."""
    return stored_restart_lib.plan(self._t)
