# Copyright 2020 The dm_control Authors.
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#    http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
# ============================================================================
"""dm_control's composer tutorial on mjx_composer: `dm_control_tutorial.py` ported.

Diff it against `dm_control_tutorial.py` (dm_control's `tutorial.ipynb`):
the imports change, and the hooks become pure: they take a key and return
the physics. The PyMJCF models (`Leg`, `make_creature`, the `Button`'s)
are unchanged. Changed because hooks are pure: the `Button`'s activation
count lives in its per-world entity state (`initial_state`), read with
`num_activated_steps(physics)`; traced values branch with `jnp.where` and
`&`, and `UniformCircle` uses `jnp` for its traced heading. Changed beyond
that: the arena is an MjSpec (`add_light`).
"""

# PyMJCF
from dm_control import mjcf

# Composer high level imports
import mjx_composer as composer
from mjx_composer import variation
from mjx_composer.observation import observable

# Imports for Composer tutorial example
from mjx_composer.suite.entities import arenas as floors
from mjx_composer.variation import distributions
from mjx_composer.variation import noises

import jax.numpy as jnp
import numpy as np


class Leg(object):
  """A 2-DoF leg with position actuators."""

  def __init__(self, length, rgba):
    self.model = mjcf.RootElement()

    # Defaults:
    self.model.default.joint.damping = 2
    self.model.default.joint.type = 'hinge'
    self.model.default.geom.type = 'capsule'
    self.model.default.geom.rgba = rgba  # Continued below...

    # Thigh:
    self.thigh = self.model.worldbody.add('body')
    self.hip = self.thigh.add('joint', axis=[0, 0, 1])
    self.thigh.add('geom', fromto=[0, 0, 0, length, 0, 0], size=[length / 4])

    # Hip:
    self.shin = self.thigh.add('body', pos=[length, 0, 0])
    self.knee = self.shin.add('joint', axis=[0, 1, 0])
    self.shin.add('geom', fromto=[0, 0, 0, 0, 0, -length], size=[length / 5])

    # Position actuators:
    self.model.actuator.add('position', joint=self.hip, kp=10)
    self.model.actuator.add('position', joint=self.knee, kp=10)


BODY_RADIUS = 0.1
BODY_SIZE = (BODY_RADIUS, BODY_RADIUS, BODY_RADIUS / 2)
random_state = np.random.RandomState(42)


def make_creature(num_legs):
  """Constructs a creature with `num_legs` legs."""
  rgba = random_state.uniform([0, 0, 0, 1], [1, 1, 1, 1])
  model = mjcf.RootElement()
  model.compiler.angle = 'radian'  # Use radians.

  # Make the torso geom.
  model.worldbody.add(
      'geom', name='torso', type='ellipsoid', size=BODY_SIZE, rgba=rgba
  )

  # Attach legs to equidistant sites on the circumference.
  for i in range(num_legs):
    theta = 2 * i * np.pi / num_legs
    hip_pos = BODY_RADIUS * np.array([np.cos(theta), np.sin(theta), 0])
    hip_site = model.worldbody.add('site', pos=hip_pos, euler=[0, 0, theta])
    leg = Leg(length=BODY_RADIUS, rgba=rgba)
    hip_site.attach(leg.model)

  return model


class Creature(composer.Entity):
  """A multi-legged creature derived from `composer.Entity`."""

  def _build(self, num_legs):
    self._model = make_creature(num_legs)

  def _build_observables(self):
    return CreatureObservables(self)

  @property
  def mjcf_model(self):
    return self._model

  @property
  def actuators(self):
    return tuple(self._model.find_all('actuator'))


# Add simple observable features for joint angles and velocities.
class CreatureObservables(composer.Observables):

  @composer.observable
  def joint_positions(self):
    all_joints = self._entity.mjcf_model.find_all('joint')
    return observable.MJCFFeature('qpos', all_joints)

  @composer.observable
  def joint_velocities(self):
    all_joints = self._entity.mjcf_model.find_all('joint')
    return observable.MJCFFeature('qvel', all_joints)


NUM_SUBSTEPS = 25  # The number of physics substeps per control timestep.


