"""The humanoid walk on generated terrain, composed from the locomotion kit.

`Walk`'s humanoid, reward, observation and randomization (`tasks/walk.py`)
on the kit's terrain, each locomotion part a reusable piece of
`mjx_composer.suite.locomotion`:

* the arena is a `TerrainGenerator` (by default `KINDS`: flat, rough,
  slopes up and down, waves, stairs up and down; 5 levels of 8 m tiles,
  Isaac Lab's tile size),
  its geoms in geom group `TERRAIN_GROUP` (2), apart from the humanoid's
  (group 0), so that rays see the terrain only;
* a `TerrainCurriculum` keeps each world's level: a humanoid that walked
  more than half a tile from its spawn point goes up a level at its next
  episode, one that covered less than half of `move_speed` x its episode's
  duration goes down; the level is reported as the `terrain_level` metric;
* every episode starts on the platform of a tile of the world's level (a
  kind drawn per episode), the torso `initial_height` above the platform,
  with `Walk`'s random heading and joint angles;
* the reward is `Walk`'s, `standing * upright * small_control * move`,
  with the head's height measured above the terrain directly below it (a
  one-ray `HeightScan` down from the head) rather than above z = 0; the
  same height decides falls (`fall_height`);
* the policy sees a `HeightScan` of the terrain (a 1.6 m x 1.0 m grid every
  0.1 m around the torso, aligned with its heading) with U(-0.1, 0.1) m
  noise per ray, delayed as `Walk`'s other policy inputs, and the critic
  its clean twin (`height_scan=False`: neither);
* an episode also ends, as a truncation (discount 1), when the torso comes
  within `terrain_part.OUT_OF_BOUNDS_MARGIN` of the terrain's edge: beyond
  it there is no ground; the flat border around the grid
  (`terrain_part.BORDER`) keeps that rare.

The humanoid collides with the terrain by its feet only
(`collisions='feet'`: the four foot capsules; the head's height decides
falls) and its contacts are capped at two per capsule, as the XML's cap of
8 has them (`terrain_part`). The terrain's grid is 0.1 m: a foot capsule
(0.134 m bounding radius) meets 4 x 4 cells there, 7 x 7 at the Go1's
0.05 m; a stair's 0.3 m tread keeps its top and its riser becomes a
0.1 m slope (`sub_terrains`).

Deviation from `Walk`: the randomized ground friction is the height
field's (the terrain's one geom, as `Walk` randomizes its floor's).
"""

import jax.numpy as jnp
import numpy as np

from mjx_composer.suite.locomotion import height_scan as height_scan_lib
from mjx_composer.suite.locomotion.terrain import terrain_part
from mjx_composer.suite.tasks import walk

# The default sub-terrain kinds: continuous ground and stairs, without the
# stepping stones, beams, grids and obstacles (`kinds=sub_terrains.KINDS`
# adds them).
KINDS = (
    'flat',
    'random_uniform',
    'pyramid_slope',
    'inverted_pyramid_slope',
    'waves',
    'pyramid_stairs',
    'inverted_pyramid_stairs',
)
TERRAIN_GROUP = 2  # The humanoid's geoms are in group 0.
HORIZONTAL_SCALE = 0.1  # Metres: a foot capsule meets 4 x 4 cells.
_OWNER = 'TerrainWalk'


class TerrainWalk(walk.Walk):
  """`Walk` on a generated terrain with a curriculum (module docstring).

  Args:
    kinds: the terrain's sub-terrain kinds (`sub_terrains.KINDS`).
    levels: the terrain's difficulty levels.
    tile_size: the side of a tile, metres.
    border: the width of the flat border around the grid, metres.
    initial_levels: (low, high) of a world's first level.
    scan_size: (length, width) of the height scan's grid, metres.
    scan_resolution: the height scan's spacing, metres.
    terrain_seed: the seed of the random sub-terrains.
    height_scan: whether the policy and the critic observe the height scan
      (False: neither does; the head's height is still measured by a ray).
    collisions: the `Humanoid`'s contacts ('feet': the foot capsules only).
    **kwargs: `Walk`'s arguments.
  """

  def __init__(
      self,
      kinds=KINDS,
      levels=5,
      tile_size=8.0,
      border=terrain_part.BORDER,
      initial_levels=(0, 1),
      scan_size=(1.6, 1.0),
      scan_resolution=0.1,
      terrain_seed=0,
      height_scan=True,
      collisions='feet',
      **kwargs,
  ):
    self._part = terrain_part.TerrainPart(
        _OWNER,
        kinds=kinds,
        levels=levels,
        tile_size=tile_size,
        horizontal_scale=HORIZONTAL_SCALE,
        border=border,
        initial_levels=initial_levels,
        scan_size=scan_size,
        scan_resolution=scan_resolution,
        terrain_seed=terrain_seed,
        height_scan=height_scan,
        group=TERRAIN_GROUP,
    )
    super().__init__(collisions=collisions, **kwargs)
    if collisions == 'feet':
      self._part.cap_contacts(self.humanoid.foot_geoms)
    # The ground below the head: one ray, straight down from above it.
    self._head_ray = height_scan_lib.HeightScan(
        self.humanoid.head,
        points=np.zeros((1, 2), np.float32),
        alignment='world',
        geomgroup=self._arena.geomgroup,
    )
    self._part.observe(
        self.humanoid.torso,
        self.physics_steps_per_control_step,
        noise=self.noise_level * terrain_part.HEIGHT_SCAN_NOISE,
        delay=self.observation_delay,
    )

  def _build_arena(self):
    return self._part.terrain

  def _start(self, physics, key):
    """Starts on a tile of this world's level (the curriculum's)."""
    physics, spawn = self._part.spawn(physics, key)
    lift = jnp.array([0.0, 0.0, self.humanoid.initial_height], jnp.float32)
    return physics, spawn + lift

  # -- composition -----------------------------------------------------------

  @property
  def terrain(self):
    return self._part.terrain

  @property
  def curriculum(self):
    return self._part.curriculum

  @property
  def height_scan(self):
    """The policy's `HeightScan` (None with `height_scan=False`)."""
    return self._part.scan

  @property
  def task_observables(self):
    return self._part.observables(super().task_observables)

  def observation_groups(self):
    return self._part.groups(super().observation_groups())

  # -- episode ---------------------------------------------------------------

  def after_step(self, physics, key):
    del key
    return self._part.record(
        physics,
        physics.bind(self.humanoid.torso).xpos,
        self._move_speed,
        self.control_timestep,
    )

  # -- outcome ---------------------------------------------------------------

  def head_height(self, physics):
    """The head's height above the terrain directly below it, metres."""
    return -self._head_ray.scan(physics)[0][0]

  def out_of_bounds(self, physics):
    """Whether the torso is near the terrain's edge (`TerrainPart`)."""
    return self._part.out_of_bounds(physics.bind(self.humanoid.torso).xpos[:2])

  def should_terminate_episode(self, physics):
    return jnp.logical_or(
        super().should_terminate_episode(physics), self.out_of_bounds(physics)
    )

  def get_discount(self, physics):
    """0 after a fall (as `Walk`'s); 1 when leaving the terrain."""
    fell = super().should_terminate_episode(physics)
    return jnp.where(fell, 0.0, 1.0)

  def get_metrics(self, physics):
    return {
        **super().get_metrics(physics),
        **self._part.metrics(physics),
    }
