"""Reach: move an arm's hand to a target sampled per episode, beside a ball.

The scene composes three bundled entities: a `Floor` arena, an `Arm` robot
built in code, and a free `Ball` prop dropped at a random spot each episode.
The target is per-world task state, sampled in `initialize_episode`.

Domain randomization (`randomize=True`, the default) resamples per episode
and per world, through one `MJCFVariator` whose derived quantities (inertia,
`invweight0`, `actuator_acc0`, ...) match a recompiled model: the colours of
every arm link and the ball, the arm links' densities (so their masses), the
ball's radius and mass, the ball's and floor's friction, and the arm's motor
gears.

Observations come in two groups: the policy sees joint positions and
velocities with sensor noise, a delayed and buffered hand position and the
target; the critic additionally sees the clean (privileged) ball pose.
"""

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer import task
from mjx_composer.observation import groups as groups_lib
from mjx_composer.observation import observable
from mjx_composer.suite.entities import arenas
from mjx_composer.suite.entities import props
from mjx_composer.suite.entities import robots
from mjx_composer.suite.entities import simulation_options as options_lib
from mjx_composer.suite.tasks import arm_parts
from mjx_composer.utils import validation
from mjx_composer.variation import colors
from mjx_composer.variation import distributions
from mjx_composer.variation import mjcf_variator
from mjx_composer.variation import noises

_TARGET_LOW = np.array([-0.45, -0.45, 0.15], np.float32)
_TARGET_HIGH = np.array([0.45, 0.45, 0.6], np.float32)