class Button(composer.Entity):
  """A button Entity which changes colour when pressed with certain force."""

  def _build(self, target_force_range=(5, 10)):
    self._min_force, self._max_force = target_force_range
    self._mjcf_model = mjcf.RootElement()
    self._geom = self._mjcf_model.worldbody.add(
        'geom', type='cylinder', size=[0.25, 0.02], rgba=[1, 0, 0, 1]
    )
    self._site = self._mjcf_model.worldbody.add(
        'site', type='cylinder', size=self._geom.size * 1.01, rgba=[1, 0, 0, 0]
    )
    self._sensor = self._mjcf_model.sensor.add('touch', site=self._site)

  def initial_state(self):
    return {'num_activated_steps': jnp.zeros((), jnp.int32)}

  def _build_observables(self):
    return ButtonObservables(self)

  @property
  def mjcf_model(self):
    return self._mjcf_model

  # Update the activation (and colour) if the desired force is applied.
  def _update_activation(self, physics):
    current_force = physics.bind(self.touch_sensor).sensordata[0]
    is_activated = (current_force >= self._min_force) & (
        current_force <= self._max_force
    )
    physics = physics.bind(self._geom).set(
        rgba=jnp.where(
            is_activated, jnp.array([0, 1, 0, 1.0]), jnp.array([1, 0, 0, 1.0])
        )
    )
    return physics.update_entity_state(
        self,
        num_activated_steps=self.num_activated_steps(physics) + is_activated,
    )

  def initialize_episode(self, physics, key):
    return self._update_activation(physics)

  def after_substep(self, physics, key):
    return self._update_activation(physics)

  @property
  def touch_sensor(self):
    return self._sensor

  def num_activated_steps(self, physics):
    return physics.entity_state(self)['num_activated_steps']


class ButtonObservables(composer.Observables):
  """A touch sensor which averages contact force over physics substeps."""

  @composer.observable
  def touch_force(self):
    return observable.MJCFFeature(
        'sensordata',
        self._entity.touch_sensor,
        buffer_size=NUM_SUBSTEPS,
        aggregator='mean',
    )


class UniformCircle(variation.Variation):
  """A uniformly sampled horizontal point on a circle of radius `distance`."""

  def __init__(self, distance):
    self._distance = distance
    self._heading = distributions.Uniform(0, 2 * np.pi)

  def __call__(self, initial_value=None, current_value=None, key=None):
    distance, heading = variation.evaluate(
        (self._distance, self._heading), key=key
    )
    return (distance * jnp.cos(heading), distance * jnp.sin(heading), 0)


class PressWithSpecificForce(composer.Task):

  def __init__(self, creature):
    self._creature = creature
    self._arena = floors.Floor()
    self._arena.add_free_entity(self._creature)
    self._arena.mjcf_model.worldbody.add_light(pos=(0, 0, 4))
    self._button = Button()
    self._arena.attach(self._button)

    # Configure initial poses
    self._creature_initial_pose = (0, 0, 0.15)
    button_distance = distributions.Uniform(0.5, 0.75)
    self._button_initial_pose = UniformCircle(button_distance)

    # Configure variators
    self._mjcf_variator = variation.MJCFVariator()
    self._physics_variator = variation.PhysicsVariator()

    # Configure and enable observables
    pos_corrptor = noises.Additive(distributions.Normal(scale=0.01))
    self._creature.observables.joint_positions.corruptor = pos_corrptor
    self._creature.observables.joint_positions.enabled = True
    vel_corruptor = noises.Multiplicative(distributions.LogNormal(sigma=0.01))
    self._creature.observables.joint_velocities.corruptor = vel_corruptor
    self._creature.observables.joint_velocities.enabled = True
    self._button.observables.touch_force.enabled = True

    def to_button(physics):
      button_pos, _ = self._button.get_pose(physics)
      return self._creature.global_vector_to_local_frame(physics, button_pos)

    self._task_observables = {}
    self._task_observables['button_position'] = observable.Generic(to_button)

    for obs in self._task_observables.values():
      obs.enabled = True

    self.control_timestep = NUM_SUBSTEPS * self.physics_timestep

  @property
  def root_entity(self):
    return self._arena

  @property
  def task_observables(self):
    return self._task_observables

  def initialize_episode_mjcf(self, random_state):
    self._mjcf_variator.apply_variations(random_state)

  def initialize_episode(self, physics, key):
    physics = self._physics_variator.apply_variations(physics, key)
    creature_pose, button_pose = variation.evaluate(
        (self._creature_initial_pose, self._button_initial_pose),
        key=key,
    )
    physics = self._creature.set_pose(physics, position=creature_pose)
    return self._button.set_pose(physics, position=button_pose)

  def get_reward(self, physics):
    return self._button.num_activated_steps(physics) / NUM_SUBSTEPS


def make_environment():
  creature = Creature(num_legs=4)
  task = PressWithSpecificForce(creature)
  env = composer.Environment(task, random_state=np.random.RandomState(42))
  return env
