"""Decorators for declaring cached properties and observables on entities.

`cached_property` evaluates its getter once per instance and caches the result
in the instance's `__dict__`, exactly like composer's. `observable` is a
`cached_property` subclass that marks a factory method on an `Observables`
subclass; `Observables.__init__` evaluates every such attribute at entity
construction time, so observables exist (and can be configured) before the
environment is built.
"""

import abc
import threading


class cached_property(property):  # pylint: disable=invalid-name
  """A property evaluated once per instance and then cached.

  The value is stored in `instance.__dict__` under the getter's name, which
  shadows this (non-data-like) lookup on later accesses only through our own
  `__get__` fast path; a per-descriptor re-entrant lock makes the first
  evaluation thread-safe.
  """

  def __init__(self, func, doc=None):
    super().__init__(fget=func, doc=doc or func.__doc__)
    self._name = func.__name__
    self._lock = threading.RLock()

  def __get__(self, instance, owner=None):
    if instance is None:
      return self
    cache = instance.__dict__
    try:
      return cache[self._name]
    except KeyError:
      pass
    with self._lock:
      if self._name not in cache:
        cache[self._name] = self.fget(instance)
      return cache[self._name]


# An abstract observable: subclasses of an abstract `Observables` must define it.
abstract_observable = abc.abstractmethod


class observable(cached_property):  # pylint: disable=invalid-name
  """Declares an observable factory on an `Observables` subclass.

  The decorated method's body runs at entity construction time (when
  `Observables.__init__` walks the class) and returns an `Observable`; the
  result is cached, so `entity.observables.<name>` always returns the same
  object and options set on it stick.
  """
