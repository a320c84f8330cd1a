"""Sub-terrains: one tile of a generated terrain, at a difficulty in [0, 1].

The kinds of Isaac Lab's and mjlab's terrain generators, computed on the
host with NumPy when the terrain is built, every one of them as surface
heights on the height field's grid (as Isaac Gym's legged_gym writes its
stairs, stones and beams into one height field): MJX collides a height field
with a robot's feet through a few grid cells around each foot, while every
box geom would be one more candidate contact pair at every physics step.
A tile is 0 on its boundary, where it meets its neighbours. Every tile has a
flat spawn platform of side `platform` at its centre, whose height is the
tile's spawn height. Each parameter that makes a kind harder grows linearly
with the difficulty, from its `*_range[0]` at difficulty 0 to `*_range[1]`
at 1 (`SubTerrainConfig`).

Smooth kinds (`SMOOTH_KINDS`), heights computed per grid point:

* 'flat': no relief (the difficulty does nothing);
* 'random_uniform': each grid point's height drawn from U(0, noise);
* 'pyramid_slope': rising towards the centre with slope `slope`;
* 'inverted_pyramid_slope': falling towards the centre (a bowl);
* 'waves': `wave_amplitude / 2 * (sin(2 pi n x / L) + sin(2 pi n y / L))`,
  `n = waves` periods across the tile;
* 'discrete_obstacles': `obstacles` rectangles of sides in
  `obstacle_width`, each raised or sunk by `obstacle_height`.

Block kinds (`BLOCK_KINDS`), described as axis-aligned boxes standing on
the ground (`blocks`) and written into the grid by `rasterize`:

* 'pyramid_stairs': steps of height `step_height` and depth `step_width`
  down from the central platform to the tile's edge (the platform, at
  least `platform` wide, takes the width the steps leave);
* 'inverted_pyramid_stairs': the same steps up from the platform (a pit);
* 'stepping_stones': square stones of side `stone_size`, `stone_gap`
  apart, `stone_height` tall, over a ground `stone_height` below;
* 'narrow_beams': four beams of width `beam_width`, `stone_height` tall,
  from the platform to the edges;
* 'random_grid': a grid of `grid_cell` wide boxes of heights drawn from
  U(0, `grid_height`) around the platform.

How a block becomes heights: its footprint's edges are moved to the nearest
grid lines (widths and gaps become whole numbers of cells, at least one;
positions move by at most half a cell), and every grid point on or inside a
footprint takes the block's top. So every tread, stone and beam keeps its
whole top surface, flat to its edge, and each vertical face becomes a slope
one grid cell wide on its lower side: a foot resting on a top is where it
would be on the box, and the foot of a riser moves out by one cell. A gap
of one cell between blocks closes (no grid point lies in it). The blocks
returned are the snapped ones, so a model built from them as box geoms is
the box version of the same tile
(`tests/suite/locomotion/terrain/test_generator.py` compares the two in
MuJoCo C).
"""

import dataclasses

import numpy as np

from mjx_composer.utils import validation

SMOOTH_KINDS = (
    'flat',
    'random_uniform',
    'pyramid_slope',
    'inverted_pyramid_slope',
    'waves',
    'discrete_obstacles',
)
BLOCK_KINDS = (
    'pyramid_stairs',
    'inverted_pyramid_stairs',
    'stepping_stones',
    'narrow_beams',
    'random_grid',
)
KINDS = SMOOTH_KINDS + BLOCK_KINDS
_OWNER = 'SubTerrainConfig'
# Each length's lower bound: 'positive' (a box or a step of size 0 cannot be
# built) or 'nonnegative' (0 turns the feature off).
_LENGTHS = {
    'platform': 'positive',
    'step_width': 'positive',
    'stone_height': 'positive',
    'grid_cell': 'positive',
}
_ENDPOINTS = {
    'noise_range': 'nonnegative',
    'slope_range': 'nonnegative',
    'wave_amplitude_range': 'nonnegative',
    'obstacle_height_range': 'nonnegative',
    'step_height_range': 'positive',
    'stone_size_range': 'positive',
    'stone_gap_range': 'nonnegative',
    'beam_width_range': 'positive',
    'grid_height_range': 'nonnegative',
}
_COUNTS = ('waves', 'obstacles')
_CHECKS = {
    'positive': validation.check_positive,
    'nonnegative': validation.check_nonnegative,
}


