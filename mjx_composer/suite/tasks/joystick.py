"""Joystick: a Unitree Go1 tracks a commanded planar velocity and yaw rate.

MuJoCo Playground's `Go1JoystickFlatTerrain` / `Go1JoystickRoughTerrain`
(playground 0.2.0, `locomotion/go1/joystick.py`), composed from bundled
parts: a `Floor` or `RoughTerrain` arena and the `Go1` robot (Menagerie's
model; see `entities/go1.py` for its MJX contact settings). What is
Playground's:

* timesteps: control 0.02 s, physics 0.004 s; episodes of 1000 control
  steps (`Environment(task, time_limit=EPISODE_SECONDS)`), truncated;
* PD control: actions in [-1, 1] set position targets `home + 0.5 *
  action`; Kp = 35, Kd = 0.5 (as Playground sets them on Menagerie's model);
* commands (vx, vy, yaw rate) drawn from U(-a, a) with a = (1.5, 0.8, 1.2)
  at reset; a resample keeps the old command with probability 1/2, else
  draws a new one whose entries are zeroed with probabilities 1 - (0.9,
  0.25, 0.5);
* every reward term and scale of Playground's `default_config` (`SCALES`):
  velocity tracking (exp(-error^2 / 0.25)), vertical velocity, roll/pitch
  rates, tilt, soft joint limits (0.95 of the range), pose, termination,
  standing still, torques, action rate, energy, feet slip, clearance, swing
  height (0.1 m) and air time; the reward is their weighted sum times the
  control timestep, clipped to [0, 10000];
* termination when the trunk turns upside down; the policy's inputs
  (linear velocity, gyro, gravity, joint positions and velocities, last
  action, command) with Playground's uniform noise scales; the critic's
  privileged extras (clean IMU, accelerometer, world angular velocity,
  actuator forces, foot contacts, velocities and air time, the push).

Deviations, each deliberate:

* commands are resampled every `command_interval` control steps (250: 5 s),
  not after exponentially distributed times with a 5 s mean, so the
  schedule is a composer-style every-k-steps event;
* the policy sees absolute joint positions (Playground subtracts the home
  pose, a constant offset), delayed by `observation_delay` sub-steps and
  with a `history` of control steps; the critic's twins are clean and
  current (Playground's policy inputs have no latency and no history);
* pushes are velocity changes of U(0.1, 1.0) m/s every `push_interval`
  control steps (Playground's Go1 joystick ships its force kicks disabled;
  its humanoid joystick tasks kick velocities like this);
* falls also terminate when the trunk's box touches the ground (Playground's
  trunk does not collide at all; ours does with `collisions='minimal'`, the
  default, see `entities/go1.py`; with `collisions='feet'` the box's pose
  against the ground's height below it tells);
* per-episode randomization (Playground randomizes once per run with its
  own wrapper) with Playground's ranges: feet friction U(0.4, 1.0) (our feet
  have contact priority, so theirs, not the floor's, is the contact's),
  joint friction loss x U(0.9, 1.1), armature x U(1.0, 1.05), trunk centre
  of mass +U(-0.05, 0.05) m, link masses x U(0.9, 1.1), trunk mass +U(-1, 1)
  kg; and, beyond Playground, Kp and Kd x U(0.9, 1.1) (motor strength);
* initial pose as Playground's reset (position +U(-0.5, 0.5) m, random
  heading, base velocities U(-0.5, 0.5)) plus joint angles within 0.1 rad
  of the home pose; on rough terrain the robot starts above the highest
  terrain point near it, and the feet's swing height and clearance are
  measured above the ground below each foot.
"""

import jax
import jax.numpy as jnp
from dm_env import specs
import numpy as np

from mjx_composer import task
from mjx_composer.observation import groups as groups_lib
from mjx_composer.observation import observable
from mjx_composer.suite.entities import arenas
from mjx_composer.suite.entities import go1 as go1_lib
from mjx_composer.suite.locomotion import commands as commands_lib
from mjx_composer.suite.locomotion import policy_critic
from mjx_composer.suite.locomotion import pushes as pushes_lib
from mjx_composer.suite.locomotion import terrain as terrain_lib
from mjx_composer.utils import transformations
from mjx_composer.utils import validation
from mjx_composer.variation import distributions
from mjx_composer.variation import mjcf_variator
from mjx_composer.variation import noises

