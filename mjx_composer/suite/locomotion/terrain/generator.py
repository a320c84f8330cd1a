"""TerrainGenerator: an arena of sub-terrains in a grid of levels x kinds.

Isaac Lab's and mjlab's terrain generator as a composer `Arena`: tile
`(level, kind)` is the sub-terrain `kinds[kind]` (`sub_terrains.KINDS`) at
the difficulty of `level` (`difficulty_range[0]` at level 0 rising linearly
to `difficulty_range[1]` at the last level). Levels run along x, kinds
along y. Every kind, stairs, stones and beams included, is written into one
MuJoCo height field covering the whole grid and a flat border around it
(`sub_terrains` says how a block becomes heights): the terrain is one geom,
in geom group `group`, which a `HeightScan` selects. MJX collides a height
field with spheres, capsules, boxes and meshes through the grid cells
around each of them, so a robot's feet cost the same on any kind.

`horizontal_scale`, the grid's spacing, sets how sharp an edge is: a riser
becomes a slope one cell wide. MJX collides a geom with a sub-grid of
`ceil(2 * r / horizontal_scale) + 1` cells a side around it (`r` its
bounding radius), two prisms a cell: the default 0.05 m is the finest
spacing at which a Go1 foot (a 0.023 m sphere) meets 2 x 2 cells, the
fewest there are; a humanoid's foot capsules (0.134 m bounding radius)
meet 7 x 7 there and 4 x 4 at 0.1 m (`TerrainWalk`'s choice).

The layout is generated once, on the host, from `seed`; every world has the
same terrain and a per-world terrain level (`curriculum.TerrainCurriculum`)
says where it spawns: `spawn_points` holds each tile's spawn point, the
centre of its flat platform.
"""

import mujoco
import numpy as np

from mjx_composer.suite.locomotion.terrain import sub_terrains
from mjx_composer.suite.locomotion.terrain import surface
from mjx_composer.utils import validation

_OWNER = 'TerrainGenerator'