def _check_endpoints(name, value, bound):
  """`value` must be two numbers (at difficulty 0, at 1), either order."""
  if isinstance(value, (str, bytes)) or np.ndim(value) != 1 or len(value) != 2:
    raise TypeError(
        f'{_OWNER}: {name} must be a pair (at difficulty 0, at difficulty 1)'
        f' of numbers, got {value!r}. Pass e.g. (0.05, 0.2).'
    )
  for i, endpoint in enumerate(value):
    _CHECKS[bound](f'{name}[{i}]', endpoint, owner=_OWNER)


@dataclasses.dataclass(frozen=True)
class SubTerrainConfig:
  """The sub-terrains' parameters: `(at difficulty 0, at difficulty 1)`.

  Lengths in metres; `slope` is rise over run.
  """

  platform: float = 1.0
  noise_range: tuple = (0.02, 0.10)
  slope_range: tuple = (0.0, 0.4)
  wave_amplitude_range: tuple = (0.0, 0.2)
  waves: int = 2
  obstacles: int = 12
  obstacle_width: tuple = (0.25, 0.6)
  obstacle_height_range: tuple = (0.03, 0.15)
  step_height_range: tuple = (0.03, 0.18)
  step_width: float = 0.3
  stone_size_range: tuple = (0.5, 0.25)
  stone_gap_range: tuple = (0.05, 0.25)
  stone_height: float = 0.2
  beam_width_range: tuple = (0.4, 0.15)
  grid_cell: float = 0.4
  grid_height_range: tuple = (0.02, 0.12)

  def __post_init__(self):
    """Refuses a bad parameter here rather than when a terrain is built."""
    for name, bound in _LENGTHS.items():
      _CHECKS[bound](name, getattr(self, name), owner=_OWNER)
    for name, bound in _ENDPOINTS.items():
      _check_endpoints(name, getattr(self, name), bound)
    for name in _COUNTS:
      validation.check_integer(
          name, getattr(self, name), owner=_OWNER, minimum=0
      )
    validation.check_range_pair(
        'obstacle_width', self.obstacle_width, owner=_OWNER, positive=True
    )

  def at(self, name, difficulty):
    """Parameter `<name>_range` at `difficulty` (linear)."""
    low, high = getattr(self, f'{name}_range')
    return low + (high - low) * float(difficulty)


def _platform_mask(xs, ys, platform):
  return (np.abs(xs)[None, :] <= platform / 2) & (
      np.abs(ys)[:, None] <= platform / 2
  )