EPISODE_SECONDS = 20.0  # Playground's 1000 steps of 0.02 s.
TERRAINS = ('flat', 'rough')
# Playground's reward scales (joystick.default_config().reward_config).
SCALES = {
    'tracking_lin_vel': 1.0,
    'tracking_ang_vel': 0.5,
    'lin_vel_z': -0.5,
    'ang_vel_xy': -0.05,
    'orientation': -5.0,
    'dof_pos_limits': -1.0,
    'pose': 0.5,
    'termination': -1.0,
    'stand_still': -1.0,
    'torques': -0.0002,
    'action_rate': -0.01,
    'energy': -0.001,
    'feet_clearance': -2.0,
    'feet_height': -0.2,
    'feet_slip': -0.1,
    'feet_air_time': 0.1,
}
TRACKING_SIGMA = 0.25
MAX_FOOT_HEIGHT = 0.1
COMMAND_AMPLITUDE = (1.5, 0.8, 1.2)
COMMAND_KEEP = (0.9, 0.25, 0.5)
# Uniform noise half-widths (Playground's noise_config.scales).
NOISE_SCALES = {
    'local_linvel': 0.1,
    'gyro': 0.2,
    'gravity': 0.05,
    'joint_positions': 0.03,
    'joint_velocities': 1.5,
}
_POSE_WEIGHTS = np.array([1.0, 1.0, 0.1] * 4, np.float32)
_POLICY = tuple(NOISE_SCALES)
_WITH_HISTORY = ('joint_positions', 'joint_velocities')
_PRIVILEGED = (
    'accelerometer',
    'global_angvel',
    'actuator_forces',
    'foot_contacts',
    'foot_velocities',
)


