"""Named tasks: the bundled ones, and your own, built by name.

    from mjx_composer.suite.tasks import registry

    registry.names()                     # ('reach', 'push', 'walk', ...)
    env = registry.make_environment(
        'walk', time_limit=25.0,
        options=composer.ExecutionOptions(auto_reset='same_step'))

Register a task under a name with a factory that returns a new `Task`:

    @registry.register('balance', description='Keep the pole up.')
    def make_balance():
      return Balance(pole_length=0.5)

    registry.register('balance_long', lambda: Balance(pole_length=1.0))

The command line (`mjx-composer list`, `mjx-composer demo --task NAME`,
`mjx-composer train NAME`), the examples and the benchmarks find tasks here,
so a task registered before they run (e.g. in a module they import, or a
script that registers it and then calls `mjx_composer.cli.main`) is
available to them by name. Its training defaults, if it needs its own, go to
`mjx_composer.training.config.register_defaults`.

The bundled tasks (reach, push, walk, joystick, joystick_rough,
joystick_terrain, walk_terrain) are registered when this module is
imported, but their modules are imported only when a task is built: building
the walk task does not import the Go1's, and `mjx-composer list` imports
none.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

from mjx_composer import environment as environment_lib
from mjx_composer import task as task_lib

TaskFactory = Callable[[], task_lib.Task]


@dataclasses.dataclass(frozen=True)
class Entry:
  """A registered task.

  Attributes:
    name: the name it is built by.
    factory: called with no arguments, returns a new `Task`.
    description: one line for `mjx-composer list`.
    distance: what the task's 'distance' metric measures (for the demo's
      summary), or None if it reports none.
  """

  name: str
  factory: TaskFactory
  description: str = ''
  distance: str | None = None


_ENTRIES: dict[str, Entry] = {}


def register(
    name: str,
    factory: TaskFactory | None = None,
    *,
    description: str = '',
    distance: str | None = None,
):
  """Registers a task factory under `name`.

  As a call, `register(name, factory, ...)` returns `factory`; without a
  factory, `register(name, ...)` is a decorator for one.

  Args:
    name: a new name, without whitespace.
    factory: called with no arguments, returns a new `Task`.
    description: one line for `mjx-composer list` (defaults to the first
      line of the factory's docstring).
    distance: what the task's 'distance' metric measures, if it reports
      one.

  Returns:
    `factory`, or a decorator that registers the function it decorates.

  Raises:
    ValueError: for a name already registered, or an empty name or one with
      whitespace.
    TypeError: for a factory that is not callable.
  """
  if not isinstance(name, str) or not name or name != ''.join(name.split()):
    raise ValueError(
        f'A task name is a non-empty string without whitespace, got {name!r}.'
    )
  if name in _ENTRIES:
    raise ValueError(
        f'A task named {name!r} is already registered '
        f'({_ENTRIES[name].description or "no description"}); choose another '
        'name, or unregister it first.'
    )

  def add(factory):
    if not callable(factory):
      raise TypeError(
          f'register({name!r}, factory): the factory must be callable, got '
          f'{factory!r}.'
      )
    doc = (getattr(factory, '__doc__', None) or '').strip()
    _ENTRIES[name] = Entry(
        name,
        factory,
        description or (doc.splitlines()[0] if doc else ''),
        distance,
    )
    return factory

  if factory is None:
    return add
  return add(factory)


def unregister(name: str) -> None:
  """Removes a registered task (e.g. to register it again)."""
  entry(name)
  del _ENTRIES[name]


def names() -> tuple[str, ...]:
  """The registered task names, in the order they were registered."""
  return tuple(_ENTRIES)


def entry(name: str) -> Entry:
  """The registered `Entry` of `name`.

  Raises:
    KeyError: for a name that is not registered; the message lists those
      that are.
  """
  try:
    return _ENTRIES[name]
  except KeyError:
    raise KeyError(
        f'Unknown task {name!r}; registered tasks: {", ".join(_ENTRIES)}. '
        'Add your own with mjx_composer.suite.tasks.registry.register.'
    ) from None


def describe(name: str) -> str:
  """The one-line description of a registered task."""
  return entry(name).description


def make_task(name: str) -> task_lib.Task:
  """A new `Task` of the registered `name`."""
  task = entry(name).factory()
  if not isinstance(task, task_lib.Task):
    raise TypeError(
        f'The factory registered as {name!r} returned {task!r}, not a Task.'
    )
  return task


def make_environment(
    name: str,
    time_limit: float = float('inf'),
    options: environment_lib.ExecutionOptions | None = None,
    **kwargs,
) -> environment_lib.Environment:
  """`Environment(make_task(name), time_limit, options=options, **kwargs)`.

  Args:
    name: a registered task name (`names()`).
    time_limit: episode length in seconds (truncation); `inf` for none.
    options: the `ExecutionOptions` (None: the defaults).
    **kwargs: `Environment`'s other arguments (e.g. `random_state`,
      `max_reset_attempts`).

  Returns:
    The `Environment`, observing the task's observation groups.

  Raises:
    KeyError: for a name that is not registered.
  """
  return environment_lib.Environment(
      make_task(name), time_limit=time_limit, options=options, **kwargs
  )


# -- the bundled tasks ---------------------------------------------------------
# Each factory imports its task's module when called, so that importing the
# registry (and listing the tasks) loads no robot or terrain code.
# pylint: disable=g-import-not-at-top


@register(
    'reach',
    description='An arm moves its hand to a target sampled per episode.',
    distance='hand-target distance',
)
def _reach():
  from mjx_composer.suite.tasks import reach

  return reach.Reach()


@register(
    'push',
    description='The arm sweeps randomly placed boxes into a target zone.',
    distance='box-zone distance',
)
def _push():
  from mjx_composer.suite.tasks import push

  return push.Push()


@register(
    'walk',
    description=(
        "The suite's humanoid walks at a target speed (Playground's "
        'HumanoidWalk).'
    ),
    distance='distance walked',
)
def _walk():
  from mjx_composer.suite.tasks import walk

  return walk.Walk()


@register(
    'joystick',
    description=(
        'A Unitree Go1 tracks a commanded velocity and yaw rate on flat '
        "ground (Playground's Go1JoystickFlatTerrain)."
    ),
    distance='distance travelled',
)
def _joystick():
  from mjx_composer.suite.tasks import joystick

  return joystick.Joystick(terrain='flat')


@register(
    'joystick_rough',
    description=(
        'The Go1 tracks commands on rough terrain, a height field per world '
        "(Playground's Go1JoystickRoughTerrain)."
    ),
    distance='distance travelled',
)
def _joystick_rough():
  from mjx_composer.suite.tasks import joystick

  return joystick.Joystick(terrain='rough')


@register(
    'joystick_terrain',
    description=(
        'The Go1 tracks commands on generated terrain (slopes, stairs, '
        'stepping stones, ...) with a terrain curriculum, a height scan and '
        "actuation delay (Isaac Lab's and mjlab's rough velocity task)."
    ),
    distance='distance travelled',
)
def _joystick_terrain():
  from mjx_composer.suite.tasks import joystick_terrain

  return joystick_terrain.TerrainJoystick()


@register(
    'walk_terrain',
    description=(
        'The humanoid walks on generated terrain (slopes, waves, stairs) '
        'with a terrain curriculum and a height scan.'
    ),
    distance='distance walked',
)
def _walk_terrain():
  from mjx_composer.suite.tasks import walk_terrain

  return walk_terrain.TerrainWalk()
