"""`Observables`: an entity's named collection of observables.

Subclass `Observables` and declare each observable as a method decorated with
`define.observable`; the body runs once, when the entity is constructed, and
returns an `Observable`::

    class ArmObservables(Observables):

      @define.observable
      def joint_positions(self):
        return MJCFFeature('qpos', self._entity.joints)

The collection keeps composer's conventions: declared observables are kept in
alphabetical order of their attribute names, keys are qualified with the
entity's attachment prefix (`'arm/joint_positions'`), and options can be set
for all observables at once or per observable.
"""

import abc
import collections
import weakref

from mjx_composer import define
from mjx_composer.observation.observable import base


def _prefix(entity) -> str:
  """The entity's full identifier as a key prefix ('' or ending in '/')."""
  try:
    identifier = entity.full_identifier
  except (AttributeError, ReferenceError) as e:
    raise ValueError(
        'cannot retrieve the full identifier of the entity that owns these '
        'observables'
    ) from e
  if identifier and not identifier.endswith('/'):
    identifier += '/'
  return identifier


class _ObservableKeys:
  """Attribute access to fully qualified keys: `keys.joint_positions`."""

  def __init__(self, entity, observables):
    self._entity = entity
    self._observables = observables

  def __getattr__(self, name):
    if name.startswith('_'):
      raise AttributeError(name)
    if name not in self._observables:
      raise AttributeError(f'No observable with name {name!r}')
    return _prefix(self._entity) + name

  def __dir__(self):
    return list(self._observables.keys())


class Observables:
  """The observables of one entity, keyed by name.

  `Observables(entity)` evaluates every `define.observable` attribute of its
  class, in `sorted(dir(type(self)))` order, and keeps the results in an
  `OrderedDict`. Observables declared this way start disabled (an
  `Observable` is created with `enabled=False`); the entity, task or user
  enables them, e.g. through `set_options` or `enable_all`.
  """

  def __init__(self, entity):
    try:
      self._entity = weakref.proxy(entity)
    except TypeError:  # objects that cannot be weakly referenced
      self._entity = entity
    self._observables = collections.OrderedDict()
    self._keys_helper = _ObservableKeys(self._entity, self._observables)
    cls = type(self)
    for name in sorted(dir(cls)):
      if isinstance(getattr(cls, name, None), define.observable):
        self._observables[name] = getattr(self, name)

  @property
  def dict_keys(self):
    """An object whose attributes are the observables' qualified keys."""
    return self._keys_helper

  def as_dict(self, fully_qualified=True):
    """An `OrderedDict` of the observables.

    Args:
      fully_qualified: key them as `'<entity full identifier>/<name>'` (e.g.
        `'arm/hand/joint_positions'`); otherwise by bare name.

    Raises:
      ValueError: if the entity's full identifier cannot be read.
    """
    if not fully_qualified:
      return collections.OrderedDict(self._observables)
    prefix = _prefix(self._entity)
    return collections.OrderedDict(
        (prefix + name, obs) for name, obs in self._observables.items()
    )

  def get_observable(self, name, name_fully_qualified=False):
    """The observable named `name` (bare, or qualified if requested)."""
    if name_fully_qualified:
      prefix = _prefix(self._entity)
      if prefix and name.startswith(prefix):
        name = name[len(prefix) :]
    return self._observables[name]

  def set_options(self, options):
    """Configures observables.

    Args:
      options: `None`; a flat dict of options (keys among `update_interval`,
        `buffer_size`, `delay`, `aggregator`, `corruptor`, `enabled`) applied
        to every observable; or `{observable name: {option: value}}`.

    Raises:
      KeyError: for an unknown observable name.
      AttributeError: for an unknown option.
    """
    options = options or {}
    if set(options).issubset(base.OPTION_NAMES):
      for obs in self._observables.values():
        obs.configure(**options)
      return
    for name, obs_options in options.items():
      obs = self._observables.get(name)
      if obs is None:
        raise KeyError(f'No observable with name {name!r}')
      obs.configure(**obs_options)

  def enable_all(self):
    for obs in self._observables.values():
      obs.enabled = True

  def disable_all(self):
    for obs in self._observables.values():
      obs.enabled = False

  def add_observable(self, name, observable, enabled=True):
    """Adds an observable under `name`, enabled by default (as composer).

    Added observables are not attributes: read them with `get_observable`.
    """
    self._observables[name] = observable
    self._observables[name].enabled = enabled


class FreePropObservableMixin(metaclass=abc.ABCMeta):
  """Observables every free-floating prop provides.

  Mix it into an `Observables` subclass and define each with
  `define.observable`, e.g. `MJCFFeature('sensordata', framepos_sensor)`.
  """

  @property
  @abc.abstractmethod
  def position(self):
    """The prop's position in the world frame."""

  @property
  @abc.abstractmethod
  def orientation(self):
    """The prop's orientation (a quaternion) in the world frame."""

  @property
  @abc.abstractmethod
  def linear_velocity(self):
    """The prop's linear velocity in the world frame."""

  @property
  @abc.abstractmethod
  def angular_velocity(self):
    """The prop's angular velocity in the world frame."""