class TerrainGenerator(surface.HeightFieldArena):
  """A grid of sub-terrains of increasing difficulty (module docstring).

  Args:
    kinds: the sub-terrain kinds, one column each (`sub_terrains.KINDS`).
    levels: the number of difficulty levels (rows).
    tile_size: the side of a (square) tile, metres; a multiple of
      `horizontal_scale`.
    horizontal_scale: the height field's grid spacing, metres (module
      docstring).
    border: the width of the flat border around the grid, metres; a
      multiple of `horizontal_scale`.
    difficulty_range: (at level 0, at the last level), in [0, 1].
    config: a `sub_terrains.SubTerrainConfig` (each kind's parameters).
    group: the geom group of the terrain's geoms.
    seed: the seed of the random sub-terrains.
    name: the arena's name.
  """

  def _build(
      self,
      kinds=sub_terrains.KINDS,
      levels=5,
      tile_size=4.0,
      horizontal_scale=0.05,
      border=1.0,
      difficulty_range=(0.0, 1.0),
      config=None,
      group=0,
      seed=0,
      name='terrain',
  ):
    if not isinstance(name, str) or not name:
      raise TypeError(
          f'{_OWNER}: name must be a non-empty string, got {name!r}.'
      )
    super()._build(name=name)
    if isinstance(kinds, (str, bytes)) or not hasattr(kinds, '__iter__'):
      raise TypeError(
          f'{_OWNER}: kinds must be a sequence of sub-terrain kinds, got '
          f"{kinds!r}. Pass e.g. ('flat', 'pyramid_stairs')."
      )
    kinds = tuple(kinds)
    unknown = [k for k in kinds if k not in sub_terrains.KINDS]
    if not kinds or unknown:
      raise ValueError(
          f'{_OWNER}: kinds must be a non-empty sequence of '
          f'{sub_terrains.KINDS}, got unknown {unknown or kinds!r}.'
      )
    self._kinds = kinds
    self._levels = validation.check_integer(
        'levels', levels, owner=_OWNER, minimum=1
    )
    scale = validation.check_positive(
        'horizontal_scale', horizontal_scale, owner=_OWNER
    )
    self._tile = validation.check_positive('tile_size', tile_size, owner=_OWNER)
    border = validation.check_nonnegative('border', border, owner=_OWNER)
    for arg, value in (('tile_size', self._tile), ('border', border)):
      cells = value / scale
      if abs(cells - round(cells)) > 1e-6 or (arg == 'tile_size' and cells < 2):
        raise ValueError(
            f'{_OWNER}: {arg}={value} must be a multiple of horizontal_scale='
            f'{scale} (and a tile at least 2 cells): pass e.g. '
            f'{arg}={round(cells) * scale or 2 * scale}.'
        )
    self._difficulty_range = validation.check_range_pair(
        'difficulty_range', difficulty_range, owner=_OWNER, nonnegative=True
    )
    if self._difficulty_range[1] > 1.0:
      raise ValueError(
          f'{_OWNER}: difficulty_range must lie in [0, 1], got '
          f'{difficulty_range!r}.'
      )
    self._config = sub_terrains.SubTerrainConfig() if config is None else config
    if not isinstance(self._config, sub_terrains.SubTerrainConfig):
      raise TypeError(
          f'{_OWNER}: config must be a sub_terrains.SubTerrainConfig, got '
          f'{config!r}. Pass e.g. SubTerrainConfig(platform=1.5) or None.'
      )
    self._group = validation.check_integer(
        'group', group, owner=_OWNER, minimum=0
    )
    seed = validation.check_integer('seed', seed, owner=_OWNER, minimum=0)
    self._scale, self._border = scale, border
    self._generate(np.random.default_rng(seed))

  # -- generation (host) -----------------------------------------------------

  def difficulty(self, level):
    """The difficulty of `level` (a host number)."""
    low, high = self._difficulty_range
    if self._levels == 1:
      return high
    return low + (high - low) * level / (self._levels - 1)

  def tile_centre(self, level, kind):
    """The (x, y) centre of tile `(level, kind)`."""
    return np.array(
        [
            (level - (self._levels - 1) / 2) * self._tile,
            (kind - (len(self._kinds) - 1) / 2) * self._tile,
        ]
    )

  def _generate(self, rng):
    scale, tile = self._scale, self._tile
    half_extent = np.array(
        [
            self._levels * tile / 2 + self._border,
            len(self._kinds) * tile / 2 + self._border,
        ]
    )
    ncol, nrow = (np.round(2 * half_extent / scale).astype(int) + 1).tolist()
    heights = np.zeros((nrow, ncol))
    tile_cells = int(round(tile / scale))
    local = np.linspace(-tile / 2, tile / 2, tile_cells + 1)
    spawns = np.zeros((self._levels, len(self._kinds), 3))
    for level in range(self._levels):
      for index, kind in enumerate(self._kinds):
        centre = self.tile_centre(level, index)
        tile_heights, spawn = sub_terrains.tile(
            kind, self.difficulty(level), local, local, rng, self._config
        )
        col = int(round((centre[0] - tile / 2 + half_extent[0]) / scale))
        row = int(round((centre[1] - tile / 2 + half_extent[1]) / scale))
        heights[row : row + tile_cells + 1, col : col + tile_cells + 1] = (
            tile_heights
        )
        spawns[level, index] = [*centre, spawn]
    self._heights = heights
    self._spawn_points = spawns
    low, high = heights.min(), heights.max()
    span = max(high - low, 1e-3)
    self._field = surface.HeightField(
        self.mjcf_model,
        half_extent=half_extent,
        shape=heights.shape,
        span=span,
        base=1.0,
        elevation=(heights - low) / span,
        z=low,
        group=self._group,
        texrepeat=[2, 2],  # A 0.5 m checker.
    )

  # -- what tasks read -------------------------------------------------------

  @property
  def kinds(self):
    return self._kinds

  @property
  def levels(self):
    return self._levels

  @property
  def tile_size(self):
    return self._tile

  @property
  def half_extent(self):
    """(x, y) half-sizes of the whole terrain, border included, metres
    (it is centred on the world's origin)."""
    return self._field.half_extent

  @property
  def group(self):
    """The geom group of the terrain's geoms (for a `HeightScan`)."""
    return self._group

  @property
  def geomgroup(self):
    """MuJoCo's group mask selecting the terrain's geoms only."""
    mask = [0] * mujoco.mjNGROUP
    mask[min(self._group, mujoco.mjNGROUP - 1)] = 1
    return tuple(mask)

  @property
  def spawn_points(self):
    """(levels, kinds, 3): each tile's spawn point (its platform's centre)."""
    return self._spawn_points.copy()

  @property
  def heights(self):
    """(rows, cols) the height field's surface heights, metres (host)."""
    return self._heights.copy()

  @property
  def horizontal_scale(self):
    """The height field's grid spacing, metres."""
    return self._scale

  def regenerate(self, random_state=None):
    """Composer's build-time regeneration: the layout is fixed by `seed`."""
    del random_state

  def regenerate_world(self, physics, key):
    """Every world shares the generated terrain: nothing to sample."""
    del key
    return physics
