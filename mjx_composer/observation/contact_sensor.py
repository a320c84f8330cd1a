"""`ContactSensor`: contact flags, forces, and air and contact times per world.

Legged-locomotion rewards and observations need, for each foot, whether it
touches the ground, how hard, how long it has been in the air or on the
ground, and at the step a foot lands, how long it was in the air (Isaac Lab's
and mjlab's contact sensor; MuJoCo Playground's `feet_air_time`). A
`ContactSensor` gives them for any rows of geom sets (feet: one row per foot)
against another set (the ground) or anything else, from `contacts.summarize`.

The times are per-world state, kept in the task's state like the locomotion
kit's other parts: the task declares the sensor's entries
(`initial_task_state() | sensor.initial_state()`), calls
`sensor.update(physics, dt)` once per control step (in `after_step`, with
`dt = self.control_timestep`), and rewards read the accessors. The entries
start at zero with every episode.

Timing, at each update (the last sub-step's contacts):

* `air_time`: time since the last update that saw the row in contact
  (0 while in contact); `contact_time`: time since the last update that saw
  it in the air (0 while in the air). Each grows by `dt` per update.
* `first_contact`: the row touches now after at least one update in the
  air (a touch-down; not at the first update of an episode that starts in
  contact); `last_air_time`: at that update, the air time that just ended,
  this update's `dt` included; kept until the next touch-down.
* `first_air` and `last_contact_time`: the same for lift-offs.

So Isaac Lab's `compute_first_contact` is `first_contact`, and Playground's
air-time reward is `sum((last_air_time - 0.1) * first_contact)`.
"""

from __future__ import annotations

import jax.numpy as jnp

from mjx_composer.observation import contacts as contacts_lib
from mjx_composer.observation.observable import base as observable_base
from mjx_composer.utils import validation

_OWNER = 'ContactSensor'
_TIMES = ('air_time', 'contact_time', 'last_air_time', 'last_contact_time')
_FLAGS = ('contact', 'first_contact', 'first_air')


