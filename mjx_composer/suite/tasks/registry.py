"""Named tasks: the bundled ones, and your own, each registered once.

    from mjx_composer.suite.tasks import registry

    registry.names()                     # ('reach', 'push', 'walk', ...)
    env = registry.make_environment(
        'walk', time_limit=25.0,
        options=composer.ExecutionOptions(auto_reset='same_step'))

A task is registered under a name with everything the tools need to know
about it, in one place: a factory that returns a new `Task` and the keyword
arguments it is called with, a one-line description (`mjx-composer list`),
its training defaults (`TrainConfig` fields, read by
`mjx_composer.training.config.defaults`), the camera its videos are
rendered from, and the metrics it reports (`mjx-composer demo` prints their
episode-end means):

    registry.register(
        'balance', Balance, kwargs=dict(pole_length=0.5),
        description='Keep the pole up.',
        training=dict(time_limit=10.0, num_timesteps=20_000_000),
        camera='cart/side',
        metrics={'angle': 'the pole angle at the episode end (rad)'})

    @registry.register('balance_short', description='A short pole.')
    def make_balance_short():
      return Balance(pole_length=0.25)

The command line (`mjx-composer list|demo|train|play|export`), the examples
and the benchmarks find tasks here by name. Your own tasks reach them in
one of three ways: a module that registers them, named by `--import MODULE`
on the command line (`import_modules`; `train` records it in the run
folder, so `play`, `export` and `--resume` import it again); a distribution
that declares the module in the entry-point group `mjx_composer.tasks`
(`[project.entry-points."mjx_composer.tasks"] NAME = "module"` in its
pyproject.toml), imported on the registry's first lookup; or a script that
registers them and then calls `mjx_composer.cli.main`.

The bundled tasks (reach, push, walk, joystick, joystick_rough,
joystick_terrain, walk_terrain) are registered when this module is
imported, but their modules are imported only when a task is built: building
the walk task does not import the Go1's, and `mjx-composer list` imports
none of them, nor MJX.
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.metadata
import typing
from typing import Any, Callable, Iterable, Mapping

if typing.TYPE_CHECKING:  # imported where used: listing tasks loads no MJX
  from mjx_composer import environment as environment_lib
  from mjx_composer import task as task_lib

TaskFactory = Callable[..., 'task_lib.Task']
ENTRY_POINT_GROUP = 'mjx_composer.tasks'


class UnknownTaskError(KeyError):
  """A task name that is not registered (the message lists those that are)."""

  def __str__(self):
    return str(self.args[0]) if self.args else ''


class TaskModuleError(ImportError):
  """A module named to register tasks that could not be imported."""


@dataclasses.dataclass(frozen=True)
class Entry:
  """A registered task.

  Attributes:
    name: the name it is built by.
    factory: called with `kwargs` (and `make_task`'s overrides), returns a
      new `Task`.
    kwargs: the keyword arguments the factory is called with.
    description: one line for `mjx-composer list`.
    training: the task's training defaults, `TrainConfig` field -> value
      (checked by `mjx_composer.training.config.defaults`).
    camera: name of a camera of the compiled model that follows the robot,
      for videos; None: a free camera looking at the workspace.
    metrics: name of a `State.metrics` entry the task reports -> a one-line
      description (with its unit).
  """

  name: str
  factory: TaskFactory
  kwargs: dict[str, Any] = dataclasses.field(default_factory=dict)
  description: str = ''
  training: dict[str, Any] = dataclasses.field(default_factory=dict)
  camera: str | None = None
  metrics: dict[str, str] = dataclasses.field(default_factory=dict)


_ENTRIES: dict[str, Entry] = {}
# Whether the entry-point group has been imported (None: being imported).
_entry_points_loaded: bool | None = False


def _check_mapping(name, what, value, values_type=None):
  if not isinstance(value, Mapping) or not all(
      isinstance(k, str) for k in value
  ):
    raise TypeError(
        f'register({name!r}, ...): {what} must be a mapping with string '
        f'keys, got {value!r}.'
    )
  if values_type and not all(
      isinstance(v, values_type) for v in value.values()
  ):
    raise TypeError(
        f'register({name!r}, ...): the values of {what} must be '
        f'{values_type.__name__}s (one-line descriptions), got {value!r}.'
    )
  return dict(value)


def register(
    name: str,
    factory: TaskFactory | None = None,
    *,
    kwargs: Mapping[str, Any] | None = None,
    description: str = '',
    training: Mapping[str, Any] | None = None,
    camera: str | None = None,
    metrics: Mapping[str, str] | None = None,
):
  """Registers a task under `name`, with all its facts.

  As a call, `register(name, factory, ...)` returns `factory`; without a
  factory, `register(name, ...)` is a decorator for one.

  Args:
    name: a new name, without whitespace.
    factory: called with `kwargs`, returns a new `Task` (a `Task` subclass,
      or a function).
    kwargs: keyword arguments of the factory (default: none).
    description: one line for `mjx-composer list` (defaults to the first
      line of the factory's docstring).
    training: the task's training defaults, `TrainConfig` field -> value
      (e.g. `time_limit`, `num_timesteps`); checked against `TrainConfig`'s
      fields when a run reads them (`training.config.defaults`).
    camera: name of a camera of the compiled model to render videos from
      (e.g. 'robot/tracking', one that follows the robot); None: a free
      camera looking at the workspace.
    metrics: name of a `State.metrics` entry the task reports (its
      `get_metrics`) -> a one-line description with its unit.

  Returns:
    `factory`, or a decorator that registers the function it decorates.

  Raises:
    ValueError: for a name already registered, or an empty name or one with
      whitespace.
    TypeError: for a factory that is not callable, `kwargs`, `training` or
      `metrics` that are not mappings with string keys (and, for `metrics`,
      string values), or a camera that is not a string or None.
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
  kwargs = _check_mapping(name, 'kwargs', {} if kwargs is None else kwargs)
  training = _check_mapping(
      name, 'training', {} if training is None else training
  )
  metrics = _check_mapping(
      name, 'metrics', {} if metrics is None else metrics, str
  )
  if camera is not None and (not isinstance(camera, str) or not camera):
    raise TypeError(
        f'register({name!r}, ...): camera must be the name of a camera of '
        f'the compiled model, or None for a free camera; got {camera!r}.'
    )
  if not isinstance(description, str) or '\n' in description:
    raise TypeError(
        f'register({name!r}, ...): description must be one line of text, '
        f'got {description!r}.'
    )

  def add(factory):
    if not callable(factory):
      raise TypeError(
          f'register({name!r}, factory): the factory must be callable, got '
          f'{factory!r}.'
      )
    doc = (getattr(factory, '__doc__', None) or '').strip()
    _ENTRIES[name] = Entry(
        name=name,
        factory=factory,
        kwargs=kwargs,
        description=description or (doc.splitlines()[0] if doc else ''),
        training=training,
        camera=camera,
        metrics=metrics,
    )
    return factory

  if factory is None:
    return add
  return add(factory)


def unregister(name: str) -> None:
  """Removes a registered task (e.g. to register it again)."""
  entry(name)
  del _ENTRIES[name]


def _import(module: str, source: str) -> None:
  """Imports `module`; TaskModuleError in one line if it fails."""
  if not isinstance(module, str) or not module.strip():
    raise TaskModuleError(
        f'A task module is a module name (e.g. my_tasks), got {module!r}.'
    )
  try:
    importlib.import_module(module)
  except Exception as e:  # Whatever the module raised, said in one line.
    reason = ' '.join(str(e).split())
    raise TaskModuleError(
        f'Could not import the task module {module!r} ({source}): '
        f'{type(e).__name__}: {reason}'
    ) from e


def import_modules(module_names: Iterable[str]) -> None:
  """Imports modules that register tasks (the command line's `--import`).

  Each is imported as `import MODULE` would (a module imported before is not
  run again), so the tasks it registers are available by name.

  Raises:
    TaskModuleError: for a module that cannot be imported, naming it and
      the exception, in one line.
  """
  if isinstance(module_names, str):
    raise TypeError(
        f'import_modules takes a sequence of module names, got the string '
        f'{module_names!r}; pass [{module_names!r}].'
    )
  for module in module_names:
    _import(module, '--import')


def _load_entry_points() -> None:
  """Imports the modules of the `mjx_composer.tasks` entry points, once."""
  global _entry_points_loaded
  if _entry_points_loaded is not False:
    return  # loaded, or loading (a plugin that looks tasks up)
  _entry_points_loaded = None
  try:
    for point in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
      dist = getattr(point.dist, 'name', None) or 'an installed distribution'
      _import(
          point.value.partition(':')[0].strip(),
          f'entry point {point.name!r} of {dist} in the group '
          f'{ENTRY_POINT_GROUP!r}; fix or uninstall it',
      )
  except BaseException:
    _entry_points_loaded = False  # say so again at the next lookup
    raise
  _entry_points_loaded = True


def names() -> tuple[str, ...]:
  """The registered task names, in the order they were registered."""
  _load_entry_points()
  return tuple(_ENTRIES)


def entry(name: str) -> Entry:
  """The registered `Entry` of `name`.

  Raises:
    UnknownTaskError: (a KeyError) for a name that is not registered; the
      message lists those that are.
  """
  _load_entry_points()
  try:
    return _ENTRIES[name]
  except (KeyError, TypeError):
    raise UnknownTaskError(
        f'Unknown task {name!r}; registered tasks: {", ".join(_ENTRIES)}. '
        'Register your own with mjx_composer.suite.tasks.registry.register, '
        'in a module the command line imports with --import MODULE.'
    ) from None


def describe(name: str) -> str:
  """The one-line description of a registered task."""
  return entry(name).description


def make_task(name: str, **overrides) -> task_lib.Task:
  """A new `Task` of `name`: its factory called with its kwargs + `overrides`."""
  from mjx_composer import task as task_lib  # pylint: disable=g-import-not-at-top,redefined-outer-name

  registered = entry(name)
  task = registered.factory(**{**registered.kwargs, **overrides})
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
    UnknownTaskError: for a name that is not registered.
  """
  from mjx_composer import environment as environment_lib  # pylint: disable=g-import-not-at-top,redefined-outer-name

  return environment_lib.Environment(
      make_task(name), time_limit=time_limit, options=options, **kwargs
  )


# -- the bundled tasks ---------------------------------------------------------
# Each factory imports its task's module when called, so that importing the
# registry (and listing the tasks) loads no robot or terrain code.


@dataclasses.dataclass(frozen=True)
class _Bundled:
  """A bundled task's class, imported from its module when called."""

  module: str
  cls: str

  def __call__(self, **kwargs) -> task_lib.Task:
    module = importlib.import_module(f'mjx_composer.suite.tasks.{self.module}')
    return getattr(module, self.cls)(**kwargs)


# MuJoCo Playground's PPO settings for HumanoidWalk (dm_control_suite_params);
# the episode is walk.EPISODE_SECONDS.
_PLAYGROUND_WALK = dict(
    num_timesteps=60_000_000,
    num_evals=10,
    reward_scaling=10.0,
    normalize=True,
    time_limit=25.0,
    unroll_length=30,
    num_minibatches=32,
    num_updates_per_batch=16,
    discounting=0.995,
    learning_rate=1e-3,
    entropy_cost=1e-2,
    num_envs=2048,
    batch_size=1024,
    init_noise_std=1.0,
    policy_layers=(32, 32, 32, 32),
    value_layers=(256, 256, 256, 256, 256),
    video_steps=200,
)
# Its PPO settings for Go1JoystickFlatTerrain / RoughTerrain
# (locomotion_params), whose critic sees the privileged state; the episode is
# joystick.EPISODE_SECONDS.
_PLAYGROUND_JOYSTICK = dict(
    num_timesteps=200_000_000,
    num_evals=10,
    reward_scaling=1.0,
    normalize=True,
    time_limit=20.0,
    unroll_length=20,
    num_minibatches=32,
    num_updates_per_batch=4,
    discounting=0.97,
    learning_rate=3e-4,
    entropy_cost=1e-2,
    num_envs=8192,
    batch_size=256,
    max_grad_norm=1.0,
    init_noise_std=1.0,
    policy_layers=(512, 256, 128),
    value_layers=(512, 256, 128),
    critic_obs='critic',
    video_steps=200,
)
_WALK_METRICS = {
    'distance': "the torso's horizontal distance from its start (m)",
    'speed': "the centre of mass's horizontal speed (m/s)",
    'head_height': "the head's height (m)",
}
_JOYSTICK_METRICS = {
    'distance': "the trunk's horizontal distance from its start (m)",
    'velocity_error': 'commanded minus actual horizontal velocity (m/s)',
    'yaw_rate_error': 'commanded minus actual yaw rate (rad/s)',
}
_TERRAIN_LEVEL = {'terrain_level': "the curriculum's terrain level"}

# reach's training defaults are `TrainConfig`'s own.
register(
    'reach',
    _Bundled('reach', 'Reach'),
    description='An arm moves its hand to a target sampled per episode.',
    metrics={'distance': 'hand-target distance (m)'},
)
register(
    'push',
    _Bundled('push', 'Push'),
    description='The arm sweeps randomly placed boxes into a target zone.',
    metrics={
        'distance': 'mean box-zone distance (m)',
        'boxes_in_zone': 'boxes in the target zone',
    },
)
register(
    'walk',
    _Bundled('walk', 'Walk'),
    description=(
        "The suite's humanoid walks at a target speed (Playground's "
        'HumanoidWalk).'
    ),
    training=_PLAYGROUND_WALK,
    camera='humanoid/side',
    metrics=_WALK_METRICS,
)
register(
    'joystick',
    _Bundled('joystick', 'Joystick'),
    kwargs=dict(terrain='flat'),
    description=(
        'A Unitree Go1 tracks a commanded velocity and yaw rate on flat '
        "ground (Playground's Go1JoystickFlatTerrain)."
    ),
    training=_PLAYGROUND_JOYSTICK,
    camera='go1/tracking',
    metrics=_JOYSTICK_METRICS,
)
register(
    'joystick_rough',
    _Bundled('joystick', 'Joystick'),
    kwargs=dict(terrain='rough'),
    description=(
        'The Go1 tracks commands on rough terrain, a height field per world '
        "(Playground's Go1JoystickRoughTerrain)."
    ),
    training=_PLAYGROUND_JOYSTICK,
    camera='go1/tracking',
    metrics=_JOYSTICK_METRICS,
)
# The terrain tasks train with their flat twins' settings (joystick_terrain's
# critic sees the clean height scan and the privileged state).
register(
    'joystick_terrain',
    _Bundled('joystick_terrain', 'TerrainJoystick'),
    description=(
        'The Go1 tracks commands on generated terrain (slopes, stairs, '
        'stepping stones, ...) with a terrain curriculum, a height scan and '
        "actuation delay (Isaac Lab's and mjlab's rough velocity task)."
    ),
    training=_PLAYGROUND_JOYSTICK,
    camera='go1/tracking',
    metrics={**_JOYSTICK_METRICS, **_TERRAIN_LEVEL},
)
register(
    'walk_terrain',
    _Bundled('walk_terrain', 'TerrainWalk'),
    description=(
        'The humanoid walks on generated terrain (slopes, waves, stairs) '
        'with a terrain curriculum and a height scan.'
    ),
    training=_PLAYGROUND_WALK,
    camera='humanoid/side',
    metrics={**_WALK_METRICS, **_TERRAIN_LEVEL},
)