class Reach(task.Task):
  """Reach a random target with the arm's hand.

  Reward: `1 - tanh(distance / 0.3)`, in [0, 1]. No termination: episodes
  end at the environment's time limit (truncation).

  Args:
    control_timestep: seconds per agent step. physics_timestep: seconds per
      physics step (must divide the control timestep).
    observation_noise: standard deviation of the joint sensor noise.
    randomize: resample colours, masses, sizes, friction and actuator gains
      every episode (see the module docstring).
    solver_iterations, solver_ls_iterations: MuJoCo's solver caps written
      on the root (`simulation_options.SOLVER_CAPS` by default: 4 and 8;
      None keeps MuJoCo's 100 and 50, on which MJX's float32 solver runs
      far longer for nearly the same trajectory).
  """

  def __init__(
      self,
      control_timestep=0.02,
      physics_timestep=0.004,
      observation_noise=0.01,
      randomize=True,
      solver_iterations=options_lib.SOLVER_CAPS['iterations'],
      solver_ls_iterations=options_lib.SOLVER_CAPS['ls_iterations'],
  ):
    arm_parts.check_arm_task_arguments(
        'Reach',
        control_timestep,
        physics_timestep,
        observation_noise,
        solver_iterations,
        solver_ls_iterations,
    )
    validation.check_bool('randomize', randomize, owner='Reach')
    self._arena = arenas.Floor(size=(1.5, 1.5))
    self._arm = robots.Arm()
    self._arena.attach(self._arm)
    self._ball = props.Ball()
    self._arena.add_free_entity(self._ball)
    self.set_timesteps(control_timestep, physics_timestep)
    arm_parts.cap_solver(self._arena, solver_iterations, solver_ls_iterations)

    arm_obs = self._arm.observables
    arm_obs.joint_positions.configure(
        enabled=True, corruptor=arm_parts.gaussian_noise(observation_noise)
    )
    arm_obs.joint_velocities.configure(
        enabled=True, corruptor=arm_parts.gaussian_noise(10 * observation_noise)
    )
    # A slower, delayed hand tracker: sampled every 2 sub-steps, 1 sub-step
    # late, the last 3 samples stacked.
    arm_obs.hand_position.configure(
        enabled=True, update_interval=2, delay=1, buffer_size=3
    )
    # Actuator forces averaged over the control step's sub-steps.
    arm_obs.actuator_forces.configure(
        enabled=True,
        buffer_size=self.physics_steps_per_control_step,
        aggregator='mean',
    )
    self._ball.observables.position.configure(
        enabled=True, corruptor=arm_parts.gaussian_noise(observation_noise)
    )
    for name in ('orientation', 'linear_velocity', 'angular_velocity'):
      self._ball.observables.get_observable(name).enabled = True
    self._target = observable.Generic(
        lambda physics: physics.task_state['target']
    )
    self._target.enabled = True
    self._distance = observable.Generic(self._hand_to_target)
    self._distance.enabled = True
    self._variator = mjcf_variator.MJCFVariator()
    if randomize:
      self._bind_randomization()

  def _bind_randomization(self):
    scale = lambda low, high: noises.Multiplicative(
        distributions.Uniform(low, high)
    )
    bind = self._variator.bind_attributes
    for geom in self._arm.mjcf_model.geoms:
      bind(
          geom,
          rgba=colors.HsvVariation(
              h=distributions.Uniform(0.0, 1.0),
              s=distributions.Uniform(0.3, 0.8),
              v=distributions.Uniform(0.5, 1.0),
          ),
      )
      if geom.name != 'base':  # the fixed pedestal's mass is irrelevant
        bind(geom, density=scale(0.7, 1.3))
    for actuator in self._arm.actuators:
      bind(actuator, gear=scale(0.8, 1.2))
    bind(
        self._ball.geom,
        size=scale(0.7, 1.3),
        mass=scale(0.5, 2.0),
        friction=scale(0.5, 1.5),
        rgba=colors.RgbVariation(
            r=distributions.Uniform(0.0, 1.0),
            g=distributions.Uniform(0.0, 1.0),
            b=distributions.Uniform(0.0, 1.0),
        ),
    )
    bind(self._arena.ground_geoms[0], friction=scale(0.7, 1.3))

  @property
  def root_entity(self):
    return self._arena

  @property
  def arm(self):
    return self._arm

  @property
  def ball(self):
    return self._ball

  @property
  def task_observables(self):
    return {'target': self._target, 'hand_to_target': self._distance}

  @staticmethod
  def observation_groups():
    """The policy/critic split used by the demo and training scripts."""
    policy = [
        'arm/joint_positions',
        'arm/joint_velocities',
        'arm/hand_position',
        'target',
    ]
    critic = policy + [
        'arm/actuator_forces',
        'ball/position',
        'ball/orientation',
        'ball/linear_velocity',
        'ball/angular_velocity',
        'hand_to_target',
    ]
    return {
        'policy': groups_lib.ObservationGroup(keys=policy, flatten=True),
        'critic': groups_lib.ObservationGroup(
            keys=critic, corrupted=False, flatten=True
        ),
    }

  def initial_task_state(self):
    return {'target': jnp.zeros(3, jnp.float32)}

  def initialize_episode(self, physics, key):
    variation_key, target_key, ball_key = jax.random.split(key, 3)
    physics = self._variator.apply_variations(physics, variation_key)
    target = jax.random.uniform(
        target_key, (3,), minval=_TARGET_LOW, maxval=_TARGET_HIGH
    )
    angle, radius = jax.random.uniform(
        ball_key,
        (2,),
        minval=jnp.array([-np.pi, 0.3]),
        maxval=jnp.array([np.pi, 0.8]),
    )
    ball_xy = radius * jnp.array([jnp.cos(angle), jnp.sin(angle)])
    radius = physics.bind(self._ball.geom).size[0]  # varied per world
    physics = self._ball.set_pose(
        physics, position=jnp.concatenate([ball_xy, radius[None]])
    )
    return physics.update_task_state(target=target)

  def _hand_to_target(self, physics):
    return jnp.linalg.norm(
        physics.bind(self._arm.hand).xpos - physics.task_state['target']
    )[None]

  def get_reward(self, physics):
    return 1.0 - jnp.tanh(self._hand_to_target(physics)[0] / 0.3)

  def get_metrics(self, physics):
    return {'distance': self._hand_to_target(physics)[0]}
