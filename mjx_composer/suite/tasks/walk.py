"""Walk: the dm_control suite humanoid walks at a target speed.

MuJoCo Playground's `HumanoidWalk` (playground 0.2.0,
`dm_control_suite/humanoid.py`), composed from bundled parts: a `Floor`
arena and the `Humanoid` robot (the same XML). What is Playground's:

* timesteps: control 0.025 s, physics 0.005 s (5 sub-steps); episodes of
  1000 control steps are `Environment(task, time_limit=25.0)`
  (`EPISODE_SECONDS`), ended by truncation;
* the reward, `stand * move * small_control`, with Playground's constants:
  `stand` = tolerance(head height, >= 1.4 m, margin 0.35, gaussian) x
  tolerance(torso z axis . world z, >= 0.9, margin 1.9, linear, 0 at the
  margin); `small_control` = (4 + mean tolerance(control, margin 1,
  quadratic, 0 at the margin)) / 5; `move` = (5 x tolerance(horizontal
  centre-of-mass speed, >= 1 m/s, margin 1 m/s, linear, 0 at the margin) +
  1) / 6 (with `move_speed=0`: mean tolerance(horizontal velocity, margin 2)).
  The control is the world's `ctrl` (the action as written), the speed the
  torso subtree's linear velocity sensor;
* the observation `HumanoidWalk` returns (joint angles, head height,
  extremities in the torso frame, torso vertical, centre-of-mass velocity,
  free-joint and joint velocities) is the policy group's content.

What this task adds, each switchable, on composer's features (Playground's
task has none of them; `Walk(**PLAYGROUND_EQUIVALENT)` turns them off):

* observation noise (uniform, Playground's locomotion scales), latency
  (`observation_delay` physics sub-steps) and a history of `history` control
  steps of the joint readings, on the 'policy' group; the 'critic' group sees
  clean, current twins of the same values plus privileged ones (IMU, the
  last push);
* per-episode randomization (`randomize`) through one `MJCFVariator`: floor
  friction x U(0.7, 1.3), every body's geom densities (so link masses)
  x U(0.9, 1.1), motor gears (strength) x U(0.9, 1.1); and the initial pose:
  a random heading and joint angles within 0.1 rad of the XML's (Playground
  starts every episode from `qpos0`);
* pushes: every `push_interval` control steps a horizontal velocity change
  of U(0.1, 0.5) m/s in a random direction;
* early termination on falls (`terminate_on_fall`): the episode ends, with
  discount 0, when the head is below `fall_height` (0.8 m; standing, it is
  at about 1.5 m). Playground's episodes only end at the time limit.
"""

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer import task
from mjx_composer.observation import groups as groups_lib
from mjx_composer.observation import observable
from mjx_composer.suite.entities import arenas
from mjx_composer.suite.entities import humanoid as humanoid_lib
from mjx_composer.suite.locomotion import policy_critic
from mjx_composer.suite.locomotion import pushes as pushes_lib
from mjx_composer.utils import rewards
from mjx_composer.utils import transformations
from mjx_composer.utils import validation
from mjx_composer.variation import distributions
from mjx_composer.variation import mjcf_variator
from mjx_composer.variation import noises

# Playground's constants (dm_control's).
STAND_HEIGHT = 1.4
WALK_SPEED = 1.0
RUN_SPEED = 10.0
EPISODE_SECONDS = 25.0  # Playground's 1000 steps of 0.025 s.
# Uniform noise half-widths, Playground's Go1 joystick scales.
NOISE_SCALES = {
    'joint_positions': 0.03,
    'joint_velocities': 1.5,
    'torso_vertical': 0.05,
    'center_of_mass_velocity': 0.1,
    'root_velocity': 0.1,
}
# The keyword arguments that make the task Playground's HumanoidWalk.
PLAYGROUND_EQUIVALENT = dict(
    noise_level=0.0,
    observation_delay=0,
    history=1,
    randomize=False,
    push_interval=0,
    terminate_on_fall=False,
)
# The policy's inputs, in Playground's order; those with a history.
_POLICY = (
    'joint_positions',
    'head_height',
    'extremities',
    'torso_vertical',
    'center_of_mass_velocity',
    'root_velocity',
    'joint_velocities',
)
_WITH_HISTORY = ('joint_positions', 'joint_velocities')
_PRIVILEGED = ('gyro', 'torso_velocity', 'accelerometer')


def _check_arguments(**kwargs):
  """`Walk`'s arguments, checked before anything is built."""
  v, owner = validation, 'Walk'
  v.check_nonnegative(
      'move_speed',
      kwargs['move_speed'],
      owner=owner,
      fix='Pass a speed in m/s, >= 0 (0: stand still).',
  )
  for name in ('control_timestep', 'physics_timestep', 'fall_height'):
    v.check_positive(name, kwargs[name], owner=owner)
  v.check_nonnegative(
      'noise_level', kwargs['noise_level'], owner=owner, fix='0: no noise.'
  )
  v.check_nonnegative(
      'initial_pose_noise', kwargs['initial_pose_noise'], owner=owner
  )
  v.check_integer(
      'observation_delay', kwargs['observation_delay'], owner=owner, minimum=0
  )
  v.check_integer('history', kwargs['history'], owner=owner, minimum=1)
  if kwargs['push_interval'] is not None:
    v.check_integer(
        'push_interval',
        kwargs['push_interval'],
        owner=owner,
        minimum=0,
        fix='Pass an int >= 0 (0 or None: no pushes).',
    )
  v.check_range_pair(
      'push_magnitude', kwargs['push_magnitude'], owner=owner, nonnegative=True
  )
  v.check_bool('randomize', kwargs['randomize'], owner=owner)
  v.check_bool('terminate_on_fall', kwargs['terminate_on_fall'], owner=owner)


