"""What a locomotion task on generated terrain adds to its flat-ground twin.

`TerrainJoystick` (the Go1) and `TerrainWalk` (the humanoid) are their flat
tasks with the same part: a `TerrainGenerator` arena, a `TerrainCurriculum`
that keeps each world's level and picks its spawn tile, a policy height scan
with its clean twin for the critic, and the robot's contacts with the
terrain limited and capped (`contact_caps`). `TerrainPart` builds them once
from the task's arguments and the task calls it from its own hooks:

    part = TerrainPart('MyTask', kinds=..., levels=..., ...)
    arena = part.terrain                          # the task's root entity
    part.observe(robot.trunk, n_sub_steps, noise=0.1, delay=1)
    physics, spawn = part.spawn(physics, key)     # initialize_episode
    physics = part.record(physics, xy, speed, dt)  # after_step
    part.out_of_bounds(xy)                        # should_terminate_episode

Leaving the terrain: beyond the height field's edge there is no ground, so
an episode whose robot comes within `OUT_OF_BOUNDS_MARGIN` of the edge ends
as a truncation (discount 1: Isaac Lab's `terrain_out_of_bounds`), not as a
fall. The tasks' default flat border around the grid, `BORDER`, is wide
enough that few episodes get there: with a 1 m border, 62.5% of a trained
Go1 policy's 20 s episodes on a flat 4 m tile reached the edge; with 16 m,
none (docs/locomotion.md, "The terrain's edge").

The contact caps: MJX collides a height field with a foot through a patch
of grid cells and keeps up to 4 contacts a foot, every one a slot of the
state and 4 constraint rows (pyramidal friction, `condim` 3) whether it
touches or not. A foot resting on a surface needs one contact, two in the
crease at the foot of a riser, so the terrain part caps the contacts at
`CONTACTS_PER_FOOT` per terrain-colliding foot (`max_contact_points`, MJX's
cap on the deepest contacts kept). The cap on candidate pairs
(`max_geom_pairs`) does not apply to a height field's pairs in MJX, and
every terrain pair is a foot's: the robot's own cap on its other pairs
stands.
"""

import jax.numpy as jnp
import numpy as np

from mjx_composer.observation import groups as groups_lib
from mjx_composer.suite.locomotion import curriculum as curriculum_lib
from mjx_composer.suite.locomotion import height_scan as height_scan_lib
from mjx_composer.suite.locomotion import policy_critic
from mjx_composer.suite.locomotion.terrain import generator
from mjx_composer.utils import validation

HEIGHT_SCAN_NOISE = 0.1  # Metres, per ray (Isaac Lab's height_scan noise).
OUT_OF_BOUNDS_MARGIN = 1.0  # Metres from the terrain's edge.
BORDER = 16.0  # Metres of flat ground around the grid (module docstring).
CONTACTS_PER_FOOT = 2  # A surface, or the crease at the foot of a riser.