class ContactSensor:
  """Contact flags, forces and air/contact times of rows of geoms (module doc).

  Args:
    rows: a list of geom sets, one per row (each an entity, body, geom,
      name or a list of these: `contacts.geom_ids`); e.g. a robot's foot
      geoms, one row each.
    other: the set every row is matched against (e.g. the arena's ground
      geoms); None: any geom outside the row's set.
    name: the prefix of the task-state entries (`<name>_air_time`, ...).
    force_threshold: None: a row is in contact when it has any contact;
      a number: when its summed normal force exceeds it (newtons), as Isaac
      Lab's sensor thresholds its force.
  """

  def __init__(self, rows, other=None, name='contact', force_threshold=None):
    if isinstance(rows, (str, bytes)) or not hasattr(rows, '__len__'):
      raise TypeError(
          f'{_OWNER}: rows must be a list of geom sets, one per row (e.g. '
          f'[left_foot, right_foot]), got {rows!r}.'
      )
    if not len(rows):
      raise ValueError(f'{_OWNER}: rows is empty: give one geom set per row.')
    if not isinstance(name, str) or not name:
      raise ValueError(
          f'{_OWNER}: name must be a non-empty string, got {name!r}.'
      )
    if force_threshold is not None:
      force_threshold = validation.check_nonnegative(
          'force_threshold',
          force_threshold,
          owner=_OWNER,
          fix='Pass None (any contact) or a force in newtons >= 0.',
      )
    self._rows = list(rows)
    self._other = other
    self.name = name
    self._threshold = force_threshold

  @property
  def num_rows(self) -> int:
    return len(self._rows)

  def _key(self, entry):
    return f'{self.name}_{entry}'

  def initial_state(self) -> dict:
    """The task-state entries: `<name>_<entry>` for the flags (bool) and
    times (float32), each of shape `(rows,)`, all zero."""
    n = self.num_rows
    state = {self._key(e): jnp.zeros((n,), bool) for e in _FLAGS}
    state.update({self._key(e): jnp.zeros((n,), jnp.float32) for e in _TIMES})
    return state

  # -- instantaneous readings ------------------------------------------------

  def measure(self, physics) -> contacts_lib.ContactRows:
    """This physics' contacts per row (`contacts.ContactRows`), with
    `touching` thresholded as the sensor's flag."""
    rows = contacts_lib.summarize(physics, self._rows, self._other)
    if self._threshold is not None:
      rows = rows.replace(touching=rows.normal_force > self._threshold)
    return rows

  # -- state -----------------------------------------------------------------

  def update(self, physics, dt, touching=None):
    """Advances the times by one update of `dt` seconds; returns the physics.

    Call once per control step, from `after_step` (or once per sub-step from
    `after_substep`, with the physics timestep).

    Args:
      physics: one world's `Physics`, its task state holding the sensor's
        entries.
      dt: seconds since the last update (the task's `control_timestep`).
      touching: None: the rows' flags from the contacts (`measure`); else a
        `(rows,)` bool array of flags computed elsewhere, e.g. from MuJoCo
        contact sensors' `sensordata`, which is the way under
        `ExecutionOptions(impl='warp')`, where `measure` is refused.
    """
    if touching is None:
      touching = self.measure(physics).touching
    else:
      touching = jnp.asarray(touching, bool)
      if touching.shape != (self.num_rows,):
        raise ValueError(
            f'{_OWNER} {self.name!r}: touching must have shape '
            f'({self.num_rows},), one flag per row, got {touching.shape}.'
        )
    state = physics.task_state
    missing = [k for k in self.initial_state() if k not in (state or {})]
    if missing:
      raise KeyError(
          f'{_OWNER} {self.name!r}: the task state has no entries {missing}: '
          'declare them with initial_task_state() | sensor.initial_state().'
      )
    read = lambda entry: state[self._key(entry)]
    air, on = read('air_time'), read('contact_time')
    dt = jnp.asarray(dt, jnp.float32)
    first_contact = touching & (air > 0)
    first_air = ~touching & (on > 0)
    return physics.update_task_state(
        **{
            self._key('contact'): touching,
            self._key('first_contact'): first_contact,
            self._key('first_air'): first_air,
            self._key('last_air_time'): jnp.where(
                first_contact, air + dt, read('last_air_time')
            ),
            self._key('last_contact_time'): jnp.where(
                first_air, on + dt, read('last_contact_time')
            ),
            self._key('air_time'): jnp.where(touching, 0.0, air + dt),
            self._key('contact_time'): jnp.where(touching, on + dt, 0.0),
        }
    )

  def _entry(self, entry):
    return lambda physics: physics.task_state[self._key(entry)]

  def contact(self, physics):
    """`(rows,)` bool: in contact at the last update."""
    return self._entry('contact')(physics)

  def first_contact(self, physics):
    """`(rows,)` bool: touched down at the last update."""
    return self._entry('first_contact')(physics)

  def first_air(self, physics):
    """`(rows,)` bool: lifted off at the last update."""
    return self._entry('first_air')(physics)

  def air_time(self, physics):
    """`(rows,)` seconds since the last update in contact (0 in contact)."""
    return self._entry('air_time')(physics)

  def contact_time(self, physics):
    """`(rows,)` seconds since the last update in the air (0 in the air)."""
    return self._entry('contact_time')(physics)

  def last_air_time(self, physics):
    """`(rows,)` the air time that ended at the last touch-down."""
    return self._entry('last_air_time')(physics)

  def last_contact_time(self, physics):
    """`(rows,)` the contact time that ended at the last lift-off."""
    return self._entry('last_contact_time')(physics)

  def landing_air_time(self, physics):
    """`(rows,)` `last_air_time` where a row touched down at the last update,
    else 0: the input of an air-time reward."""
    return jnp.where(
        self.first_contact(physics), self.last_air_time(physics), 0.0
    )

  # -- observables -----------------------------------------------------------

  def observables(self) -> dict:
    """Observables of the sensor, each `(rows,)` (forces `(rows, 3)`):
    'contact', 'air_time', 'contact_time', 'last_air_time',
    'last_contact_time' (float32, from the state at the last update) and
    'normal_force', 'force' (read from the physics when sampled). New
    observables are disabled, as composer's."""
    as_float = lambda fn: lambda physics: jnp.asarray(fn(physics), jnp.float32)
    out = {
        entry: observable_base.Generic(as_float(self._entry(entry)))
        for entry in ('contact',) + _TIMES
    }
    out['normal_force'] = observable_base.Generic(
        lambda physics: self.measure(physics).normal_force
    )
    out['force'] = observable_base.Generic(
        lambda physics: self.measure(physics).force
    )
    return out
