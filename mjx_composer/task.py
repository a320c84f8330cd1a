"""`Task`: what the agent should do in a composed scene.

A task names its root entity, sets the control and physics timesteps, and
defines reward, discount and termination as pure functions of a `Physics`.
Its hooks run before the entities' hooks (composer's order) and, like theirs,
are pure: they take a `Physics` and a PRNG key and return the new `Physics`.

Per-world task state (a sampled target, a counter) does not live on `self`,
which is shared by every world: declare it in `initial_task_state()` and read
or write it through `physics.task_state` / `physics.update_task_state(...)`.
"""

import abc
import collections
import math

from dm_env import specs
import mujoco
import numpy as np

_MJMAXVAL = 1e10  # mujoco.mjMAXVAL: the bound of unlimited controls.
_DEFAULT_PHYSICS_TIMESTEP = 0.002


def check_timestep(name, value) -> float:
  """Returns `value` as float seconds; raises unless positive and finite."""
  try:
    if isinstance(value, (bool, str, bytes)):
      raise TypeError
    seconds = float(value)
  except (TypeError, ValueError):
    raise TypeError(
        f'{name} must be a number of seconds, got {type(value).__name__} '
        f'{value!r}.'
    ) from None
  if not math.isfinite(seconds) or seconds <= 0:
    raise ValueError(
        f'{name} must be a positive, finite number of seconds, got {value!r}. '
        'Set both timesteps with e.g. task.set_timesteps(control_timestep=0.02,'
        ' physics_timestep=0.002): the control timestep an integer multiple of'
        ' the physics timestep.'
    )
  return seconds


def check_timesteps_divisible(control_timestep, physics_timestep) -> int:
  """Returns control/physics as an int, or raises composer's ValueError.

  Both must be positive, finite numbers of seconds (ValueError otherwise).
  """
  physics_timestep = check_timestep('physics_timestep', physics_timestep)
  control_timestep = check_timestep('control_timestep', control_timestep)
  num_steps = control_timestep / physics_timestep
  rounded = int(round(num_steps))
  if abs(num_steps - rounded) > 1e-6 or rounded < 1:
    raise ValueError(
        'Control timestep should be an integer multiple of physics timestep: '
        f'got {control_timestep!r} and {physics_timestep!r}.'
    )
  return rounded