class Walk(task.Task):
  """Walk at `move_speed` (module docstring).

  Args:
    move_speed: target horizontal speed, m/s (0: stand still).
    control_timestep, physics_timestep: seconds per agent / physics step.
    noise_level: multiplies `NOISE_SCALES` (0: no noise).
    observation_delay: physics sub-steps before a policy sample is visible.
    history: control steps of joint positions and velocities the policy
      sees.
    randomize: per-episode domain randomization and initial pose.
    push_interval: control steps between pushes (0: none).
    push_magnitude: (low, high) velocity change of a push, m/s.
    terminate_on_fall: end the episode when the head is below
      `fall_height`.
    fall_height: metres.
    initial_pose_noise: half-width of the joint angles' initial spread, rad.
    collisions: the `Humanoid`'s contacts: 'all' (the XML's) or 'feet'.
  """

  def __init__(
      self,
      move_speed=WALK_SPEED,
      control_timestep=0.025,
      physics_timestep=0.005,
      noise_level=1.0,
      observation_delay=1,
      history=2,
      randomize=True,
      push_interval=200,
      push_magnitude=(0.1, 0.5),
      terminate_on_fall=True,
      fall_height=0.8,
      initial_pose_noise=0.1,
      collisions='all',
  ):
    validation.check_choice(
        'collisions', collisions, humanoid_lib.COLLISIONS, owner='Walk'
    )
    _check_arguments(
        move_speed=move_speed,
        control_timestep=control_timestep,
        physics_timestep=physics_timestep,
        noise_level=noise_level,
        observation_delay=observation_delay,
        history=history,
        randomize=randomize,
        push_interval=push_interval,
        push_magnitude=push_magnitude,
        terminate_on_fall=terminate_on_fall,
        fall_height=fall_height,
        initial_pose_noise=initial_pose_noise,
    )
    self._move_speed = float(move_speed)
    self._arena = self._build_arena()
    self._humanoid = humanoid_lib.Humanoid(collisions=collisions)
    frame = self._arena.add_free_entity(self._humanoid)
    frame.pos = [0.0, 0.0, self._humanoid.initial_height]
    self._humanoid.apply_simulation_options(self._arena.mjcf_model)
    self.set_timesteps(control_timestep, physics_timestep)
    self._randomize = bool(randomize)
    self._pose_noise = float(initial_pose_noise) if randomize else 0.0
    self._pushes = pushes_lib.Pushes(push_interval, push_magnitude)
    self._terminate_on_fall = bool(terminate_on_fall)
    self._fall_height = float(fall_height)
    self._variator = mjcf_variator.MJCFVariator()
    if randomize:
      self._bind_randomization()
    self._noise_level = float(noise_level)
    self._observation_delay = int(observation_delay)
    self._configure_observables(noise_level, observation_delay, history)

  # -- set-up ----------------------------------------------------------------

  def _build_arena(self):
    """The arena (a subclass may build its own; its first ground geom's
    friction is randomized)."""
    return arenas.Floor(size=(20.0, 20.0))

  def _start(self, physics, key):
    """Where this episode starts: `(physics, torso position (3,))`."""
    del key
    position = jnp.array([0.0, 0.0, self._humanoid.initial_height])
    return physics, position.astype(jnp.float32)

  def head_height(self, physics):
    """The head's height above the ground, metres: its z on the floor."""
    return self._humanoid.head_height(physics)

  def _bind_randomization(self):
    scale = lambda low, high: noises.Multiplicative(
        distributions.Uniform(low, high)
    )
    bind = self._variator.bind_attributes
    bind(self._arena.ground_geoms[0], friction=scale(0.7, 1.3))
    for geom in self._humanoid.mjcf_model.geoms:
      bind(geom, density=scale(0.9, 1.1))
    for actuator in self._humanoid.actuators:
      bind(actuator, gear=scale(0.9, 1.1))

  def _configure_observables(self, noise_level, delay, history):
    self._twins = policy_critic.split_policy_and_critic(
        self._humanoid.observables,
        _POLICY,
        _PRIVILEGED,
        self.physics_steps_per_control_step,
        NOISE_SCALES,
        noise_level,
        delay,
        history,
        _WITH_HISTORY,
    )
    self._last_push = observable.Generic(
        lambda physics: physics.task_state['push']
    )
    self._last_push.enabled = True

  # -- composition -----------------------------------------------------------

  @property
  def root_entity(self):
    return self._arena

  @property
  def humanoid(self):
    return self._humanoid

  @property
  def variator(self):
    return self._variator

  @property
  def noise_level(self):
    """The factor of the policy's observation noise."""
    return self._noise_level

  @property
  def observation_delay(self):
    """Physics sub-steps before a policy sample is visible."""
    return self._observation_delay

  @property
  def pushes(self):
    return self._pushes

  @property
  def task_observables(self):
    return {**self._twins, 'last_push': self._last_push}

  def observation_groups(self):
    """'policy': noisy, late, with history; 'critic': clean and current."""
    policy = [f'humanoid/{name}' for name in _POLICY]
    critic = (
        list(self._twins)
        + [f'humanoid/{name}' for name in _PRIVILEGED]
        + ['last_push']
    )
    return {
        'policy': groups_lib.ObservationGroup(keys=policy, flatten=True),
        'critic': groups_lib.ObservationGroup(
            keys=critic, corrupted=False, flatten=True
        ),
    }

  # -- episode ---------------------------------------------------------------

  def initial_task_state(self):
    return {
        'step': jnp.zeros((), jnp.int32),
        'push': jnp.zeros(3, jnp.float32),
        'start_xy': jnp.zeros(2, jnp.float32),
    }

  def initialize_episode(self, physics, key):
    variation_key, yaw_key, pose_key = jax.random.split(key, 3)
    physics = self._variator.apply_variations(physics, variation_key)
    humanoid = self._humanoid
    # A key folded from the episode's: the draws above stay as they were.
    physics, position = self._start(physics, jax.random.fold_in(key, 11))
    yaw = 0.0
    if self._randomize:
      yaw = jax.random.uniform(yaw_key, (), minval=-np.pi, maxval=np.pi)
    physics = humanoid.set_pose(
        physics, position, transformations.yaw_quaternion(jnp.asarray(yaw))
    )
    if self._pose_noise:
      joints = physics.bind(list(humanoid.joints))
      qpos0 = joints.qpos0
      ranges = joints.range
      noise = jax.random.uniform(
          pose_key,
          qpos0.shape,
          minval=-self._pose_noise,
          maxval=self._pose_noise,
      )
      qpos = jnp.clip(qpos0 + noise, ranges[:, 0], ranges[:, 1])
      physics = physics.bind(list(humanoid.joints)).set(qpos=qpos)
    return physics.update_task_state(
        step=jnp.zeros((), jnp.int32),
        push=jnp.zeros(3, jnp.float32),
        start_xy=position[:2],
    )

  def before_step(self, physics, action, key):
    physics = physics.set_control(action)
    step = physics.task_state['step']
    physics, kick = self._pushes.apply(
        physics, self._humanoid.freejoint, step, key
    )
    return physics.update_task_state(step=step + 1, push=kick)

  # -- outcome ---------------------------------------------------------------

  def _com_velocity(self, physics):
    return physics.bind(self._humanoid.com_velocity).sensordata

  def reward_terms(self, physics):
    """Playground's reward factors: standing, upright, small_control, move."""
    humanoid = self._humanoid
    standing = rewards.tolerance(
        self.head_height(physics),
        bounds=(STAND_HEIGHT, float('inf')),
        margin=STAND_HEIGHT / 4,
    )
    upright = rewards.tolerance(
        humanoid.upright(physics),
        bounds=(0.9, float('inf')),
        sigmoid='linear',
        margin=1.9,
        value_at_margin=0,
    )
    small_control = rewards.tolerance(
        physics.data.ctrl, margin=1, value_at_margin=0, sigmoid='quadratic'
    ).mean()
    small_control = (4 + small_control) / 5
    horizontal = self._com_velocity(physics)[:2]
    if self._move_speed == 0.0:
      move = rewards.tolerance(horizontal, margin=2).mean()
    else:
      move = rewards.tolerance(
          jnp.linalg.norm(horizontal),
          bounds=(self._move_speed, float('inf')),
          margin=self._move_speed,
          value_at_margin=0,
          sigmoid='linear',
      )
      move = (5 * move + 1) / 6
    return {
        'standing': standing,
        'upright': upright,
        'small_control': small_control,
        'move': move,
    }

  def get_reward(self, physics):
    terms = self.reward_terms(physics)
    return (
        terms['standing']
        * terms['upright']
        * terms['small_control']
        * terms['move']
    )

  def fallen(self, physics):
    return self.head_height(physics) < self._fall_height

  def should_terminate_episode(self, physics):
    if not self._terminate_on_fall:
      return False
    return self.fallen(physics)

  def get_discount(self, physics):
    return jnp.where(self.should_terminate_episode(physics), 0.0, 1.0)

  def get_metrics(self, physics):
    torso_xy = physics.bind(self._humanoid.torso).xpos[:2]
    terms = self.reward_terms(physics)
    return {
        'distance': jnp.linalg.norm(torso_xy - physics.task_state['start_xy']),
        'speed': jnp.linalg.norm(self._com_velocity(physics)[:2]),
        'head_height': self.head_height(physics),
        **{f'reward/{k}': v for k, v in terms.items()},
    }
