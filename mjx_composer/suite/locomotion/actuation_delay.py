"""Actuation delay: the actuators act on controls set some sub-steps ago.

Real motors react late: the command a policy sends reaches the joints after
a transport and processing delay, which varies between robots. mjlab and
Isaac Lab model it as a delay of the actuation in physics steps, drawn per
episode. `ActuationDelay` does that for any set of actuators: each world
draws a delay of `d` sub-steps, uniformly from `delay_range`, at every
episode's start, and sub-step `t` of the episode then runs with the controls
that the task set for sub-step `t - d` (the episode's initial controls
before its start).

The task calls it from its hooks, after setting its controls:

* `initialize_episode`: `delay.reset(physics, key)` (draws the delay and
  fills the history with the initial controls);
* `before_substep`: `delay.before_substep(physics)` (records the task's
  controls, applies the delayed ones);
* `after_substep`: `delay.after_substep(physics)` (puts the task's controls
  back, so that `data.ctrl` always reads what the task set).

Its entries (the drawn delay and the history of the controls) live in the
task's state: merge `delay.initial_state()` into `initial_task_state()`.
"""

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer.utils import validation

_OWNER = 'ActuationDelay'


class ActuationDelay:
  """A per-world, per-episode delay of some actuators' controls.

  Args:
    actuators: the actuators to delay (MjSpec actuator handles, e.g. a
      robot's `actuators`); the others act at once.
    delay_range: (low, high), inclusive, of the delay in physics sub-steps;
      each episode draws an integer uniformly from it.
    name: the task-state entries' prefix (`<name>_steps`,
      `<name>_history`).
  """

  def __init__(self, actuators, delay_range=(0, 2), name='actuation_delay'):
    if isinstance(actuators, (str, bytes)) or not hasattr(
        actuators, '__iter__'
    ):
      raise TypeError(
          f'{_OWNER}: actuators must be a list of actuators, got '
          f'{actuators!r}. Pass e.g. robot.actuators.'
      )
    self.actuators = list(actuators)
    if not self.actuators:
      raise ValueError(
          f'{_OWNER}: actuators is empty: pass the actuators to delay, e.g. '
          'robot.actuators.'
      )
    if (
        isinstance(delay_range, (str, bytes))
        or np.ndim(delay_range) != 1
        or len(delay_range) != 2
    ):
      raise TypeError(
          f'{_OWNER}: delay_range must be a (low, high) pair of integers, '
          f'got {delay_range!r}. Pass e.g. (0, 2).'
      )
    low = validation.check_integer(
        'delay_range[0]', delay_range[0], owner=_OWNER, minimum=0
    )
    high = validation.check_integer(
        'delay_range[1]', delay_range[1], owner=_OWNER, minimum=0
    )
    if low > high:
      raise ValueError(
          f'{_OWNER}: delay_range must have low <= high, got {delay_range!r}.'
          f' Swap the bounds: ({high}, {low}).'
      )
    self.delay_range = (low, high)
    if not isinstance(name, str) or not name:
      raise TypeError(
          f'{_OWNER}: name must be a non-empty string, got {name!r}.'
      )
    self.name = name

  @property
  def max_delay(self):
    return self.delay_range[1]

  def initial_state(self):
    """The task-state entries (merge them into `initial_task_state`).

    `<name>_steps`: this episode's delay in sub-steps; `<name>_history`:
    the controls set for the last `max_delay + 1` sub-steps, newest first.
    """
    return {
        f'{self.name}_steps': jnp.zeros((), jnp.int32),
        f'{self.name}_history': jnp.zeros(
            (self.max_delay + 1, len(self.actuators)), jnp.float32
        ),
    }

  def steps(self, physics):
    """This world's delay in sub-steps (an int32 scalar)."""
    return physics.task_state[f'{self.name}_steps']

  def reset(self, physics, key):
    """Draws the episode's delay; the past controls are the current ones.

    Call at the end of `initialize_episode`, once the initial controls are
    set.
    """
    low, high = self.delay_range
    steps = jax.random.randint(key, (), low, high + 1, jnp.int32)
    control = physics.bind(self.actuators).ctrl.astype(jnp.float32)
    history = jnp.broadcast_to(control, (self.max_delay + 1, control.size))
    return physics.update_task_state(
        **{f'{self.name}_steps': steps, f'{self.name}_history': history}
    )

  def before_substep(self, physics):
    """Records the task's controls and applies those of `d` sub-steps ago."""
    state = physics.task_state
    history = state[f'{self.name}_history']
    control = physics.bind(self.actuators).ctrl.astype(history.dtype)
    history = jnp.concatenate([control[None], history[:-1]])
    delayed = history[state[f'{self.name}_steps']]
    physics = physics.update_task_state(**{f'{self.name}_history': history})
    return physics.bind(self.actuators).set(ctrl=delayed)

  def after_substep(self, physics):
    """Puts the task's controls (the newest recorded) back into `ctrl`."""
    history = physics.task_state[f'{self.name}_history']
    return physics.bind(self.actuators).set(ctrl=history[0])
