"""Every bundled task's constructor argument refuses bad values of its kind.

A property-style sweep: the arguments come from the constructors'
signatures, the bad values from each argument's kind (read from its
default): non-finite, negative, wrong order or wrong type; for a sequence
of names, empty, unknown or not a sequence. Each bad value
must be refused before anything is built, by a `TypeError` or `ValueError`
whose message quotes the argument's name. An argument added without a check
fails here; one that legitimately accepts a value of the list goes into
`ACCEPTED` with the reason.

Nothing is compiled: the checks run first in each constructor, so the sweep
costs milliseconds per call.
"""

import importlib
import inspect
import math
import pkgutil
import re

import pytest

from mjx_composer import task as task_lib
from mjx_composer import tasks as tasks_package
from mjx_composer.tasks import locomotion
from mjx_composer.tasks import registry

_NAN, _INF = math.nan, math.inf

# Bad values per kind of argument.
_BAD = {
    bool: ['yes', None, 1],
    int: [2.5, -1, True, 'abc', _NAN],
    float: [_NAN, _INF, -_INF, -1.0, 'abc', None],
    tuple: [(_NAN, 1.0), (0.5, 0.1), (-1.0, 1.0), 3, 'ab', (1.0, 2.0, 3.0)],
    str: ['no such option', 3],
    'names': [(), ('no such option',), 'flat', 3],  # A sequence of names.
}
# Arguments whose kind cannot be read from a default.
_KINDS = {('Pushes', 'interval'): int}
# (class, argument, repr(bad value)) -> why it is accepted.
ACCEPTED = {
    ('TerrainJoystick', 'scan_size', '(0.5, 0.1)'): (
        'a (length, width) size, not a (low, high) range'
    ),
}
# Registered task names -> the class their factory builds.
_REGISTERED = {
    'reach': 'Reach',
    'push': 'Push',
    'walk': 'Walk',
    'joystick': 'Joystick',
    'joystick_rough': 'Joystick',
    'joystick_terrain': 'TerrainJoystick',
}
# Helpers of the bundled tasks that take user arguments too.
_HELPERS = (locomotion.Pushes,)


def _task_classes():
  """Every `Task` subclass defined in a module of `mjx_composer.tasks`."""
  classes = {}
  for info in pkgutil.iter_modules(tasks_package.__path__):
    module = importlib.import_module(f'{tasks_package.__name__}.{info.name}')
    for value in vars(module).values():
      if (
          inspect.isclass(value)
          and issubclass(value, task_lib.Task)
          and value.__module__ == module.__name__
      ):
        classes[value.__name__] = value
  return classes


_CLASSES = {**_task_classes(), **{h.__name__: h for h in _HELPERS}}


def _kind(cls, parameter):
  if (cls.__name__, parameter.name) in _KINDS:
    return _KINDS[(cls.__name__, parameter.name)]
  default = parameter.default
  if isinstance(default, bool):
    return bool
  if isinstance(default, (int, float, str)):
    return type(default)
  if isinstance(default, (tuple, list)):
    return 'names' if all(isinstance(x, str) for x in default) else tuple
  raise AssertionError(
      f'{cls.__name__}({parameter.name}=...): add its kind to _KINDS '
      f'(default {default!r}).'
  )


def _cases():
  cases = []
  for name, cls in sorted(_CLASSES.items()):
    signature = inspect.signature(cls.__init__)
    for parameter in list(signature.parameters.values())[1:]:
      if parameter.kind in (parameter.VAR_KEYWORD, parameter.VAR_POSITIONAL):
        continue  # Passed on to a base class, whose own are swept.
      for bad in _BAD[_kind(cls, parameter)]:
        if (name, parameter.name, repr(bad)) not in ACCEPTED:
          cases.append(
              pytest.param(
                  cls,
                  parameter.name,
                  bad,
                  id=f'{name}-{parameter.name}-{bad!r}',
              )
          )
  return cases


def _required(cls):
  """Valid values for the arguments without a default."""
  return {'interval': 1} if cls is locomotion.Pushes else {}


@pytest.mark.parametrize('cls, argument, bad', _cases())
def test_bad_argument_is_refused_naming_it(cls, argument, bad):
  kwargs = {**_required(cls), argument: bad}
  with pytest.raises((TypeError, ValueError)) as error:
    cls(**kwargs)
  # The argument is named (a check delegated to a part, such as the
  # terrain generator's, may name its own class rather than the task).
  assert re.search(rf'\b{argument}\b', str(error.value)), str(error.value)


def test_sweep_covers_every_registered_task():
  assert set(registry.names()) <= set(_REGISTERED), (
      'A task was registered without an entry in _REGISTERED: add it, so '
      'that its constructor arguments are swept.'
  )
  assert {_REGISTERED[n] for n in registry.names()} <= set(_CLASSES)


def test_sweep_finds_the_bundled_task_classes():
  assert {'Reach', 'Push', 'Walk', 'Joystick'} <= set(_CLASSES)


def test_accepted_exceptions_name_real_arguments():
  for name, argument, _ in ACCEPTED:
    assert argument in inspect.signature(_CLASSES[name].__init__).parameters
