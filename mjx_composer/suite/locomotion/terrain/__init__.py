"""Terrain arenas: grounds that are one MuJoCo height field.

* `TerrainGenerator` (`generator.py`): a grid of sub-terrains
  (`sub_terrains.py`: slopes, waves, obstacles, stairs, stepping stones,
  beams, random grids) of rising difficulty, with a spawn point per tile,
  for a `curriculum.TerrainCurriculum`.
* `RoughTerrain` (`rough.py`): bumps and noise, a profile per world and
  episode.
* `surface.HeightField`: what both are built from, and where the ground is
  below a point, on the device.
* `terrain_part.TerrainPart`: what the terrain tasks add to their flat
  twins (a `TerrainGenerator`, its curriculum, a height scan), and
  `terrain_part.check_arguments`, their terrain arguments' checks.
"""

from mjx_composer.suite.locomotion.terrain import sub_terrains
from mjx_composer.suite.locomotion.terrain import surface
from mjx_composer.suite.locomotion.terrain.generator import TerrainGenerator
from mjx_composer.suite.locomotion.terrain.rough import RoughTerrain

__all__ = ['RoughTerrain', 'TerrainGenerator', 'sub_terrains', 'surface']
