"""The Go1 joystick on generated terrain, composed from the locomotion kit.

Isaac Lab's and mjlab's rough-terrain velocity task on `Joystick`'s robot,
rewards and randomization (`tasks/joystick.py`), with each locomotion part
a reusable piece of `mjx_composer.suite.locomotion`, joined by the terrain part
that `TerrainWalk` shares (`terrain_part.TerrainPart`):

* the arena is a `TerrainGenerator` (every sub-terrain kind, stairs, stones
  and beams included, in one height field; a grid of difficulty levels x
  kinds);
* a `TerrainCurriculum` keeps each world's level: a robot that walked more
  than half a tile from its spawn point goes up a level at its next
  episode, one that covered less than half its commanded distance goes
  down; the level is reported as the `terrain_level` metric;
* every episode starts on the platform of a tile of the world's level (a
  kind drawn per episode), with `Joystick`'s spread of the initial pose
  (+U(-0.5, 0.5) m around the platform's centre);
* the policy sees a `HeightScan` of the terrain (a 1.6 m x 1.0 m grid every
  0.1 m around the trunk, aligned with its heading) with U(-0.1, 0.1) m
  noise per ray, and the critic its clean twin (`height_scan=False`: no
  scan, `Joystick`'s observation groups);
* an `ActuationDelay` delays the motors by a per-episode draw of
  `actuation_delay` physics sub-steps;
* the command is `Joystick`'s `VelocityCommand`.

The Go1 collides with the terrain by its feet only (`collisions='feet'`,
Playground's feet-only model): on a height field the trunk's box would
cost dozens of grid cells at every physics step where a foot costs four.
A fall is the trunk upside down or its box reaching below the terrain
under it (`Joystick.fallen`). An episode whose trunk comes near the
terrain's edge ends as a truncation, not a fall; the flat border around
the grid keeps that rare (`terrain_part`). The contacts are capped at two per foot
(`terrain_part`). The terrain's grid is 0.05 m, the finest at which a foot
meets 2 x 2 cells (`locomotion.terrain.generator`).
"""

import jax
import jax.numpy as jnp

from mjx_composer.suite.locomotion import actuation_delay as delay_lib
from mjx_composer.suite.locomotion.terrain import sub_terrains
from mjx_composer.suite.locomotion.terrain import terrain_part
from mjx_composer.suite.tasks import joystick

HORIZONTAL_SCALE = 0.05  # Metres: a foot meets 2 x 2 cells (docstring).


class TerrainJoystick(joystick.Joystick):
  """`Joystick` on a generated terrain with a curriculum (module docstring).

  Args:
    kinds: the terrain's sub-terrain kinds (`sub_terrains.KINDS`).
    levels: the terrain's difficulty levels.
    tile_size: the side of a tile, metres.
    border: the width of the flat border around the grid, metres.
    initial_levels: (low, high) of a world's first level.
    actuation_delay: (low, high) of the motors' delay in physics sub-steps.
    scan_size: (length, width) of the height scan's grid, metres.
    scan_resolution: the height scan's spacing, metres.
    terrain_seed: the seed of the random sub-terrains.
    height_scan: whether the policy and the critic observe the height scan
      (False: neither does, and no rays are cast).
    collisions: the `Go1`'s contacts ('feet': the feet only; see
      `entities.go1`).
    **kwargs: `Joystick`'s arguments (not `terrain`).
  """

  def __init__(
      self,
      kinds=sub_terrains.KINDS,
      levels=5,
      tile_size=4.0,
      border=terrain_part.BORDER,
      initial_levels=(0, 1),
      actuation_delay=(0, 2),
      scan_size=(1.6, 1.0),
      scan_resolution=0.1,
      terrain_seed=0,
      height_scan=True,
      collisions='feet',
      **kwargs,
  ):
    terrain_part.check_arguments(
        'TerrainJoystick', actuation_delay=actuation_delay
    )
    if 'terrain' in kwargs:
      raise TypeError(
          'TerrainJoystick generates its terrain: pass kinds, levels and '
          f"tile_size instead of terrain={kwargs['terrain']!r}."
      )
    self._part = terrain_part.TerrainPart(
        'TerrainJoystick',
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
        group=0,
    )
    super().__init__(terrain='flat', collisions=collisions, **kwargs)
    self._terrain = 'generated'
    if collisions == 'feet':
      self._part.cap_contacts(self.go1.foot_geoms)
    self._delay = delay_lib.ActuationDelay(self.go1.actuators, actuation_delay)
    self._part.observe(
        self.go1.trunk,
        self.physics_steps_per_control_step,
        noise=self.noise_level * terrain_part.HEIGHT_SCAN_NOISE,
        delay=self.observation_delay,
    )

  def _build_arena(self, terrain):
    del terrain
    return self._part.terrain

  def _ground(self, physics, key, xy):
    """Spawns on a tile of this world's level (the curriculum's)."""
    del xy
    physics, spawn = self._part.spawn(physics, key)
    return physics, spawn[:2], spawn[2] + 0.01

  # -- composition -----------------------------------------------------------

  @property
  def terrain(self):
    return self._part.terrain

  @property
  def curriculum(self):
    return self._part.curriculum

  @property
  def actuation_delay(self):
    return self._delay

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

  def out_of_bounds(self, physics):
    """Whether the trunk is near the terrain's edge (`TerrainPart`)."""
    return self._part.out_of_bounds(physics.bind(self.go1.trunk).xpos[:2])

  def should_terminate_episode(self, physics):
    """A fall, or leaving the terrain (`Joystick.get_discount` reads the
    fall alone: discount 1 when leaving)."""
    return jnp.logical_or(
        super().should_terminate_episode(physics), self.out_of_bounds(physics)
    )

  def initial_task_state(self):
    return {**super().initial_task_state(), **self._delay.initial_state()}

  def initialize_episode(self, physics, key):
    physics = super().initialize_episode(physics, key)
    return self._delay.reset(physics, jax.random.fold_in(key, 11))

  def before_substep(self, physics, action, key):
    del action, key
    return self._delay.before_substep(physics)

  def after_substep(self, physics, key):
    del key
    return self._delay.after_substep(physics)

  def after_step(self, physics, key):
    physics = super().after_step(physics, key)
    command = self.command.velocity(physics)
    return self._part.record(
        physics,
        physics.bind(self.go1.trunk).xpos,
        jnp.linalg.norm(command[:2]),
        self.control_timestep,
    )

  def get_metrics(self, physics):
    return {
        **super().get_metrics(physics),
        **self._part.metrics(physics),
    }
