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
  """The base class of tasks.

  A task names the root entity of the scene, its timesteps, its observables
  and its outcome (reward, discount, termination), and takes part in the
  environment's hooks: on the host once, when the `Environment` is built
  (`initialize_episode_mjcf`, `after_compile`), and on the device in every
  episode and step of every world (`initialize_episode`, `before_step`,
  `before_substep`, `after_substep`, `after_step`). The task's hooks run
  before its entities' (composer's order).

  The device hooks and outcome methods are traced by `jax.jit` once and then
  run for every world under `jax.vmap`. So, unlike composer's, they:

  * are pure: they take a `Physics` and a PRNG key and return the new
    `Physics` (an unchanged one if they change nothing); `physics` is never
    modified in place;
  * keep nothing on `self`, which every world shares and which is read only
    while tracing: per-world values live in task state
    (`initial_task_state`, `physics.task_state`,
    `physics.update_task_state(...)`) or, for a world's whole life, in
    persistent entries (`physics.set_persistent`);
  * draw randomness from `key` only (`jax.random`), never from NumPy or
    Python's `random`, so that the same key gives the same episode;
  * branch on traced values with `jnp.where` / `jax.lax`, not Python `if`;
    Python side effects (printing, appending to lists) happen once, at
    trace time.

  After a step hook moves bodies (writes `qpos`), call `physics.forward()`
  (or `physics.kinematics()`) before reading positions: MJX has no lazy
  forward pass, and a stale read is a trace-time `StaleReadError`. In
  `initialize_episode` such a read runs the forward pass's stage it needs,
  as composer's reset context does.
  """

  @property
  @abc.abstractmethod
  def root_entity(self):
    """The root `Entity` (usually an `Arena`) of the scene."""

  def iter_entities(self):
    """Every entity of the scene: the root, then its descendants depth first."""
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
    """The observation groups of the environment's observation.

    Override it to split the observation, e.g.
    `{'policy': ObservationGroup(keys=[...]), 'critic': ...}` (see
    `observation.groups`): the observation is then `{group: its value}`.

    Returns:
      `{group name: ObservationGroup}`, or None (the default): the
      observation is one dict of every enabled observable.
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
    """Sets both timesteps, checking that one divides the other.

    Args:
      control_timestep: the agent's timestep, in seconds.
      physics_timestep: the physics timestep, in seconds.

    Raises:
      ValueError: unless `control_timestep` is an integer multiple of
        `physics_timestep`, both positive and finite.
    """
    check_timesteps_divisible(control_timestep, physics_timestep)
    self._check_root_entity().mjcf_model.option.timestep = physics_timestep
    self._control_timestep = control_timestep

  @property
  def physics_steps_per_control_step(self) -> int:
    """How many physics steps one control step runs."""
    return check_timesteps_divisible(
        self.control_timestep, self.physics_timestep
    )

  # -- specs ---------------------------------------------------------------

  def action_spec(self, physics) -> specs.BoundedArray:
    """A `BoundedArray` over all actuators' controls, from `ctrlrange`.

    Unlimited actuators get ±mjMAXVAL, like `mujoco.action_spec`. The spec's
    name is the tab-separated actuator names. When overriding it, put
    actions that drive no MuJoCo actuator first, as composer's convention
    is, and override `before_step` to apply them.

    Args:
      physics: the environment's initial `Physics` (for the model's
        actuators).

    Returns:
      The spec of one world's action.
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

    Returns:
      A pytree of arrays (e.g. `{'target': jnp.zeros(3)}`), read in hooks as
      `physics.task_state` and written with `physics.update_task_state`.
    """
    return {}

  # -- hooks ---------------------------------------------------------------
  # Build time (host): run once, when the `Environment` is built.

  def initialize_episode_mjcf(self, random_state):
    """Edits the scene's specs before the model is compiled.

    Runs once, when the `Environment` is built (composer runs it before
    every episode; the model here is compiled once). It may add, remove or
    edit elements of the entities' specs. Per-episode changes belong in
    `initialize_episode` instead (a variation writes per-world model
    fields), except composer's `mjcf_variator.apply_variations(random_state)`:
    called here, it has the environment apply that `MJCFVariator` at every
    reset, per world, before the `initialize_episode` hooks.

    Args:
      random_state: a `numpy.random.RandomState` (the `Environment`'s
        `random_state`).
    """

  def after_compile(self, physics, random_state):
    """Runs once, after the model is compiled and put on the device.

    It may read the compiled model (`physics.mj_model`, `physics.bind`) and
    cache what later hooks need (e.g. element indices) on `self`, which is
    allowed here: it runs on the host, not per world.

    Args:
      physics: the `Physics` of the compiled model at `qpos0`.
      random_state: a `numpy.random.RandomState` (the `Environment`'s
        `random_state`).

    Returns:
      None, or a `Physics` whose model the environment keeps (to change
      model fields shared by every world).
    """

  # Device (pure): traced once, run for every world; each returns the
  # new Physics.

  def initialize_episode(self, physics, key):
    """Sets up an episode of one world.

    Runs at every reset, after the model's default state (`qpos0`) and its
    kinematics, before the entities' `initialize_episode`. It may set the
    state (`qpos`, `qvel`, ...), write task state, write model fields
    (each such field becomes per-world and is found automatically), create
    persistent entries, schedule hooks with `physics.schedule_before_step`,
    and report a failed initialization with `physics.fail_initialization()`
    (the environment retries up to `max_reset_attempts` times).

    Args:
      physics: one world's `Physics`.
      key: a PRNG key for this hook's draws.

    Returns:
      The new `Physics`.
    """
    del key
    return physics

  def before_step(self, physics, action, key):
    """Applies the action, before the control step's physics steps.

    The default writes `action` into the actuators' controls. Overrides
    must still set the control, through `super().before_step(...)` or
    `physics.set_control(...)` (e.g. to clip or transform the action). It
    may write state, task state, persistent entries and model fields (a
    model field it writes is made per world from the reset on, found by an
    abstract trace of the step hooks); it may not add persistent entries or
    task state keys (their structure is fixed at reset).

    Args:
      physics: one world's `Physics`.
      action: one world's action, shaped as `action_spec`.
      key: a PRNG key for this hook's draws.

    Returns:
      The new `Physics`.
    """
    del key
    return physics.set_control(action)

  def before_substep(self, physics, action, key):
    """Runs before each physics step of the control step.

    Actuation may be set, or overridden, here. What it may write is what
    `before_step` may.

    Args:
      physics: one world's `Physics`.
      action: one world's action, as given to `before_step`.
      key: a PRNG key for this hook's draws (a different one every
        sub-step).

    Returns:
      The new `Physics`.
    """
    del action, key
    return physics

  def after_substep(self, physics, key):
    """Runs after each physics step of the control step.

    What it may write is what `before_step` may.

    Args:
      physics: one world's `Physics`.
      key: a PRNG key for this hook's draws (a different one every
        sub-step).

    Returns:
      The new `Physics`.
    """
    del key
    return physics

  def after_step(self, physics, key):
    """Runs after the control step's physics steps.

    It runs before the last observation update and the reward, discount and
    termination, which see what it writes. What it may write is what
    `before_step` may.

    Args:
      physics: one world's `Physics`.
      key: a PRNG key for this hook's draws.

    Returns:
      The new `Physics`.
    """
    del key
    return physics

  # -- outcome -------------------------------------------------------------
  # Pure functions of the physics after a control step; they write nothing.
  # The physics they receive is read only (`Physics.read_only`): a write
  # raises `physics.ReadOnlyPhysicsError` while the step is traced. A
  # count or other state that composer's tasks update in `get_reward`
  # is updated in `after_step`, and read here.

  @abc.abstractmethod
  def get_reward(self, physics):
    """The reward of the control step that ended in `physics`.

    Args:
      physics: one world's `Physics` after the step's hooks.

    Returns:
      A scalar (or an array matching `get_reward_spec`).
    """

  def get_discount(self, physics):
    """The discount of the control step that ended in `physics`.

    Args:
      physics: one world's `Physics` after the step's hooks.

    Returns:
      A scalar in [0, 1] (or an array matching `get_discount_spec`); 1.0 by
      default.
    """
    del physics
    return 1.0

  def should_terminate_episode(self, physics):
    """Whether the episode ends at `physics` (a termination, not a
    truncation: the step's discount is `get_discount`'s).

    Args:
      physics: one world's `Physics` after the step's hooks.

    Returns:
      A boolean scalar; False by default.
    """
    del physics
    return False

  def get_metrics(self, physics):
    """Extra per-world metrics, reported in `State.metrics` every step.

    Args:
      physics: one world's `Physics` after the step's hooks (or after the
        reset, at the start of an episode).

    Returns:
      `{name: scalar}`, the same names at every step (stored as float32).
    """
    del physics
    return {}


class NullTask(Task):
  """A task with no reward: for exploring a scene.

  Args:
    root_entity: the scene's root `Entity` (usually an `Arena`).
  """

  def __init__(self, root_entity):
    self._root_entity = root_entity

  @property
  def root_entity(self):
    return self._root_entity

  def get_reward(self, physics):
    del physics
    return 0.0
