"""Push: sweep randomly placed boxes into a target zone with the arm.

The scene composes bundled entities only: a `WalledArena`, the `Arm` robot at
its centre, `num_boxes` free `Box` props, and a 2D `PositionDetector` that
marks the target zone. Every episode, per world, the zone moves to a random
spot on a ring around the arm and a `PropPlacer` drops the boxes at random
positions and headings on the floor such that no box starts in contact with
anything: the walls, the arm, or another box. A world whose boxes cannot all
be placed is marked as a failed initialization, which
`Environment(max_reset_attempts=...)` resamples.

Observations come in two groups, like reach's: the policy sees noisy joint
positions and velocities, the hand position, the boxes' positions and the
zone's centre; the critic additionally sees the boxes' velocities and which
boxes are in the zone.
"""

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer import task
from mjx_composer.initializers import prop_initializer
from mjx_composer.observation import groups as groups_lib
from mjx_composer.suite.entities import arenas
from mjx_composer.suite.entities import position_detector
from mjx_composer.suite.entities import props
from mjx_composer.suite.entities import robots
from mjx_composer.suite.entities import simulation_options as options_lib
from mjx_composer.suite.tasks import arm_parts
from mjx_composer.utils import validation
from mjx_composer.variation import distributions
from mjx_composer.variation import rotations

_ARENA_HALF_SIZE = 0.55
_BOX_HALF_SIZE = 0.03
# Boxes start this far above the floor: a box resting exactly on the floor
# touches it (distance 0), which composer's placer counts as a collision.
_DROP_HEIGHT = 0.002
_PLACEMENT_HALF_SIZE = 0.48
_ZONE_HALF_SIZE = 0.1
_ZONE_RADIUS = (0.25, 0.4)
_PLACEMENTS = ('placer', 'ring', 'unchecked', 'fixed')
_BOX_COLOURS = (
    (0.85, 0.3, 0.25, 1.0),
    (0.3, 0.7, 0.35, 1.0),
    (0.25, 0.45, 0.85, 1.0),
    (0.85, 0.75, 0.2, 1.0),
    (0.6, 0.35, 0.75, 1.0),
)


