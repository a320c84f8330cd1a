"""TerrainGenerator: an arena of sub-terrains in a grid of levels x kinds.

Isaac Lab's and mjlab's terrain generator as a composer `Arena`: tile
`(level, kind)` is the sub-terrain `kinds[kind]` (`sub_terrains.KINDS`) at
the difficulty of `level` (`difficulty_range[0]` at level 0 rising linearly
to `difficulty_range[1]` at the last level). Levels run along x, kinds
along y. The height-field kinds share one MuJoCo height field covering the
whole grid (flat under the box tiles and the border); the box kinds' boxes
are static geoms of the world body. MJX collides height fields and boxes
with spheres, capsules, boxes and meshes (the feet and limbs of the bundled
robots); every terrain geom is in geom group `group`, which a `HeightScan`
selects.

The layout is generated once, on the host, from `seed`; every world has the
same terrain and a per-world terrain level (`curriculum.TerrainCurriculum`)
says where it spawns: `spawn_points` holds each tile's spawn point, the
centre of its flat platform.
"""

import mujoco
import numpy as np

from mjx_composer import arena
from mjx_composer.locomotion import sub_terrains
from mjx_composer.utils import validation

_OWNER = 'TerrainGenerator'


class TerrainGenerator(arena.Arena):
  """A grid of sub-terrains of increasing difficulty (module docstring).

  Args:
    kinds: the sub-terrain kinds, one column each (`sub_terrains.KINDS`).
    levels: the number of difficulty levels (rows).
    tile_size: the side of a (square) tile, metres; a multiple of
      `horizontal_scale`.
    horizontal_scale: the height field's grid spacing, metres.
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
      horizontal_scale=0.1,
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
    xs = np.linspace(-half_extent[0], half_extent[0], ncol)
    ys = np.linspace(-half_extent[1], half_extent[1], nrow)
    heights = np.zeros((nrow, ncol))
    tile_cells = int(round(tile / scale))
    local = np.linspace(-tile / 2, tile / 2, tile_cells + 1)
    boxes, spawns = [], np.zeros((self._levels, len(self._kinds), 3))
    for level in range(self._levels):
      for index, kind in enumerate(self._kinds):
        centre = self.tile_centre(level, index)
        difficulty = self.difficulty(level)
        if kind in sub_terrains.HFIELD_KINDS:
          tile_heights = sub_terrains.height_field(
              kind, difficulty, local, local, rng, self._config
          )
          col = int(round((centre[0] - tile / 2 + half_extent[0]) / scale))
          row = int(round((centre[1] - tile / 2 + half_extent[1]) / scale))
          heights[row : row + tile_cells + 1, col : col + tile_cells + 1] = (
              tile_heights
          )
          spawn = tile_heights[tile_cells // 2, tile_cells // 2]
        else:
          tile_boxes, spawn = sub_terrains.boxes(
              kind, difficulty, tile / 2, rng, self._config
          )
          tile_boxes[:, :2] += centre
          boxes.append(tile_boxes)
        spawns[level, index] = [*centre, spawn]
    self._heights = heights
    self._hfield_half = half_extent
    self._spawn_points = spawns
    self._boxes = np.concatenate(boxes) if boxes else np.zeros((0, 6))
    self._add_geoms(heights, half_extent)

  def _add_geoms(self, heights, half_extent):
    spec = self.mjcf_model
    spec.add_texture(
        name='grid',
        type=mujoco.mjtTexture.mjTEXTURE_2D,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
        width=256,
        height=256,
        rgb1=[0.25, 0.3, 0.35],
        rgb2=[0.15, 0.2, 0.25],
    )
    spec.add_material(
        name='grid',
        textures=['', 'grid'] + [''] * 8,
        texrepeat=[1 / self._scale / 5] * 2,
        texuniform=True,
    )
    spec.add_material(name='box', rgba=[0.45, 0.5, 0.55, 1.0])
    spec.worldbody.add_light(
        name='top',
        pos=[0, 0, 4],
        dir=[0, 0, -1],
        type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
    )
    low, high = heights.min(), heights.max()
    # MuJoCo normalizes the elevations to [0, 1] and scales them by
    # size[2]: heights spanning [low, high] need size[2] = high - low and
    # the geom `low` lower.
    span = max(high - low, 1e-3)
    nrow, ncol = heights.shape
    self._hfield = spec.add_hfield(
        name='terrain',
        size=[half_extent[0], half_extent[1], span, 1.0],
        nrow=nrow,
        ncol=ncol,
        userdata=np.ravel((heights - low) / span).tolist(),
    )
    self._ground = spec.worldbody.add_geom(
        name='ground',
        type=mujoco.mjtGeom.mjGEOM_HFIELD,
        hfieldname='terrain',
        pos=[0, 0, low],
        material='grid',
        group=self._group,
    )
    self._box_geoms = tuple(
        spec.worldbody.add_geom(
            name=f'box_{i}',
            type=mujoco.mjtGeom.mjGEOM_BOX,
            pos=box[:3],
            size=box[3:],
            material='box',
            group=self._group,
        )
        for i, box in enumerate(self._boxes)
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
    return self._hfield_half.copy()

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
  def boxes(self):
    """(n, 6) the boxes' centres and half-sizes (host)."""
    return self._boxes.copy()

  @property
  def ground_geoms(self):
    return (self._ground,) + self._box_geoms

  def regenerate(self, random_state=None):
    """Composer's build-time regeneration: the layout is fixed by `seed`."""
    del random_state

  def regenerate_world(self, physics, key):
    """Every world shares the generated terrain: nothing to sample."""
    del key
    return physics
