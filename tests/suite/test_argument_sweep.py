"""Every bundled task's and locomotion part's argument refuses bad values.

A property-style sweep over the bundled tasks, the locomotion kit
(`mjx_composer.suite.locomotion`: every public class), `policy_observable`
and the contact observation parts. The arguments come from the constructors'
signatures (an entity's from its `_build`), the bad values from each
argument's kind (read from its default, or given in `_KINDS`): non-finite,
negative (unless the default is), wrong order or wrong type; for a sequence
of names, empty, unknown or not a sequence; for an integer pair, fractional,
swapped or negative. Each bad value must be refused before anything is
built, by a `TypeError` or `ValueError` whose message quotes the argument's
name. An argument (or a locomotion class) added without a check fails here;
one that legitimately accepts a value of the list goes into `ACCEPTED`, and
one checked only where it is used (a geom set) into `RESOLVED_LATER`, each
with the reason.

Nothing is compiled: the checks run first in each constructor, so the sweep
costs milliseconds per call (the curriculum's terrain, two flat tiles, is
built once).
"""

import functools
import importlib
import inspect
import math
import pkgutil
import re

import mujoco
import pytest

from mjx_composer import task as task_lib
from mjx_composer.observation import contact_sensor
from mjx_composer.observation import observable
from mjx_composer.observation.observable import contact
from mjx_composer.suite import locomotion as locomotion_package
from mjx_composer.suite import tasks as tasks_package
from mjx_composer.suite.locomotion import actuation_delay
from mjx_composer.suite.locomotion import commands
from mjx_composer.suite.locomotion import curriculum
from mjx_composer.suite.locomotion import height_scan
from mjx_composer.suite.locomotion import policy_critic
from mjx_composer.suite.locomotion import pushes
from mjx_composer.suite.locomotion import terrain
from mjx_composer.suite.locomotion.terrain import sub_terrains
from mjx_composer.suite.locomotion.terrain import surface
from mjx_composer.suite.locomotion.terrain import terrain_part
from mjx_composer.suite.tasks import registry

_NAN, _INF = math.nan, math.inf

