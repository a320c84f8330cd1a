"""Tests for the `Observables` collection (the observable parts of composer's
entity_test)."""

import abc

import jax.numpy as jnp
import pytest

from mjx_composer import define
from mjx_composer.observation.observable import base
from mjx_composer.observation.observable import collection


def _add_twelve(value, key):
  del key
  return value + 12


class _Entity:
  """Just enough of an entity: a full identifier."""

  def __init__(self, full_identifier=''):
    self.full_identifier = full_identifier
    self.evaluations = 0


class _EntityObservables(collection.Observables):

  @define.observable
  def observable1(self):
    self._entity.evaluations += 1
    return base.Generic(lambda p: 1)

  @define.observable
  def observable0(self):
    return base.Generic(lambda p: 0)

  @define.cached_property
  def not_an_observable(self):
    return 'ignored'


# Observables hold their entity weakly (as composer's do): keep ours alive.
_ENTITIES = []


def _make(cls, identifier=''):
  entity = _Entity(identifier)
  _ENTITIES.append(entity)
  return cls(entity)


def test_declared_observables_in_alphabetical_order():
  entity = _Entity()
  observables = _EntityObservables(entity)
  assert entity.evaluations == 1  # Evaluated at construction, once.
  assert list(observables.as_dict()) == ['observable0', 'observable1']
  assert observables.observable1 is observables.as_dict()['observable1']
  assert entity.evaluations == 1
  assert not observables.observable0.enabled


@pytest.mark.parametrize(
    'identifier,prefix',
    [
        ('', ''),
        ('subentity/', 'subentity/'),
        ('arm/hand/', 'arm/hand/'),
        ('arm', 'arm/'),
    ],
)
def test_keys_are_fully_qualified(identifier, prefix):
  observables = _make(_EntityObservables, identifier)
  assert list(observables.as_dict()) == [
      prefix + 'observable0',
      prefix + 'observable1',
  ]
  assert list(observables.as_dict(fully_qualified=False)) == [
      'observable0',
      'observable1',
  ]
  assert observables.dict_keys.observable0 == prefix + 'observable0'
  assert 'observable0' in dir(observables.dict_keys)
  with pytest.raises(AttributeError):
    observables.dict_keys.unknown  # pylint: disable=pointless-statement
  assert observables.get_observable('observable1') is observables.observable1
  assert observables.get_observable(
      prefix + 'observable1', name_fully_qualified=True
  ) is (observables.observable1)


def test_unreadable_identifier_raises_value_error():
  observables = _make(_EntityObservables)
  del observables._entity.full_identifier  # pylint: disable=protected-access
  with pytest.raises(ValueError, match='full identifier'):
    observables.as_dict()


def test_enable_and_disable_all():
  observables = _make(_EntityObservables)
  observables.enable_all()
  assert all(o.enabled for o in observables.as_dict().values())
  observables.disable_all()
  assert not any(o.enabled for o in observables.as_dict().values())
  observables.observable0.enabled = True
  assert observables.as_dict()['observable0'].enabled


def test_set_options_flat_applies_to_all():
  observables = _make(_EntityObservables)
  options = dict(
      update_interval=2,
      buffer_size=10,
      delay=1,
      aggregator='max',
      corruptor=_add_twelve,
      enabled=True,
  )
  observables.set_options(options)
  for obs in observables.as_dict().values():
    assert (obs.update_interval, obs.buffer_size, obs.delay) == (2, 10, 1)
    assert obs.aggregator == base.AGGREGATORS['max']
    assert obs.corruptor is _add_twelve and obs.enabled


def test_set_options_partial_flat_leaves_the_rest():
  observables = _make(_EntityObservables)
  observables.set_options({'update_interval': 3, 'enabled': True})
  for obs in observables.as_dict().values():
    assert obs.update_interval == 3 and obs.enabled
    assert obs.delay is None and obs.buffer_size is None
    assert obs.aggregator is None and obs.corruptor is None
  observables.set_options(None)  # None means no options.


def test_set_options_per_observable():
  observables = _make(_EntityObservables)
  observables.set_options(
      {
          'observable0': {'update_interval': 4, 'enabled': True},
          'observable1': {'delay': 2},
      }
  )
  assert observables.observable0.update_interval == 4
  assert observables.observable0.enabled
  assert observables.observable1.delay == 2
  assert observables.observable1.update_interval == 1
  assert not observables.observable1.enabled


def test_set_options_errors():
  observables = _make(_EntityObservables)
  with pytest.raises(KeyError, match="No observable with name 'asdf'"):
    observables.set_options({'asdf': {'enabled': True}})
  with pytest.raises(
      AttributeError, match='Cannot add attribute asdf in configure.'
  ):
    observables.set_options({'observable0': {'asdf': 1}})


def test_add_observable_is_enabled_by_default():
  observables = _make(_EntityObservables, 'arm/')
  added = base.Generic(lambda p: 2)
  observables.add_observable('extra', added)
  assert added.enabled
  assert observables.as_dict()['arm/extra'] is added
  assert observables.get_observable('extra') is added
  assert observables.dict_keys.extra == 'arm/extra'
  hidden = base.Generic(lambda p: 3)
  observables.add_observable('hidden', hidden, enabled=False)
  assert not hidden.enabled
  assert not hasattr(observables, 'extra')  # Not an attribute.


class _PropObservables(
    collection.Observables, collection.FreePropObservableMixin
):

  @define.observable
  def position(self):
    return base.Generic(lambda p: jnp.zeros(3))

  @define.observable
  def orientation(self):
    return base.Generic(lambda p: jnp.array([1.0, 0.0, 0.0, 0.0]))

  @define.observable
  def linear_velocity(self):
    return base.Generic(lambda p: jnp.zeros(3))

  @define.observable
  def angular_velocity(self):
    return base.Generic(lambda p: jnp.zeros(3))


def test_free_prop_observable_mixin():
  assert isinstance(collection.FreePropObservableMixin, abc.ABCMeta)

  class Incomplete(collection.Observables, collection.FreePropObservableMixin):

    @define.observable
    def position(self):
      return base.Generic(lambda p: jnp.zeros(3))

  with pytest.raises(TypeError):
    Incomplete(_Entity())
  observables = _make(_PropObservables, 'ball/')
  assert list(observables.as_dict()) == [
      'ball/angular_velocity',
      'ball/linear_velocity',
      'ball/orientation',
      'ball/position',
  ]
  assert isinstance(observables, collection.FreePropObservableMixin)


def test_observables_hold_a_weak_reference_to_the_entity():
  entity = _Entity('a/')
  observables = _EntityObservables(entity)
  assert observables.as_dict()
  del entity
  with pytest.raises(ValueError):
    observables.as_dict()


def test_package_exports():
  from mjx_composer import observation  # pylint: disable=g-import-not-at-top

  assert observation.Observables is collection.Observables
  assert observation.observable.Observables is collection.Observables
  assert observation.ObservationPadding.INITIAL_VALUE.value == -1
  assert observation.ObservationPadding.ZERO.value == 0
  assert isinstance(observation.observable.OPTION_NAMES, frozenset)
