"""Reach: move an arm's hand to a target sampled per episode, beside a ball.

The scene composes three bundled entities: a `Floor` arena, an `Arm` robot
built in code, and a free `Ball` prop dropped at a random spot each episode.
The target is per-world task state, sampled in `initialize_episode`.

Observations come in two groups: the policy sees joint positions and
velocities with sensor noise, a delayed and buffered hand position and the
target; the critic additionally sees the clean (privileged) ball pose.
"""

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer import task
from mjx_composer.entities import arenas
from mjx_composer.entities import props
from mjx_composer.entities import robots
from mjx_composer.observation import groups as groups_lib
from mjx_composer.observation import observable

_TARGET_LOW = np.array([-0.45, -0.45, 0.15], np.float32)
_TARGET_HIGH = np.array([0.45, 0.45, 0.6], np.float32)


def gaussian_noise(scale):
  """A corruptor adding N(0, scale²) noise to every sample."""
  def corrupt(value, key):
    return value + scale * jax.random.normal(key, jnp.shape(value),
                                             jnp.result_type(value))
  return corrupt


class Reach(task.Task):
  """Reach a random target with the arm's hand.

  Reward: `1 - tanh(distance / 0.3)`, in [0, 1]. No termination: episodes
  end at the environment's time limit (truncation).

  Args:
    control_timestep: seconds per agent step. physics_timestep: seconds per
      physics step (must divide the control timestep).
    observation_noise: standard deviation of the joint sensor noise.
  """

  def __init__(self, control_timestep=0.02, physics_timestep=0.004,
               observation_noise=0.01):
    self._arena = arenas.Floor(size=(1.5, 1.5))
    self._arm = robots.Arm()
    self._arena.attach(self._arm)
    self._ball = props.Ball()
    self._arena.add_free_entity(self._ball)
    self.set_timesteps(control_timestep, physics_timestep)

    arm_obs = self._arm.observables
    arm_obs.joint_positions.configure(
        enabled=True, corruptor=gaussian_noise(observation_noise))
    arm_obs.joint_velocities.configure(
        enabled=True, corruptor=gaussian_noise(10 * observation_noise))
    # A slower, delayed hand tracker: sampled every 2 sub-steps, 1 sub-step
    # late, the last 3 samples stacked.
    arm_obs.hand_position.configure(enabled=True, update_interval=2, delay=1,
                                    buffer_size=3)
    # Actuator forces averaged over the control step's sub-steps.
    arm_obs.actuator_forces.configure(
        enabled=True, buffer_size=self.physics_steps_per_control_step,
        aggregator='mean')
    self._ball.observables.position.configure(
        enabled=True, corruptor=gaussian_noise(observation_noise))
    for name in ('orientation', 'linear_velocity', 'angular_velocity'):
      self._ball.observables.get_observable(name).enabled = True
    self._target = observable.Generic(
        lambda physics: physics.task_state['target'])
    self._target.enabled = True
    self._distance = observable.Generic(self._hand_to_target)
    self._distance.enabled = True

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
    policy = ['arm/joint_positions', 'arm/joint_velocities',
              'arm/hand_position', 'target']
    critic = policy + ['arm/actuator_forces', 'ball/position',
                       'ball/orientation', 'ball/linear_velocity',
                       'ball/angular_velocity', 'hand_to_target']
    return {'policy': groups_lib.ObservationGroup(keys=policy, flatten=True),
            'critic': groups_lib.ObservationGroup(keys=critic, corrupted=False,
                                                  flatten=True)}

  def initial_task_state(self):
    return {'target': jnp.zeros(3, jnp.float32)}

  def initialize_episode(self, physics, key):
    target_key, ball_key = jax.random.split(key)
    target = jax.random.uniform(target_key, (3,), minval=_TARGET_LOW,
                                maxval=_TARGET_HIGH)
    angle, radius = jax.random.uniform(ball_key, (2,), minval=jnp.array(
        [-np.pi, 0.3]), maxval=jnp.array([np.pi, 0.8]))
    ball_xy = radius * jnp.array([jnp.cos(angle), jnp.sin(angle)])
    physics = self._ball.set_pose(
        physics, position=jnp.concatenate([ball_xy, jnp.array([0.05])]))
    return physics.update_task_state(target=target)

  def _hand_to_target(self, physics):
    return jnp.linalg.norm(physics.bind(self._arm.hand).xpos
                           - physics.task_state['target'])[None]

  def get_reward(self, physics):
    return 1. - jnp.tanh(self._hand_to_target(physics)[0] / 0.3)

  def get_metrics(self, physics):
    return {'distance': self._hand_to_target(physics)[0]}
