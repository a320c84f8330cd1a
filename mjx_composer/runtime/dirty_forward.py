"""Composer's dirty-flag forward pass after a control step.

dm_control's `mjcf.Physics` marks itself dirty when a binding writes an
input of the forward pass (`ctrl`, `qpos`, `qvel`, `act`, `qfrc_applied`,
`xfrc_applied`, or a model field but the visual ones), and runs `mj_forward`
before the next binding read of anything else. `Physics.step` neither runs
it nor clears the mark. Every dm_control walker applies its action with
`physics.bind(actuators).ctrl = action`; so where nothing reads through a
binding between that write and the end of the control step's sub-steps,
the first binding read after them (an observable, the reward) runs
`mj_forward` on the new state: the acceleration stage (`qacc`, actuator
and constraint forces, contacts, accelerometers, touch, force and torque
sensors) read after such a step is of the NEW state, where after
`physics.set_control(action)` (which marks nothing) it is that of the
state the last physics step started from.

This module tells, at trace time, whether composer's physics is dirty
when a control step's sub-steps end (`dirty_after_substeps`): it traces
the hooks that run until then, in composer's order, with
`bindings.recording_dirty_events` open, and replays what they record
(`replay`). `reset_forward.after_step` then ends such a control step with
the full forward pass of the new state where its readers read, through a
binding, what only the acceleration stage computes
(`forwarding_read`, `reset_forward.reads_acceleration`). A control step
starts clean: composer's reset ends with a forward pass, and a control
step's readers, which read through bindings, clear what it leaves.

`ExecutionOptions(dirty_forward='never')` keeps the step's own values
instead (MJX's `mj_step` timing, one forward pass fewer per control step).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mjx_composer.physics import bindings
from mjx_composer.runtime import keys as keys_lib

MODES = ('composer', 'never')


def replay(events, dirty: bool = False) -> bool:
  """Composer's dirty flag after `events` (`bindings.recording_dirty_events`),
  from `dirty`: a dirtying write sets it, a forwarding read or a forward
  pass clears it."""
  for kind, _ in events:
    if kind == bindings.DIRTYING_WRITE:
      dirty = True
    elif kind in (bindings.FORWARDING_READ, bindings.FORWARD):
      dirty = False
  return dirty


def forwarding_read(events) -> bool:
  """Whether `events`, recorded while composer's physics is dirty, run its
  forward pass at a binding read (rather than in a forward pass of the
  hooks' own, whose results the later readers then read; or never)."""
  for kind, _ in events:
    if kind == bindings.FORWARDING_READ:
      return True
    if kind == bindings.FORWARD:
      return False
  return False


def dirty_after_substeps(transitions) -> bool:
  """Whether composer's physics is dirty when `transitions`' sub-steps end
  (before the `after_step` hooks).

  Traces (shapes only) what composer runs until then: the scheduled and
  `before_step` hooks, then for each sub-step `before_substep` and
  `after_substep`, and for every sub-step but the last the observation
  update after it (the observables sampled there, as `Updater.update`
  samples them at that sub-step). The physics steps themselves touch no
  binding. A sub-step's hooks see the sub-step's index as a Python int
  here (a traced one in the step program); hooks cannot branch on it in
  Python there, so they access the same bindings.
  """
  t = transitions
  state = t.analysis.reset_shapes.state
  n = t.n_sub_steps
  recorded = {}

  def control_step(state, key, action):
    keys = keys_lib.StepKeys.split(key)
    fields = tuple(state.model_fields)
    with bindings.recording_dirty_events() as events:
      physics = t.before_step(state, action, keys)
      for i in range(n):
        # As the sub-step loop carries it (a `PhysicsCarry`).
        physics = t.restore(physics.carry(fields))
        physics = t.before_substep(physics, action, keys, i, fields)
        sub_keys = keys.of_substep(i)
        # The physics step: new data of the same shapes, nothing recorded.
        physics = physics.replace(data=physics.data)
        physics = t.hooks.after_substep(physics, sub_keys.after())
        if i < n - 1:
          t.updater.update(state.obs_state, physics, sub_keys.obs(), i + 1)
    recorded['events'] = list(events)
    return physics.data

  jax.eval_shape(
      control_step,
      state,
      keys_lib.key_shape(),
      jax.ShapeDtypeStruct(t.action_shape, jnp.float32),
  )
  return replay(recorded['events'])