# Bad values per kind of argument.
_BAD = {
    bool: ['yes', None, 1],
    int: [2.5, -1, True, 'abc', _NAN],
    float: [_NAN, _INF, -_INF, -1.0, 'abc', None],
    tuple: [(_NAN, 1.0), (0.5, 0.1), (-1.0, 1.0), 3, 'ab', (1.0, 2.0, 3.0)],
    str: ['no such option', 3],
    'names': [(), ('no such option',), 'flat', 3],  # A sequence of names.
    # A (low, high) range of a signed quantity (a velocity, a heading).
    'signed_range': [(_NAN, 1.0), (0.5, 0.1), 3, 'ab', (1.0, 2.0, 3.0)],
    'int_pair': [(-1, 1), (2, 1), (0.5, 1), (True, 1), 3, 'ab', (0, 1, 2)],
    # (at difficulty 0, at difficulty 1): either order, each >= 0.
    'endpoints': [(_NAN, 1.0), (-1.0, 1.0), 3, 'ab', (1.0, 2.0, 3.0)],
    'flags': [(1, 0, 0, 0, 0, 2), (1, 0, 0, 0, 0, _NAN), (1, 0, 0), 'ab', 3],
    'label': ['', 3, None],  # A name or prefix of the part's entries.
    'object': ['abc', 3, None],  # An element, an observable, a terrain.
    'elements': [(), 'abc', 3, None],  # A list of elements.
    'points': [[[_NAN, 0.0]], [[0.0, 0.0, 0.0]], [], 'abc', 3],
    'callable': ['abc', 3],
    'aggregator': ['no such option', 3],
    'config': ['abc', 3, 0, {}],
}
# Arguments whose kind cannot be read from a default.
_KINDS = {
    ('Pushes', 'interval'): int,
    ('VelocityCommand', 'heading_range'): 'signed_range',
    ('ActuationDelay', 'actuators'): 'elements',
    ('HeightScan', 'frame'): 'object',
    ('HeightScan', 'points'): 'points',
    ('HeightScan', 'geomgroup'): 'flags',
    ('TerrainGenerator', 'config'): 'config',
    ('TerrainCurriculum', 'terrain'): 'object',
    ('TerrainCurriculum', 'up_distance'): float,
    ('ContactSensor', 'rows'): 'elements',
    ('ContactSensor', 'force_threshold'): float,
    ('ContactFeature', 'kind'): str,
    ('ContactFeature', 'max_contacts'): int,
    ('ContactFeature', 'buffer_size'): int,
    ('ContactFeature', 'delay'): int,
    ('ContactFeature', 'aggregator'): 'aggregator',
    ('ContactFeature', 'corruptor'): 'callable',
    ('policy_observable', 'obs'): 'object',
    ('policy_observable', 'n_sub_steps'): int,
    ('policy_observable', 'corruptor'): 'callable',
    **{
        ('SubTerrainConfig', field.name): 'endpoints'
        for field in sub_terrains.dataclasses.fields(
            sub_terrains.SubTerrainConfig
        )
        if field.name.endswith('_range')
    },
}
# Arguments checked where they are used, not at construction -> why.
RESOLVED_LATER = {
    ('ContactSensor', 'other'): (
        'a geom set (an entity, body, geom, name or list), resolved against '
        'the compiled model when the read is traced (contacts.geom_ids)'
    ),
    ('ContactFeature', 'first'): 'a geom set, as ContactSensor.other',
    ('ContactFeature', 'second'): 'a geom set, as ContactSensor.other',
}
# (class, argument, repr(bad value)) -> why it is accepted.
ACCEPTED = {
    ('TerrainJoystick', 'scan_size', '(0.5, 0.1)'): (
        'a (length, width) size, not a (low, high) range'
    ),
    ('TerrainWalk', 'scan_size', '(0.5, 0.1)'): (
        'a (length, width) size, not a (low, high) range'
    ),
    ('RoughTerrain', 'size', '(0.5, 0.1)'): (
        'a (half-x, half-y) size, not a (low, high) range'
    ),
    ('HeightScan', 'size', '(0.5, 0.1)'): (
        'a (length, width) size, not a (low, high) range'
    ),
    ('HeightScan', 'ray_start', '-1.0'): (
        "a height relative to the frame: rays may start below the frame's "
        'origin (a frame carried high above the feet)'
    ),
    ('TerrainCurriculum', 'up_distance', 'None'): 'None: half a tile',
    ('ContactSensor', 'force_threshold', 'None'): 'None: any contact counts',
}
# Registered task names -> the class their factory builds.
_REGISTERED = {
    'reach': 'Reach',
    'push': 'Push',
    'walk': 'Walk',
    'walk_terrain': 'TerrainWalk',
    'joystick': 'Joystick',
    'joystick_rough': 'Joystick',
    'joystick_terrain': 'TerrainJoystick',
}
# Helpers of the bundled tasks that take user arguments too.
_HELPERS = (pushes.Pushes, policy_critic.policy_observable)
# The locomotion kit and the contact observation parts.
_PARTS = (
    commands.VelocityCommand,
    actuation_delay.ActuationDelay,
    height_scan.HeightScan,
    terrain.TerrainGenerator,
    terrain.RoughTerrain,
    sub_terrains.SubTerrainConfig,
    curriculum.TerrainCurriculum,
    contact_sensor.ContactSensor,
    contact.ContactFeature,
)


def _task_classes():
  """Every `Task` subclass defined in a module of `mjx_composer.suite.tasks`."""
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


_CLASSES = {
    **_task_classes(),
    **{h.__name__: h for h in _HELPERS + _PARTS},
}


def _parameters(target):
  """The user's arguments of a class (or an entity's `_build`) or function."""
  if not inspect.isclass(target):
    return list(inspect.signature(target).parameters.values())
  parameters = list(inspect.signature(target.__init__).parameters.values())[1:]
  variadic = (inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD)
  if hasattr(target, '_build') and all(p.kind in variadic for p in parameters):
    # A composer entity: `__init__(*args, **kwargs)` calls `_build`.
    parameters = list(inspect.signature(target._build).parameters.values())[1:]
  return parameters