class Joystick(task.Task):
  """Follow a velocity command with the Go1 (module docstring).

  Args:
    terrain: 'flat' (a plane) or 'rough' (a `RoughTerrain` per world).
    control_timestep, physics_timestep: seconds per agent / physics step.
    kp, kd: the PD gains (position actuators' gain, joint damping).
    action_scale: radians of target offset per unit of action.
    command_interval: control steps between command resamples (0: never).
    noise_level: multiplies `NOISE_SCALES` (0: no noise).
    observation_delay: physics sub-steps before a policy sample is visible.
    history: control steps of joint readings the policy sees.
    randomize: per-episode domain randomization and initial pose spread.
    push_interval: control steps between pushes (0: none).
    push_magnitude: (low, high) velocity change of a push, m/s.
    terminate_on_fall: end the episode (discount 0) on a fall.
    collisions: the `Go1`'s contacts: 'minimal' (feet and trunk against
      the ground), 'feet' (feet only) or 'full'.
  """

  def __init__(
      self,
      terrain='flat',
      control_timestep=0.02,
      physics_timestep=0.004,
      kp=35.0,
      kd=0.5,
      action_scale=0.5,
      command_interval=250,
      noise_level=1.0,
      observation_delay=1,
      history=3,
      randomize=True,
      push_interval=250,
      push_magnitude=(0.1, 1.0),
      terminate_on_fall=True,
      collisions='minimal',
  ):
    v, owner = validation, 'Joystick'  # Checked before anything is built.
    v.check_choice('terrain', terrain, TERRAINS, owner=owner)
    for name, value in (
        ('control_timestep', control_timestep),
        ('physics_timestep', physics_timestep),
        ('kp', kp),
        ('action_scale', action_scale),
    ):
      v.check_positive(name, value, owner=owner)
    v.check_nonnegative('kd', kd, owner=owner)
    v.check_nonnegative('noise_level', noise_level, owner=owner, fix='0: none.')
    v.check_integer(
        'observation_delay', observation_delay, owner=owner, minimum=0
    )
    v.check_integer('history', history, owner=owner, minimum=1)
    for name, value in (
        ('command_interval', command_interval),
        ('push_interval', push_interval),
    ):
      if value is not None:
        v.check_integer(
            name,
            value,
            owner=owner,
            minimum=0,
            fix='Pass an int >= 0 (0 or None: never).',
        )
    v.check_range_pair(
        'push_magnitude', push_magnitude, owner=owner, nonnegative=True
    )
    v.check_bool('randomize', randomize, owner=owner)
    v.check_bool('terminate_on_fall', terminate_on_fall, owner=owner)
    v.check_choice('collisions', collisions, go1_lib.COLLISIONS, owner=owner)
    self._terrain = terrain
    self._arena = self._build_arena(terrain)
    self._go1 = go1_lib.Go1(kp=kp, kd=kd, collisions=collisions)
    frame = self._arena.add_free_entity(self._go1)
    frame.pos = [0.0, 0.0, self._go1.home_height]
    self._go1.apply_simulation_options(self._arena.mjcf_model)
    self.set_timesteps(control_timestep, physics_timestep)
    self._home = jnp.asarray(self._go1.home_joint_positions)
    self._action_scale = float(action_scale)
    self._command_interval = int(command_interval or 0)
    # Playground's command: U(-a, a), then its keep-or-zero resampling.
    amplitude = np.asarray(COMMAND_AMPLITUDE, np.float64)
    self._command = commands_lib.VelocityCommand(
        *[(-a, a) for a in amplitude],
        resample_interval=self._command_interval,
        keep_probability=0.5,
        zero_probability=tuple(1.0 - np.asarray(COMMAND_KEEP, np.float64)),
    )
    self._randomize = bool(randomize)
    self._pushes = pushes_lib.Pushes(push_interval, push_magnitude)
    self._terminate_on_fall = bool(terminate_on_fall)
    self._variator = mjcf_variator.MJCFVariator()
    if randomize:
      self._bind_randomization()
    self._noise_level = float(noise_level)
    self._observation_delay = int(observation_delay)
    self._configure_observables(noise_level, observation_delay, history)

  # -- set-up ----------------------------------------------------------------

  def _build_arena(self, terrain):
    """The arena for `terrain` (a subclass may build its own)."""
    if terrain == 'flat':
      return arenas.Floor(size=(10.0, 10.0))
    # The task samples the terrain itself, before placing the robot.
    return terrain_lib.RoughTerrain(auto_regenerate=False)

  def _ground(self, physics, key, xy):
    """Samples this world's ground: `(physics, origin (2,), height)`.

    The robot starts at `origin + xy`, `height` below its home height.
    """
    origin = jnp.zeros(2, jnp.float32)
    if self._terrain != 'rough':
      return physics, origin, 0.0
    physics = self._arena.regenerate_world(physics, key)
    return physics, origin, self._arena.max_height_near(physics, xy, 0.4) + 0.01

  def _bind_randomization(self):
    uniform = distributions.Uniform
    scale = lambda low, high: noises.Multiplicative(uniform(low, high))
    shift = lambda low, high: noises.Additive(uniform(low, high))
    bind = self._variator.bind_attributes
    go1 = self._go1
    for foot in go1.foot_geoms:
      # Menagerie's 0.8 x U(0.5, 1.25): Playground's U(0.4, 1.0).
      bind(foot, friction=scale(0.5, 1.25))
    for joint in go1.joints:
      bind(
          joint,
          frictionloss=scale(0.9, 1.1),
          armature=scale(1.0, 1.05),
          damping=scale(0.9, 1.1),
      )
    bind(go1.trunk, ipos=shift(-0.05, 0.05), mass=shift(-1.0, 1.0))
    for body in go1.mjcf_model.bodies:
      if body.name not in ('world', 'trunk'):
        bind(body, mass=scale(0.9, 1.1))
    for actuator in go1.actuators:
      bind(actuator, kp=scale(0.9, 1.1))

  def _configure_observables(self, noise_level, delay, history):
    self._twins = policy_critic.split_policy_and_critic(
        self._go1.observables,
        _POLICY,
        _PRIVILEGED,
        self.physics_steps_per_control_step,
        NOISE_SCALES,
        noise_level,
        delay,
        history,
        _WITH_HISTORY,
    )
    state = lambda entry: observable.Generic(
        lambda physics: physics.task_state[entry]
    )
    self._task_obs = {
        'last_action': state('action'),
        'command': self._command.observable(),
        'feet_air_time': state('air_time'),
        'last_push': state('push'),
    }
    for obs in self._task_obs.values():
      obs.enabled = True

  # -- composition -----------------------------------------------------------

  @property
  def root_entity(self):
    return self._arena

  @property
  def arena(self):
    return self._arena

  @property
  def go1(self):
    return self._go1

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
  def command_interval(self):
    return self._command_interval

  @property
  def command(self):
    """The `VelocityCommand` (its entries are in the task state)."""
    return self._command

  @property
  def task_observables(self):
    return {**self._twins, **self._task_obs}

  def observation_groups(self):
    """Playground's 'state' ('policy') and 'privileged_state' ('critic')."""
    policy = [f'go1/{name}' for name in _POLICY] + ['last_action', 'command']
    critic = (
        list(self._twins)
        + ['last_action', 'command']
        + [f'go1/{name}' for name in _PRIVILEGED]
        + ['feet_air_time', 'last_push']
    )
    return {
        'policy': groups_lib.ObservationGroup(keys=policy, flatten=True),
        'critic': groups_lib.ObservationGroup(
            keys=critic, corrupted=False, flatten=True
        ),
    }

  def action_spec(self, physics):
    """Actions in [-1, 1]: offsets of the joints' targets from home."""
    del physics
    n = len(self._go1.actuators)
    return specs.BoundedArray(
        shape=(n,),
        dtype=np.float32,
        minimum=-np.ones(n, np.float32),
        maximum=np.ones(n, np.float32),
        name='\t'.join(a.name for a in self._go1.actuators),
    )

  # -- episode ---------------------------------------------------------------

  def initial_task_state(self):
    zeros = lambda *shape: jnp.zeros(shape, jnp.float32)
    return {
        **self._command.initial_state(),
        'step': jnp.zeros((), jnp.int32),
        'action': zeros(12),
        'previous_action': zeros(12),
        'air_time': zeros(4),
        'contact': jnp.zeros(4, bool),
        'first_contact': jnp.zeros(4, bool),
        'swing_peak': zeros(4),
        'push': zeros(3),
        'start_xy': zeros(2),
    }

  def initialize_episode(self, physics, key):
    keys = jax.random.split(key, 6)
    physics = self._variator.apply_variations(physics, keys[0])
    go1 = self._go1
    xy = jnp.zeros(2, jnp.float32)
    yaw = jnp.zeros((), jnp.float32)
    velocity = jnp.zeros(6, jnp.float32)
    joints = self._home
    if self._randomize:
      xy = jax.random.uniform(keys[2], (2,), minval=-0.5, maxval=0.5)
      yaw = jax.random.uniform(keys[3], (), minval=-np.pi, maxval=np.pi)
      velocity = jax.random.uniform(keys[4], (6,), minval=-0.5, maxval=0.5)
      joints = joints + jax.random.uniform(
          keys[5], (12,), minval=-0.1, maxval=0.1
      )
    physics, origin, ground = self._ground(physics, keys[1], xy)
    xy = origin + xy
    position = jnp.concatenate([xy, jnp.reshape(ground + go1.home_height, 1)])
    physics = go1.set_pose(
        physics, position, transformations.yaw_quaternion(yaw)
    )
    physics = go1.set_velocity(physics, velocity[:3], velocity[3:])
    physics = physics.bind(list(go1.joints)).set(qpos=joints)
    # The actuators hold the initial pose until the first action.
    physics = physics.set_control(joints)
    state = self.initial_task_state()
    state.update(start_xy=xy)
    physics = physics.update_task_state(**state)
    return self._command.reset(physics, jax.random.fold_in(key, 7))

  def before_step(self, physics, action, key):
    command_key, push_key = jax.random.split(key)
    state = physics.task_state
    step = state['step']
    physics = self._command.step(physics, command_key)
    physics = physics.set_control(self._home + self._action_scale * action)
    physics, kick = self._pushes.apply(
        physics, self._go1.freejoint, step, push_key
    )
    return physics.update_task_state(
        step=step + 1,
        previous_action=state['action'],
        action=jnp.asarray(action, jnp.float32),
        push=kick,
    )

  def after_step(self, physics, key):
    """Feet bookkeeping for the rewards (Playground's, in task state)."""
    del key
    state = physics.task_state
    contact = self._go1.foot_contacts(physics)
    previous = state['contact']
    # What Playground resets at the end of its step, we reset here.
    air_time = state['air_time'] * ~previous
    first_contact = jnp.logical_and(
        air_time > 0, jnp.logical_or(contact, previous)
    )
    air_time = air_time + self.control_timestep
    swing_peak = jnp.maximum(
        state['swing_peak'] * ~previous, self.foot_clearances(physics)
    )
    return physics.update_task_state(
        contact=contact,
        first_contact=first_contact,
        air_time=air_time,
        swing_peak=swing_peak,
    )

  # -- outcome ---------------------------------------------------------------

  def ground_height(self, physics, xy):
    """The ground's height below world `xy` (2,)."""
    if self._terrain == 'flat':
      return jnp.zeros((), jnp.float32)
    return self._arena.height_at(physics, xy)

  def foot_clearances(self, physics):
    """The feet's heights above the ground below each (4,), `FEET` order:
    what the swing-height and clearance rewards measure (on flat ground,
    the feet's z)."""
    sites = physics.bind(list(self._go1.foot_sites)).xpos
    if self._terrain == 'flat':
      return sites[:, 2]
    ground = jax.vmap(lambda xy: self.ground_height(physics, xy))(sites[:, :2])
    return sites[:, 2] - ground

  def fallen(self, physics):
    """Upside down, or the trunk's box on the ground (a contact where it
    collides, its pose against the ground below it where it does not)."""
    go1 = self._go1
    upside_down = go1.upvector(physics)[2] < 0.0
    if go1.collisions == 'feet':
      xy = physics.bind(go1.trunk).xpos[:2]
      down = go1.trunk_below(physics, self.ground_height(physics, xy))
    else:
      down = go1.trunk_contact(physics)
    return jnp.logical_or(upside_down, down)

  def fell(self, physics):
    """A fall that ends the episode (`fallen`, with `terminate_on_fall`)."""
    if not self._terminate_on_fall:
      return False
    return self.fallen(physics)

  def should_terminate_episode(self, physics):
    return self.fell(physics)

  def get_discount(self, physics):
    return jnp.where(self.fell(physics), 0.0, 1.0)

  def reward_terms(self, physics):
    """Playground's unscaled reward terms (see `SCALES`)."""
    go1, state = self._go1, physics.task_state
    command = state['command']
    moving = (jnp.linalg.norm(command) > 0.01).astype(jnp.float32)
    qpos = physics.bind(list(go1.joints)).qpos
    qvel = physics.bind(list(go1.joints)).qvel
    torques = physics.bind(list(go1.actuators)).force
    local_linvel = go1.local_linvel(physics)
    global_angvel = go1.global_angvel(physics)
    ranges = physics.bind(list(go1.joints)).range
    soft_low, soft_high = 0.95 * ranges[:, 0], 0.95 * ranges[:, 1]
    feet_xy = go1.foot_velocities(physics)[:, :2]
    contact = state['contact'].astype(jnp.float32)
    first_contact = state['first_contact'].astype(jnp.float32)
    foot_z = self.foot_clearances(physics)
    return {
        'tracking_lin_vel': jnp.exp(
            -jnp.sum((command[:2] - local_linvel[:2]) ** 2) / TRACKING_SIGMA
        ),
        'tracking_ang_vel': jnp.exp(
            -((command[2] - go1.gyro(physics)[2]) ** 2) / TRACKING_SIGMA
        ),
        'lin_vel_z': go1.global_linvel(physics)[2] ** 2,
        'ang_vel_xy': jnp.sum(global_angvel[:2] ** 2),
        'orientation': jnp.sum(go1.upvector(physics)[:2] ** 2),
        'dof_pos_limits': jnp.sum(
            jnp.clip(soft_low - qpos, 0.0, None)
            + jnp.clip(qpos - soft_high, 0.0, None)
        ),
        'pose': jnp.exp(-jnp.sum((qpos - self._home) ** 2 * _POSE_WEIGHTS)),
        'termination': jnp.asarray(self.fell(physics), jnp.float32),
        'stand_still': jnp.sum(jnp.abs(qpos - self._home)) * (1.0 - moving),
        'torques': jnp.sqrt(jnp.sum(torques**2)) + jnp.sum(jnp.abs(torques)),
        'action_rate': jnp.sum(
            (state['action'] - state['previous_action']) ** 2
        ),
        'energy': jnp.sum(jnp.abs(qvel) * jnp.abs(torques)),
        'feet_slip': jnp.sum(jnp.sum(feet_xy**2, axis=-1) * contact) * moving,
        'feet_clearance': jnp.sum(
            jnp.abs(foot_z - MAX_FOOT_HEIGHT)
            * jnp.sqrt(jnp.linalg.norm(feet_xy, axis=-1))
        ),
        'feet_height': jnp.sum(
            (state['swing_peak'] / MAX_FOOT_HEIGHT - 1.0) ** 2 * first_contact
        )
        * moving,
        'feet_air_time': jnp.sum((state['air_time'] - 0.1) * first_contact)
        * moving,
    }

  def get_reward(self, physics):
    terms = self.reward_terms(physics)
    total = sum(SCALES[name] * value for name, value in terms.items())
    return jnp.clip(total * self.control_timestep, 0.0, 10000.0)

  def get_metrics(self, physics):
    trunk_xy = physics.bind(self._go1.trunk).xpos[:2]
    command = physics.task_state['command']
    linvel = self._go1.local_linvel(physics)
    return {
        'distance': jnp.linalg.norm(trunk_xy - physics.task_state['start_xy']),
        'velocity_error': jnp.linalg.norm(command[:2] - linvel[:2]),
        'yaw_rate_error': jnp.abs(command[2] - self._go1.gyro(physics)[2]),
    }