def smooth_heights(kind, difficulty, xs, ys, rng, config):
  """The (len(ys), len(xs)) heights of a smooth kind at `xs`, `ys`.

  Args:
    kind: one of `SMOOTH_KINDS`.
    difficulty: in [0, 1].
    xs, ys: the grid's coordinates in the tile's frame (centre at 0), from
      -length / 2 to length / 2.
    rng: a `numpy.random.Generator`.
    config: a `SubTerrainConfig`.
  """
  half_x, half_y = xs[-1], ys[-1]
  x, y = np.meshgrid(xs, ys, indexing='xy')
  if kind == 'flat':
    heights = np.zeros_like(x)
  elif kind == 'random_uniform':
    heights = rng.uniform(0.0, config.at('noise', difficulty), x.shape)
  elif kind in ('pyramid_slope', 'inverted_pyramid_slope'):
    # Distance from the edge, measured along the nearer axis.
    # Flat on top: the platform is as high as its edge.
    to_edge = np.minimum(half_x - np.abs(x), half_y - np.abs(y))
    to_edge = np.minimum(to_edge, min(half_x, half_y) - config.platform / 2)
    heights = config.at('slope', difficulty) * to_edge
    if kind == 'inverted_pyramid_slope':
      heights = -heights
  elif kind == 'waves':
    amplitude = config.at('wave_amplitude', difficulty)
    n = config.waves
    heights = (
        amplitude
        / 2
        * (
            np.sin(2 * np.pi * n * (x + half_x) / (2 * half_x))
            + np.sin(2 * np.pi * n * (y + half_y) / (2 * half_y))
        )
    )
  elif kind == 'discrete_obstacles':
    heights = np.zeros_like(x)
    height = config.at('obstacle_height', difficulty)
    for _ in range(config.obstacles):
      width = rng.uniform(*config.obstacle_width, size=2)
      centre = rng.uniform([-half_x, -half_y], [half_x, half_y])
      inside = (np.abs(x - centre[0]) <= width[0] / 2) & (
          np.abs(y - centre[1]) <= width[1] / 2
      )
      heights[inside] = rng.choice([-height, height])
  else:
    raise ValueError(f'Unknown smooth kind {kind!r}: one of {SMOOTH_KINDS}.')
  platform = _platform_mask(xs, ys, config.platform)
  centre = heights[len(ys) // 2, len(xs) // 2]
  if kind in ('random_uniform', 'discrete_obstacles', 'waves'):
    centre = 0.0
  heights = np.where(platform, centre, heights)
  # Height 0 on the tile's boundary: neighbouring tiles meet there.
  heights[[0, -1], :] = 0.0
  heights[:, [0, -1]] = 0.0
  return heights


def tile(kind, difficulty, xs, ys, rng, config):
  """`(heights, spawn height)` of any kind on the grid `xs`, `ys`.

  Args:
    kind: one of `KINDS`.
    difficulty: in [0, 1].
    xs, ys: the tile's grid coordinates in the tile's frame (centre at 0),
      from -length / 2 to length / 2, evenly spaced by the same step.
    rng: a `numpy.random.Generator`.
    config: a `SubTerrainConfig`.

  Returns:
    `(heights (len(ys), len(xs)), spawn height)`: 0 on the tile's boundary;
    the spawn height is the platform's, at the tile's centre.
  """
  if kind in SMOOTH_KINDS:
    heights = smooth_heights(kind, difficulty, xs, ys, rng, config)
    return heights, float(heights[len(ys) // 2, len(xs) // 2])
  cell = round(float(xs[-1] - xs[0]) / (len(xs) - 1), 9)
  tile_blocks, spawn = blocks(kind, difficulty, xs[-1], rng, config, cell)
  heights = rasterize(tile_blocks, xs, ys)
  heights[[0, -1], :] = 0.0
  heights[:, [0, -1]] = 0.0
  return heights, spawn


def rasterize(tile_blocks, xs, ys):
  """Heights of boxes standing on the ground (0) at grid points `xs`, `ys`.

  A grid point takes the highest top among the blocks whose closed
  footprint contains it (within a thousandth of a cell), else 0.

  Args:
    tile_blocks: (n, 6) boxes: centre (x, y, z) and half-sizes; each
      box's top is `z + half_z`.
    xs, ys: the grid's coordinates.
  """
  tolerance = 1e-3 * float(xs[1] - xs[0])
  heights = np.zeros((len(ys), len(xs)))
  for x, y, z, hx, hy, hz in np.asarray(tile_blocks, float):
    inside_x = np.abs(xs - x) <= hx + tolerance
    inside_y = np.abs(ys - y) <= hy + tolerance
    footprint = inside_y[:, None] & inside_x[None, :]
    heights = np.where(footprint, np.maximum(heights, z + hz), heights)
  return heights


def _snap(low, high, half, cell):
  """`[low, high]` moved onto the grid lines `-half + k * cell`.

  The lower edge goes to the nearest line; the width becomes the nearest
  whole number of cells, at least one.
  """
  # Rounded first: a half-cell tie goes up whatever the float noise.
  start = np.floor(np.round((low + half) / cell, 6) + 0.5)
  cells = max(1.0, np.floor(np.round((high - low) / cell, 6) + 0.5))
  low = start * cell - half
  return low, low + cells * cell


def _box(centre, half):
  return np.concatenate([np.asarray(centre, float), np.asarray(half, float)])


def _block(x_range, y_range, top, half, cell):
  """A box from ground to `top` over the snapped footprint x_range, y_range."""
  x0, x1 = _snap(*x_range, half, cell) if cell else x_range
  y0, y1 = _snap(*y_range, half, cell) if cell else y_range
  return _box(
      [(x0 + x1) / 2, (y0 + y1) / 2, top / 2],
      [(x1 - x0) / 2, (y1 - y0) / 2, top / 2],
  )


def _square(centre_x, centre_y, half_side, top, half, cell):
  return _block(
      (centre_x - half_side, centre_x + half_side),
      (centre_y - half_side, centre_y + half_side),
      top,
      half,
      cell,
  )


def _ring(inner, outer, top, half, cell):
  """Four blocks covering the square ring between half-widths inner, outer."""
  return [
      _block((-outer, outer), (inner, outer), top, half, cell),
      _block((-outer, outer), (-outer, -inner), top, half, cell),
      _block((inner, outer), (-inner, inner), top, half, cell),
      _block((-outer, -inner), (-inner, inner), top, half, cell),
  ]


def blocks(kind, difficulty, half, rng, config, cell=None):
  """`(blocks (n, 6), spawn height)` of a block kind on a square tile.

  Args:
    kind: one of `BLOCK_KINDS`.
    difficulty: in [0, 1].
    half: the tile's half-side, metres.
    rng: a `numpy.random.Generator`.
    config: a `SubTerrainConfig`.
    cell: the grid's spacing: footprints are snapped to the grid lines
      `-half + k * cell` (module docstring); None: not snapped.

  Returns:
    The blocks (centre (x, y, z) and half-sizes, axis-aligned, standing on
    the ground at 0) and the height of the central platform's surface.
  """
  platform = config.platform / 2
  out = []
  if kind in ('pyramid_stairs', 'inverted_pyramid_stairs'):
    step = config.at('step_height', difficulty)
    n = int(np.floor((half - platform) / config.step_width + 1e-9))
    # Every step is `step_width` deep; the platform takes what remains.
    if kind == 'pyramid_stairs':
      # Nested blocks, the outermost lowest; block n is the platform.
      for k in range(n + 1):
        w = half - k * config.step_width
        out.append(_square(0, 0, w, (k + 1) * step, half, cell))
      spawn = (n + 1) * step
    else:
      # Rings around the platform, the innermost lowest.
      for k in range(1, n + 1):
        inner = half - (n - k + 1) * config.step_width
        out.extend(
            _ring(inner, inner + config.step_width, k * step, half, cell)
        )
      spawn = 0.0
  elif kind == 'stepping_stones':
    size = config.at('stone_size', difficulty)
    gap = config.at('stone_gap', difficulty)
    top = config.stone_height
    pitch = size + gap
    count = int(np.floor((2 * half + gap) / pitch + 1e-9))
    offsets = (np.arange(count) - (count - 1) / 2) * pitch
    for x in offsets:
      for y in offsets:
        if max(abs(x), abs(y)) - size / 2 < platform:
          continue  # Under the platform.
        out.append(_square(x, y, size / 2, top, half, cell))
    out.append(_square(0, 0, platform, top, half, cell))
    spawn = top
  elif kind == 'narrow_beams':
    width = config.at('beam_width', difficulty)
    top = config.stone_height
    out.append(_square(0, 0, platform, top, half, cell))
    for sign in (1, -1):
      along = tuple(sorted((sign * platform, sign * half)))
      across = (-width / 2, width / 2)
      out.append(_block(along, across, top, half, cell))
      out.append(_block(across, along, top, half, cell))
    spawn = top
  elif kind == 'random_grid':
    grid_cell = config.grid_cell
    height = config.at('grid_height', difficulty)
    count = int(np.floor(2 * half / grid_cell + 1e-9))
    offsets = (np.arange(count) - (count - 1) / 2) * grid_cell
    for x in offsets:
      for y in offsets:
        if max(abs(x), abs(y)) - grid_cell / 2 < platform:
          continue
        top = max(rng.uniform(0.0, height), 1e-3)
        out.append(_square(x, y, grid_cell / 2, top, half, cell))
    spawn = 0.0
  else:
    raise ValueError(f'Unknown block kind {kind!r}: one of {BLOCK_KINDS}.')
  return np.reshape(np.asarray(out, float), (-1, 6)), float(spawn)