class Push(task.Task):
  """Push every box into the target zone.

  Reward, in [0, 1]: `0.6 * fraction of boxes in the zone + 0.3 * mean over
  boxes of (1 - tanh(box-to-zone xy distance / 0.3)) + 0.1 * (1 -
  tanh(distance from the hand to the nearest box outside the zone / 0.3))`.
  No termination: episodes end at the time limit.

  Args:
    num_boxes: how many boxes (5 by default, the benchmark's figure).
    placement: how the boxes start each episode: 'placer' (a `PropPlacer`:
      random positions and headings, never in collision); or, to measure
      what placement costs, 'ring' (the built ring around the arm turned by a
      random angle, random headings: random but collision-free by
      construction), 'unchecked' (the placer's distributions, first sample
      taken, boxes may overlap: `ignore_collisions=True`), or 'fixed' (the
      built ring in every world).
    max_attempts_per_prop: the placer's candidates per box.
    max_contact_points: MJX's cap on contacts handed to the solver (the
      deepest ones are kept; MuJoCo on the host ignores it). Five boxes on a
      floor between walls have ~200 potential contact points, which makes
      the constraint solver the dominant cost of a step; None for no cap.
    control_timestep, physics_timestep: seconds per agent and physics step.
    observation_noise: standard deviation of the joint sensor noise.
    solver_iterations, solver_ls_iterations: MuJoCo's solver caps written
      on the root (`simulation_options.SOLVER_CAPS` by default: 4 and 8;
      None keeps MuJoCo's 100 and 50, on which MJX's float32 solver runs
      far longer for nearly the same trajectory).
  """

  def __init__(
      self,
      num_boxes=5,
      placement='placer',
      max_attempts_per_prop=20,
      max_contact_points=40,
      control_timestep=0.02,
      physics_timestep=0.004,
      observation_noise=0.01,
      solver_iterations=options_lib.SOLVER_CAPS['iterations'],
      solver_ls_iterations=options_lib.SOLVER_CAPS['ls_iterations'],
  ):
    validation.check_integer('num_boxes', num_boxes, owner='Push', minimum=1)
    validation.check_choice('placement', placement, _PLACEMENTS, owner='Push')
    validation.check_integer(
        'max_attempts_per_prop', max_attempts_per_prop, owner='Push', minimum=1
    )
    if max_contact_points is not None:
      validation.check_integer(
          'max_contact_points',
          max_contact_points,
          owner='Push',
          minimum=1,
          fix='Pass an int >= 1, or None for no cap.',
      )
    arm_parts.check_arm_task_arguments(
        'Push',
        control_timestep,
        physics_timestep,
        observation_noise,
        solver_iterations,
        solver_ls_iterations,
    )
    self._arena = arenas.WalledArena(
        size=(_ARENA_HALF_SIZE, _ARENA_HALF_SIZE), size_variation=None
    )
    self._arm = robots.Arm()
    self._arena.attach(self._arm)
    self._boxes = []
    self._ring = []
    for i in range(num_boxes):
      box = props.Box(
          half_lengths=(_BOX_HALF_SIZE,) * 3,
          mass=0.1,
          rgba=_BOX_COLOURS[i % len(_BOX_COLOURS)],
          name=f'box_{i}',
      )
      frame = self._arena.add_free_entity(box)
      # Where the boxes start without the placer: a ring that is clear of
      # the arm and of each other.
      angle = 2 * np.pi * i / max(num_boxes, 1)
      frame.pos = [
          0.3 * np.cos(angle),
          0.3 * np.sin(angle),
          _BOX_HALF_SIZE + _DROP_HEIGHT,
      ]
      self._ring.append(np.array(frame.pos))
      self._boxes.append(box)
    self._zone = position_detector.PositionDetector(
        pos=(_ZONE_RADIUS[0], 0.0),
        size=(_ZONE_HALF_SIZE, _ZONE_HALF_SIZE),
        visible=True,
        rgba=(0.2, 0.9, 0.3, 0.3),
        name='zone',
    )
    self._arena.attach(self._zone)
    self._zone.register_entities(*self._boxes)
    if max_contact_points is not None:
      self._arena.mjcf_model.add_numeric(
          name='max_contact_points', data=[max_contact_points]
      )
    self._placement = placement
    z = _BOX_HALF_SIZE + _DROP_HEIGHT
    self._placer = prop_initializer.PropPlacer(
        self._boxes,
        position=distributions.Uniform(
            low=(-_PLACEMENT_HALF_SIZE, -_PLACEMENT_HALF_SIZE, z),
            high=(_PLACEMENT_HALF_SIZE, _PLACEMENT_HALF_SIZE, z),
        ),
        quaternion=rotations.QuaternionFromAxisAngle(
            axis=(0.0, 0.0, 1.0), angle=distributions.Uniform(-np.pi, np.pi)
        ),
        ignore_collisions=placement == 'unchecked',
        max_attempts_per_prop=max_attempts_per_prop,
    )
    self.set_timesteps(control_timestep, physics_timestep)
    arm_parts.cap_solver(self._arena, solver_iterations, solver_ls_iterations)

    arm_obs = self._arm.observables
    arm_obs.joint_positions.configure(
        enabled=True, corruptor=arm_parts.gaussian_noise(observation_noise)
    )
    arm_obs.joint_velocities.configure(
        enabled=True, corruptor=arm_parts.gaussian_noise(10 * observation_noise)
    )
    arm_obs.hand_position.enabled = True
    for box in self._boxes:
      box.observables.position.enabled = True
      box.observables.linear_velocity.enabled = True
    self._zone.observables.mid.enabled = True
    self._zone.observables.detected.enabled = True

  @property
  def root_entity(self):
    return self._arena

  @property
  def arm(self):
    return self._arm

  @property
  def boxes(self):
    return tuple(self._boxes)

  @property
  def zone(self):
    return self._zone

  @property
  def placer(self):
    return self._placer

  def observation_groups(self):
    """The policy/critic split used by the demo and training scripts."""
    boxes = [box.name for box in self._boxes]
    policy = (
        ['arm/joint_positions', 'arm/joint_velocities', 'arm/hand_position']
        + [f'{b}/position' for b in boxes]
        + ['zone/mid']
    )
    critic = (
        policy + [f'{b}/linear_velocity' for b in boxes] + ['zone/detected']
    )
    return {
        'policy': groups_lib.ObservationGroup(keys=policy, flatten=True),
        'critic': groups_lib.ObservationGroup(
            keys=critic, corrupted=False, flatten=True
        ),
    }

  def initialize_episode(self, physics, key):
    zone_key, place_key = jax.random.split(key)
    angle, radius = jax.random.uniform(
        zone_key,
        (2,),
        minval=jnp.array([-np.pi, _ZONE_RADIUS[0]]),
        maxval=jnp.array([np.pi, _ZONE_RADIUS[1]]),
    )
    physics = self._zone.set_position(
        physics, radius * jnp.array([jnp.cos(angle), jnp.sin(angle)])
    )
    if self._placement in ('placer', 'unchecked'):
      physics = self._placer(physics, place_key)
    elif self._placement == 'ring':
      physics = self._turn_ring(physics, place_key)
    return physics

  def _turn_ring(self, physics, key):
    turn_key, yaw_key = jax.random.split(key)
    turn = jax.random.uniform(turn_key, (), minval=-np.pi, maxval=np.pi)
    yaws = jax.random.uniform(
        yaw_key, (len(self._boxes),), minval=-np.pi, maxval=np.pi
    )
    c, s = jnp.cos(turn), jnp.sin(turn)
    for box, built, yaw in zip(self._boxes, self._ring, yaws):
      position = jnp.array(
          [c * built[0] - s * built[1], s * built[0] + c * built[1], built[2]]
      )
      quaternion = jnp.array([jnp.cos(yaw / 2), 0.0, 0.0, jnp.sin(yaw / 2)])
      physics = box.set_pose(physics, position, quaternion)
    return physics

  # -- reward ----------------------------------------------------------------

  def _box_positions(self, physics):
    return physics.bind([box.geom for box in self._boxes]).xpos

  def _zone_centre(self, physics):
    return physics.bind(self._zone.mid_site).pos[:2]

  def _box_to_zone(self, physics):
    return jnp.linalg.norm(
        self._box_positions(physics)[:, :2] - self._zone_centre(physics),
        axis=-1,
    )

  def get_reward(self, physics):
    in_zone = self._zone.detected_entities(physics)
    closeness = 1.0 - jnp.tanh(self._box_to_zone(physics) / 0.3)
    hand = physics.bind(self._arm.hand).xpos
    to_hand = jnp.linalg.norm(self._box_positions(physics) - hand, axis=-1)
    nearest = jnp.min(jnp.where(in_zone, jnp.inf, to_hand))
    reach_term = jnp.where(
        jnp.isfinite(nearest), 1.0 - jnp.tanh(nearest / 0.3), 1.0
    )
    return (
        0.6 * jnp.mean(in_zone.astype(jnp.float32))
        + 0.3 * jnp.mean(closeness)
        + 0.1 * reach_term
    )

  def get_metrics(self, physics):
    return {
        'boxes_in_zone': jnp.sum(
            self._zone.detected_entities(physics).astype(jnp.float32)
        ),
        'distance': jnp.mean(self._box_to_zone(physics)),
    }