def _kind(cls, parameter):
  if (cls.__name__, parameter.name) in RESOLVED_LATER:
    return None
  if (cls.__name__, parameter.name) in _KINDS:
    return _KINDS[(cls.__name__, parameter.name)]
  default = parameter.default
  if parameter.name == 'name' and isinstance(default, str):
    return 'label'
  if isinstance(default, bool):
    return bool
  if isinstance(default, (int, float, str)):
    return type(default)
  if isinstance(default, (tuple, list)):
    if all(isinstance(x, str) for x in default):
      return 'names'
    if len(default) == 2 and all(type(x) is int for x in default):
      return 'int_pair'
    return 'signed_range' if min(default) < 0 else tuple
  raise AssertionError(
      f'{cls.__name__}({parameter.name}=...): add its kind to _KINDS '
      f'(default {default!r}).'
  )


def _cases():
  cases = []
  for name, cls in sorted(_CLASSES.items()):
    for parameter in _parameters(cls):
      if parameter.kind in (parameter.VAR_KEYWORD, parameter.VAR_POSITIONAL):
        continue  # Passed on to a base class, whose own are swept.
      kind = _kind(cls, parameter)
      for bad in _BAD[kind] if kind is not None else ():
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


@functools.lru_cache(maxsize=None)
def _terrain():
  """The smallest terrain: two flat tiles of 1 m (no sub-terrain drawn)."""
  return terrain.TerrainGenerator(
      kinds=('flat',), levels=2, tile_size=1.0, border=0.0
  )


def _required(cls):
  """Minimal valid values for the arguments without a default."""
  spec = mujoco.MjSpec()
  body = spec.worldbody.add_body(name='trunk')
  body.add_joint(name='hinge', type=mujoco.mjtJoint.mjJNT_HINGE)
  motor = spec.add_actuator(
      name='motor', target='hinge', trntype=mujoco.mjtTrn.mjTRN_JOINT
  )
  return {
      pushes.Pushes: lambda: {'interval': 1},
      actuation_delay.ActuationDelay: lambda: {'actuators': [motor]},
      height_scan.HeightScan: lambda: {'frame': body},
      curriculum.TerrainCurriculum: lambda: {'terrain': _terrain()},
      contact_sensor.ContactSensor: lambda: {'rows': ['foot']},
      contact.ContactFeature: lambda: {'kind': 'touching', 'first': 'foot'},
      policy_critic.policy_observable: lambda: {
          'obs': observable.Generic(lambda physics: 0.0),
          'n_sub_steps': 1,
      },
  }.get(cls, dict)()


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


def test_sweep_covers_every_locomotion_part():
  public = set()
  prefix = f'{locomotion_package.__name__}.'
  for info in pkgutil.walk_packages(locomotion_package.__path__, prefix):
    name = info.name
    module = importlib.import_module(name)
    public |= {
        value
        for key, value in vars(module).items()
        if inspect.isclass(value)
        and value.__module__ == name
        and not key.startswith('_')
    }
  # The height field and its arena base are built by the terrain arenas
  # (swept above), not by users; the terrain tasks' part by those tasks.
  built_by_parts = {
      surface.HeightField,
      surface.HeightFieldArena,
      terrain_part.TerrainPart,
  }
  missing = public - set(_PARTS) - set(_HELPERS) - built_by_parts
  assert not missing, (
      f'Add {sorted(c.__name__ for c in missing)} to _PARTS (with its '
      'required arguments in _required), so that its arguments are swept.'
  )


@pytest.mark.parametrize('cls', _PARTS + _HELPERS, ids=lambda c: c.__name__)
def test_minimal_valid_arguments_are_accepted(cls):
  """The sweep's refusals come from the bad value, not a bad baseline."""
  cls(**_required(cls))


def test_exceptions_name_real_arguments():
  for name, argument, *_ in list(ACCEPTED) + list(RESOLVED_LATER):
    assert argument in {p.name for p in _parameters(_CLASSES[name])}