class Task(abc.ABC):
  """The base class of tasks."""

  @property
  @abc.abstractmethod
  def root_entity(self):
    """The root `Entity` (usually an `Arena`) of the scene."""

  def iter_entities(self):
    return self.root_entity.iter_entities()

  # -- observables ---------------------------------------------------------

  @property
  def observables(self):
    """All observables: the task's, then every entity's (fully qualified).

    Subclasses should generally not override this; override
    `task_observables` instead. Disabled observables are included; the
    environment keeps only enabled ones.
    """
    observables = collections.OrderedDict(self.task_observables)
    for entity in self.root_entity.iter_entities():
      observables.update(entity.observables.as_dict())
    return observables

  @property
  def task_observables(self):
    """Task-level observables `{name: Observable}` (names not prefixed)."""
    return collections.OrderedDict()

  def observation_groups(self):
    """Observation groups `Environment` uses when given none (or None).

    E.g. `{'policy': ObservationGroup(keys=[...]), 'critic': ...}` (see
    `observation.groups`). None: the observation is one dict of every
    enabled observable.
    """
    return None

  # -- timesteps -----------------------------------------------------------

  def _check_root_entity(self):
    try:
      return self.root_entity
    except Exception as e:  # pylint: disable=broad-except
      raise RuntimeError(
          'The task has no root entity yet: set it up before '
          'asking for timesteps.'
      ) from e

  @property
  def physics_timestep(self) -> float:
    """The physics timestep, i.e. the root spec's `option.timestep`."""
    timestep = self._check_root_entity().mjcf_model.option.timestep
    return float(timestep) if timestep else _DEFAULT_PHYSICS_TIMESTEP

  @physics_timestep.setter
  def physics_timestep(self, value):
    check_timestep('physics_timestep', value)
    if getattr(self, '_control_timestep', None) is not None:
      check_timesteps_divisible(self._control_timestep, value)
    self._check_root_entity().mjcf_model.option.timestep = value

  @property
  def control_timestep(self) -> float:
    """The agent's timestep; defaults to one physics timestep."""
    self._check_root_entity()
    control = getattr(self, '_control_timestep', None)
    return self.physics_timestep if control is None else control

  @control_timestep.setter
  def control_timestep(self, value):
    check_timesteps_divisible(value, self.physics_timestep)
    self._control_timestep = value

  def set_timesteps(self, control_timestep, physics_timestep):
    """Sets both timesteps, checking that one divides the other."""
    check_timesteps_divisible(control_timestep, physics_timestep)
    self._check_root_entity().mjcf_model.option.timestep = physics_timestep
    self._control_timestep = control_timestep

  @property
  def physics_steps_per_control_step(self) -> int:
    return check_timesteps_divisible(
        self.control_timestep, self.physics_timestep
    )

  # -- specs ---------------------------------------------------------------

  def action_spec(self, physics) -> specs.BoundedArray:
    """A BoundedArray over all actuators' controls, from `ctrlrange`.

    Unlimited actuators get ±mjMAXVAL, like `mujoco.action_spec`.
    """
    model = physics.mj_model
    limited = np.asarray(model.actuator_ctrllimited, bool)
    ctrlrange = np.asarray(model.actuator_ctrlrange, float).reshape(-1, 2)
    minimum = np.where(limited, ctrlrange[:, 0], -_MJMAXVAL)
    maximum = np.where(limited, ctrlrange[:, 1], _MJMAXVAL)
    names = [
        mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, i) or str(i)
        for i in range(model.nu)
    ]
    return specs.BoundedArray(
        shape=(model.nu,),
        dtype=np.float32,
        minimum=minimum.astype(np.float32),
        maximum=maximum.astype(np.float32),
        name='\t'.join(names),
    )

  def get_reward_spec(self):
    """An optional non-scalar reward spec; None means a float scalar."""
    return None

  def get_discount_spec(self):
    """An optional non-scalar discount spec; None means a float scalar."""
    return None

  # -- per-world state -----------------------------------------------------

  def initial_task_state(self):
    """The per-world task state at the start of an episode (a pytree).

    Its structure, shapes and dtypes are fixed for the environment's life;
    `initialize_episode` typically overwrites the values.
    """
    return {}

  # -- hooks ---------------------------------------------------------------
  # Build time (host).

  def initialize_episode_mjcf(self, random_state):
    """Edits specs before compilation. Runs once, at environment build."""

  def after_compile(self, physics, random_state):
    """Runs once after compilation; may return a Physics whose model is kept."""

  # Device (pure): each returns the new Physics.

  def initialize_episode(self, physics, key):
    """Sets up an episode (after qpos0, before entities' hooks)."""
    return physics

  def before_step(self, physics, action, key):
    """Applies the action. The default writes it into `ctrl`.

    Overrides must still set the control, e.g. through
    `super().before_step(...)` or `physics.set_control(...)`.
    """
    del key
    return physics.set_control(action)

  def before_substep(self, physics, action, key):
    """Runs before each physics sub-step; actuation may be set here."""
    del action, key
    return physics

  def after_substep(self, physics, key):
    del key
    return physics

  def after_step(self, physics, key):
    del key
    return physics

  # -- outcome -------------------------------------------------------------

  @abc.abstractmethod
  def get_reward(self, physics):
    """The reward (a scalar, or matching `get_reward_spec`)."""

  def get_discount(self, physics):
    del physics
    return 1.0

  def should_terminate_episode(self, physics):
    del physics
    return False

  def get_metrics(self, physics):
    """Extra per-world metrics `{name: scalar}` reported in `State.metrics`."""
    del physics
    return {}


class NullTask(Task):
  """A task with no reward: for exploring a scene."""

  def __init__(self, root_entity):
    self._root_entity = root_entity

  @property
  def root_entity(self):
    return self._root_entity

  def get_reward(self, physics):
    del physics
    return 0.0
