"""`ContactFeature`: an observable of the contacts between two sets of geoms.

`ContactFeature('normal_force', foot, floor)` observes what
`contacts.between(physics, foot, floor).normal_force` returns, at every
sample; the sets are resolved to static geom ids when the read is traced.
For times since touch-down or lift-off, which need per-world state, see
`observation.contact_sensor.ContactSensor`.
"""

import numbers

import jax.numpy as jnp
import numpy as np

from mjx_composer.observation import contacts as contacts_lib
from mjx_composer.observation.observable import base
from mjx_composer.utils import validation

_OWNER = 'ContactFeature'

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


def _check_count(name, value):
  """An observable's count option: None, an integer >= 0, or (for
  `update_interval` and `delay`) a `Variation`, drawn per sample."""
  if value is None:
    return
  if isinstance(value, (str, bytes, numbers.Number, np.generic)):
    validation.check_integer(name, value, owner=_OWNER, minimum=0)


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
    if not isinstance(kind, str) or kind not in KINDS:
      raise ValueError(
          f'{_OWNER}: unknown kind {kind!r}; choose one of {sorted(KINDS)}.'
      )
    if max_contacts is not None:
      validation.check_integer(
          'max_contacts', max_contacts, owner=_OWNER, minimum=1
      )
    # As every observable's: None or 0 means 1 sample, every sub-step.
    for option, value in (
        ('update_interval', update_interval),
        ('buffer_size', buffer_size),
        ('delay', delay),
    ):
      _check_count(option, value)
    if not (
        aggregator is None
        or callable(aggregator)
        or (isinstance(aggregator, str) and aggregator in base.AGGREGATORS)
    ):
      raise ValueError(
          f'{_OWNER}: aggregator must be None, one of '
          f'{sorted(base.AGGREGATORS)} or a callable, got {aggregator!r}.'
      )
    if corruptor is not None and not callable(corruptor):
      raise TypeError(
          f'{_OWNER}: corruptor must be None or a callable '
          f'corruptor(value, key) -> value, got {corruptor!r}.'
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