class TerrainPart:
  """A generated terrain, its curriculum and height scan (module docstring).

  Args:
    owner: the task's name, for messages.
    kinds: the terrain's sub-terrain kinds (`sub_terrains.KINDS`).
    levels: the terrain's difficulty levels.
    tile_size: the side of a tile, metres.
    horizontal_scale: the terrain grid's spacing, metres.
    border: the width of the flat border around the grid, metres.
    initial_levels: (low, high) of a world's first level.
    scan_size: (length, width) of the height scan's grid, metres.
    scan_resolution: the height scan's spacing, metres.
    terrain_seed: the seed of the random sub-terrains.
    height_scan: whether the policy and the critic observe a height scan.
    group: the terrain geoms' group (apart from the robot's, so that rays
      see the terrain only).
  """

  def __init__(
      self,
      owner,
      *,
      kinds,
      levels,
      tile_size,
      horizontal_scale,
      border,
      initial_levels,
      scan_size,
      scan_resolution,
      terrain_seed,
      height_scan,
      group,
  ):
    check_arguments(
        owner,
        kinds=kinds,
        levels=levels,
        initial_levels=initial_levels,
        scan_size=scan_size,
        scan_resolution=scan_resolution,
        terrain_seed=terrain_seed,
        height_scan=height_scan,
    )
    tile_size = validation.check_positive('tile_size', tile_size, owner=owner)
    self.terrain = generator.TerrainGenerator(
        kinds=kinds,
        levels=levels,
        tile_size=tile_size,
        horizontal_scale=horizontal_scale,
        border=border,
        group=group,
        seed=terrain_seed,
    )
    self.curriculum = curriculum_lib.TerrainCurriculum(
        self.terrain, initial_levels=initial_levels
    )
    self._scan_args = (scan_size, scan_resolution) if height_scan else None
    self.scan = self.scan_twin = None

  def observe(self, frame, n_sub_steps, noise, delay):
    """Adds the policy's height scan around `frame` and the critic's twin.

    A yaw-aligned `HeightScan` of the terrain, U(-noise, noise) metres per
    ray, sampled once per control step, visible `delay` sub-steps later;
    the twin is clean and current. Nothing without `height_scan`.
    """
    if self._scan_args is None:
      return
    size, resolution = self._scan_args
    self.scan = height_scan_lib.HeightScan(
        frame,
        size=size,
        resolution=resolution,
        geomgroup=self.terrain.geomgroup,
    )
    policy_critic.policy_observable(
        self.scan,
        n_sub_steps,
        corruptor=policy_critic.uniform_noise(noise) if noise else None,
        delay=delay,
    )
    self.scan_twin = policy_critic.clean_twin(self.scan)

  def cap_contacts(self, feet):
    """Sets MJX's contact cap for `feet`, the geoms that touch the terrain.

    Writes `max_contact_points` (`CONTACTS_PER_FOOT` per foot) on the
    arena's spec, the root's, where MJX reads it; replaces the robot's own.
    """
    spec = self.terrain.mjcf_model
    for numeric in list(spec.numerics):
      if numeric.name == 'max_contact_points':
        spec.delete(numeric)
    spec.add_numeric(
        name='max_contact_points', data=[CONTACTS_PER_FOOT * len(feet)]
    )

  # -- observations ----------------------------------------------------------

  def observables(self, observables):
    """`observables` with the scan as 'height_scan' and its twin as
    'privileged_height_scan' (unchanged without a scan)."""
    if self.scan is None:
      return observables
    return {
        **observables,
        'height_scan': self.scan,
        'privileged_height_scan': self.scan_twin,
    }

  def groups(self, groups):
    """`groups` with 'height_scan' in the policy's and its twin in the
    critic's (unchanged without a scan)."""
    if self.scan is None:
      return groups
    policy, critic = groups['policy'], groups['critic']
    return {
        'policy': groups_lib.ObservationGroup(
            keys=list(policy.keys) + ['height_scan'], flatten=True
        ),
        'critic': groups_lib.ObservationGroup(
            keys=list(critic.keys) + ['privileged_height_scan'],
            corrupted=False,
            flatten=True,
        ),
    }

  # -- episode (device) ------------------------------------------------------

  def spawn(self, physics, key):
    """Moves the world's level and draws its tile: `(physics, spawn (3,))`."""
    return self.curriculum.reset(physics, key)

  def record(self, physics, position, command_speed, dt):
    """Records the episode's progress for the curriculum (`after_step`)."""
    return self.curriculum.record(physics, position, command_speed, dt)

  def out_of_bounds(self, xy):
    """Whether `xy` lies within `OUT_OF_BOUNDS_MARGIN` of the edge."""
    limit = jnp.asarray(self.terrain.half_extent - OUT_OF_BOUNDS_MARGIN)
    return jnp.any(jnp.abs(xy) > limit)

  def metrics(self, physics):
    """`{'terrain_level': level}` for `get_metrics`."""
    return self.curriculum.metrics(physics)


def check_arguments(owner, **kwargs):
  """Checks a terrain task's arguments before anything is built.

  Each of `kinds` (a non-empty sequence of sub-terrain names; unknown names
  are refused by the `TerrainGenerator`), `levels` (an int >= 1),
  `initial_levels` and `actuation_delay` ((low, high) ints >= 0),
  `scan_size` (a (length, width) pair > 0), `scan_resolution` (> 0),
  `terrain_seed` (an int >= 0) and `height_scan` (a bool) that is given;
  `owner` names the task in the messages.
  """
  v = validation
  if 'kinds' in kwargs:
    kinds = kwargs['kinds']
    if (
        isinstance(kinds, str)
        or not isinstance(kinds, (tuple, list))
        or not kinds
    ):
      raise TypeError(
          f'{owner}: `kinds` must be a non-empty sequence of sub-terrain '
          f'names, got {kinds!r}. Pass e.g. kinds=sub_terrains.KINDS.'
      )
  if 'levels' in kwargs:
    v.check_integer('levels', kwargs['levels'], owner=owner, minimum=1)
  for name in ('initial_levels', 'actuation_delay'):
    if name in kwargs:
      pair = kwargs[name]
      v.check_range_pair(name, pair, owner=owner, nonnegative=True)
      for i, bound in enumerate(pair):
        v.check_integer(f'{name}[{i}]', bound, owner=owner, minimum=0)
  if 'scan_size' in kwargs:
    size = kwargs['scan_size']
    if isinstance(size, str) or np.ndim(size) != 1 or len(size) != 2:
      raise TypeError(
          f'{owner}: `scan_size` must be a (length, width) pair, got '
          f'{size!r}. Pass two positive numbers of metres, e.g. (1.6, 1.0).'
      )
    v.check_positive('scan_size', size, owner=owner)
  if 'scan_resolution' in kwargs:
    v.check_positive('scan_resolution', kwargs['scan_resolution'], owner=owner)
  if 'terrain_seed' in kwargs:
    v.check_integer(
        'terrain_seed', kwargs['terrain_seed'], owner=owner, minimum=0
    )
  if 'height_scan' in kwargs:
    v.check_bool('height_scan', kwargs['height_scan'], owner=owner)
