"""`ContactFeature`: an observable of the contacts between two sets of geoms.

`ContactFeature('normal_force', foot, floor)` observes what
`contacts.between(physics, foot, floor).normal_force` returns, at every
sample; the sets are resolved to static geom ids when the read is traced.
For times since touch-down or lift-off, which need per-world state, see
`observation.contact_sensor.ContactSensor`.
"""

import jax.numpy as jnp

from mjx_composer.observation import contacts as contacts_lib
from mjx_composer.observation.observable import base

# `contacts.Contacts` fields an observable can read, and their dtypes.
KINDS = {
    'touching': jnp.float32,
    'count': jnp.int32,
    'normal_force': None,
    'force': None,
    'penetration': None,
    'position': None,
    'distance': None,
    'valid': jnp.float32,
}


class ContactFeature(base.Observable):
  """A field of `contacts.between(physics, first, second)` (module docstring).

  Args:
    kind: one of `KINDS`: 'touching' (1.0 or 0.0), 'count', 'normal_force',
      'force' (`(3,)`, on `first`, world frame), 'penetration', and the
      padded lists 'position', 'distance', 'valid' (`max_contacts` rows).
    first: a set of geoms (`contacts.geom_ids`).
    second: another set, disjoint from `first`; None: anything else.
    max_contacts: rows of the padded lists (see `contacts.between`).
    update_interval, buffer_size, delay, aggregator, corruptor: as every
      observable's.
  """

  def __init__(
      self,
      kind,
      first,
      second=None,
      max_contacts=None,
      update_interval=1,
      buffer_size=None,
      delay=None,
      aggregator=None,
      corruptor=None,
  ):
    if kind not in KINDS:
      raise ValueError(
          f'ContactFeature: unknown kind {kind!r}; choose one of '
          f'{sorted(KINDS)}.'
      )
    self._kind = kind
    self._first = first
    self._second = second
    self._max_contacts = max_contacts
    super().__init__(update_interval, buffer_size, delay, aggregator, corruptor)

  @property
  def kind(self):
    return self._kind

  def _callable(self, physics):
    kind, dtype = self._kind, KINDS[self._kind]

    def read():
      value = getattr(
          contacts_lib.between(
              physics, self._first, self._second, self._max_contacts
          ),
          kind,
      )
      return value if dtype is None else jnp.asarray(value, dtype)

    return read
