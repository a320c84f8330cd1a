# Copyright 2019 The dm_control Authors.
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#    http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or  implied.
# See the License for the specific language governing permissions and
# limitations under the License.
# ============================================================================

"""Corridor-based locomotion tasks."""

import jax
import jax.numpy as jnp
import mjx_composer as composer
from mjx_composer import variation
from mjx_composer.observation import contacts
from mjx_composer.utils import rewards


class RunThroughCorridor(composer.Task):
  """A task that requires a walker to run through a corridor.

  This task rewards an agent for controlling a walker to move at a specific
  target velocity along the corridor, and for minimising the magnitude of the
  control signals used to achieve this.
  """

  def __init__(
      self,
      walker,
      arena,
      walker_spawn_position=(0, 0, 0),
      walker_spawn_rotation=None,
      target_velocity=3.0,
      contact_termination=True,
      terminate_at_height=-0.5,
      physics_timestep=0.005,
      control_timestep=0.025,
  ):
    """Initializes this task.

    Args:
      walker: an instance of `locomotion.walkers.base.Walker`.
      arena: an instance of `locomotion.arenas.corridors.Corridor`.
      walker_spawn_position: a sequence of 3 numbers, or a `composer.Variation`
        instance that generates such sequences, specifying the position at
        which the walker is spawned at the beginning of an episode.
      walker_spawn_rotation: a number, or a `composer.Variation` instance that
        generates a number, specifying the yaw angle offset (in radians) that is
        applied to the walker at the beginning of an episode.
      target_velocity: a number specifying the target velocity (in meters per
        second) for the walker.
      contact_termination: whether to terminate if a non-foot geom touches the
        ground.
      terminate_at_height: a number specifying the height of end effectors below
        which the episode terminates.
      physics_timestep: a number specifying the timestep (in seconds) of the
        physics simulation.
      control_timestep: a number specifying the timestep (in seconds) at which
        the agent applies its control inputs (in seconds).
    """

    self._arena = arena
    self._walker = walker
    self._walker.create_root_joints(self._arena.attach(self._walker))
    self._walker_spawn_position = walker_spawn_position
    self._walker_spawn_rotation = walker_spawn_rotation

    enabled_observables = []
    enabled_observables += self._walker.observables.proprioception
    enabled_observables += self._walker.observables.kinematic_sensors
    enabled_observables += self._walker.observables.dynamic_sensors
    enabled_observables.append(self._walker.observables.sensors_touch)
    enabled_observables.append(self._walker.observables.egocentric_camera)
    for observable in enabled_observables:
      observable.enabled = True

    self._vel = target_velocity
    self._contact_termination = contact_termination
    self._terminate_at_height = terminate_at_height

    self.set_timesteps(
        physics_timestep=physics_timestep, control_timestep=control_timestep
    )

  @property
  def root_entity(self):
    return self._arena

  def initialize_episode_mjcf(self, random_state):
    self._arena.regenerate(random_state)
    self._arena.mjcf_model.visual.map.znear = 0.00025
    self._arena.mjcf_model.visual.map.zfar = 4.0

  def initial_task_state(self):
    return {'failure_termination': jnp.array(False)}

  def after_compile(self, physics, random_state):
    # The walker's non-foot geoms: the same in every world, found once.
    walker_foot_geoms = set(self._walker.ground_contact_geoms)
    self._walker_nonfoot_geoms = [
        geom
        for geom in self._walker.mjcf_model.find_all('geom')
        if geom not in walker_foot_geoms
    ]

  def initialize_episode(self, physics, key):
    pose_key, rotation_key, position_key = jax.random.split(key, 3)
    physics = self._walker.reinitialize_pose(physics, pose_key)
    if self._walker_spawn_rotation:
      rotation = variation.evaluate(
          self._walker_spawn_rotation, key=rotation_key
      )
      quat = [jnp.cos(rotation / 2), 0, 0, jnp.sin(rotation / 2)]
    else:
      quat = None
    return self._walker.shift_pose(
        physics,
        position=variation.evaluate(
            self._walker_spawn_position, key=position_key
        ),
        quaternion=quat,
        rotate_velocity=True,
    )

  def _is_disallowed_contact(self, physics):
    return contacts.between(
        physics, self._walker_nonfoot_geoms, self._arena.ground_geoms
    ).touching

  def before_step(self, physics, action, key):
    return self._walker.apply_action(physics, action, key)

  def after_step(self, physics, key):
    failure_termination = jnp.array(False)
    if self._contact_termination:
      failure_termination |= self._is_disallowed_contact(physics)
    if self._terminate_at_height is not None:
      failure_termination |= jnp.any(
          physics.bind(self._walker.end_effectors).xpos[:, -1]
          < self._terminate_at_height
      )
    return physics.update_task_state(failure_termination=failure_termination)

  def get_reward(self, physics):
    walker_xvel = physics.bind(self._walker.root_body).subtree_linvel[0]
    xvel_term = rewards.tolerance(
        walker_xvel,
        (self._vel, self._vel),
        margin=self._vel,
        sigmoid='linear',
        value_at_margin=0.0,
    )
    return xvel_term

  def should_terminate_episode(self, physics):
    return physics.task_state['failure_termination']

  def get_discount(self, physics):
    return jnp.where(physics.task_state['failure_termination'], 0.0, 1.0)
