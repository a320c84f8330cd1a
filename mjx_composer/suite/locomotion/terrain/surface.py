"""The height-field ground that the terrain arenas share: built, then read.

`HeightField` adds one MuJoCo height field and its geom to an arena's spec
(with the checkered look of the bundled arenas) and answers, on the device,
what the ground is at a point: the surface heights of a world (its own
`hfield_data`, so a per-world profile is read as it is), the height below a
point as MuJoCo's collision and `mj_ray` see it, and the highest point near
one. `RoughTerrain` (a profile per world) and `TerrainGenerator` (a grid of
sub-terrains) are both a `HeightFieldArena`, an arena whose ground is one
`HeightField`; the locomotion tasks ask them where the ground is below a
robot.

MuJoCo stores elevations normalized to [0, 1] and scales them by the height
field's `size[2]`; a surface spanning [low, high] is a field of size
`high - low` whose geom sits at `z = low`.
"""

import jax.numpy as jnp
import mujoco
import numpy as np

from mjx_composer import arena
from mjx_composer.model import element_index
from mjx_composer.suite.entities import arenas


def surface_height(heights, half_size, xy):
  """The surface height of a height field at local `xy` (2,).

  Args:
    heights: (nrow, ncol) surface heights in the geom's frame (rows along
      y, columns along x).
    half_size: (x, y) half-extent of the grid.
    xy: a point in the geom's frame.

  Returns:
    `(height, inside)`: the height of the triangle above `xy` (cells split
    along the diagonal from corner (row, col) to (row + 1, col + 1), as
    MuJoCo's collision and `mj_ray` split them; outside the grid, the
    nearest edge's) and whether `xy` lies over the grid.
  """
  nrow, ncol = heights.shape
  col = (xy[0] + half_size[0]) / (2 * half_size[0]) * (ncol - 1)
  row = (xy[1] + half_size[1]) / (2 * half_size[1]) * (nrow - 1)
  inside = (
      (col >= 0.0) & (col <= ncol - 1.0) & (row >= 0.0) & (row <= nrow - 1.0)
  )
  col = jnp.clip(col, 0.0, ncol - 1.0)
  row = jnp.clip(row, 0.0, nrow - 1.0)
  c0 = jnp.clip(jnp.floor(col).astype(jnp.int32), 0, ncol - 2)
  r0 = jnp.clip(jnp.floor(row).astype(jnp.int32), 0, nrow - 2)
  fc, fr = col - c0, row - r0
  h00, h01 = heights[r0, c0], heights[r0 + 1, c0]
  h10, h11 = heights[r0, c0 + 1], heights[r0 + 1, c0 + 1]
  upper = h00 + fc * (h11 - h01) + fr * (h01 - h00)  # fr >= fc
  lower = h00 + fc * (h10 - h00) + fr * (h11 - h10)  # fc >= fr
  return jnp.where(fr >= fc, upper, lower), inside


class HeightField:
  """One height-field ground geom in an arena's spec (module docstring).

  Args:
    spec: the arena's `MjSpec`.
    half_extent: (x, y) half-sizes of the grid, metres (centred on the
      arena's origin).
    shape: (rows, columns) of the grid (rows along y).
    span: the field's `size[2]`: metres between elevation 0 and 1.
    base: the thickness of the solid below elevation 0 (`size[3]`).
    elevation: (rows, columns) normalized elevations in [0, 1], or None
      (set later through `set_elevation`).
    z: the height of elevation 0 (the geom's z).
    group: the geom's group.
    rgb: the checker's two colours.
    texrepeat: the material's texture repeat.
    texuniform: whether the texture repeats per metre.
  """

  def __init__(
      self,
      spec,
      *,
      half_extent,
      shape,
      span,
      base,
      elevation=None,
      z=0.0,
      group=0,
      rgb=((0.25, 0.3, 0.35), (0.15, 0.2, 0.25)),
      texrepeat=(8, 8),
      texuniform=True,
  ):
    self._half = np.asarray(half_extent, float)
    self._shape = tuple(int(n) for n in shape)
    self._span = float(span)
    arenas.add_grid_and_light(
        spec,
        rgb1=list(rgb[0]),
        rgb2=list(rgb[1]),
        texrepeat=list(texrepeat),
        texuniform=texuniform,
    )
    rows, cols = self._shape
    self.hfield = spec.add_hfield(
        name='terrain',
        size=[self._half[0], self._half[1], self._span, float(base)],
        nrow=rows,
        ncol=cols,
    )
    if elevation is not None:
      self.set_elevation(elevation)
    self.geom = spec.worldbody.add_geom(
        name='ground',
        type=mujoco.mjtGeom.mjGEOM_HFIELD,
        hfieldname='terrain',
        pos=[0.0, 0.0, float(z)],
        material='grid',
        group=group,
    )

  def set_elevation(self, elevation):
    """Sets the compiled elevations (rows, columns), in [0, 1] (host)."""
    # Row-major, rows along y: MuJoCo's elevation layout.
    self.hfield.userdata = np.ravel(elevation).tolist()

  @property
  def shape(self):
    return self._shape

  @property
  def half_extent(self):
    return self._half.copy()

  @property
  def span(self):
    return self._span

  def grid(self):
    """The grid's (x, y) coordinates in the geom's frame: `(xs, ys)`."""
    rows, cols = self._shape
    xs = np.linspace(-self._half[0], self._half[0], cols)
    ys = np.linspace(-self._half[1], self._half[1], rows)
    return xs, ys

  # -- reads (device) --------------------------------------------------------

  def data_range(self, physics):
    """`(start, count)` of this field's elevations in `hfield_data`."""
    model = physics.mj_model
    geom = physics.index.element_id(
        element_index.KINDS_BY_NAME['geom'], self.geom
    )
    hfield = model.geom_dataid[geom]
    return int(model.hfield_adr[hfield]), self._shape[0] * self._shape[1]

  def _elevations(self, physics):
    """`(elevations (rows, cols), z)`: this world's normalized elevations
    and the height of elevation 0; heights are `z + span * elevation`.
    Reads interpolate elevations and scale the result, not the grid."""
    start, count = self.data_range(physics)
    data = physics.model.hfield_data[start : start + count]
    return data.reshape(self._shape), physics.bind(self.geom).pos[2]

  def heights(self, physics):
    """This world's surface heights (rows, cols) in metres, rows along y."""
    elevations, z = self._elevations(physics)
    return z + self._span * elevations

  def height_at(self, physics, xy):
    """The surface height below world `xy` (2,), as MuJoCo's collision
    sees it (outside the grid: the nearest edge's)."""
    elevations, z = self._elevations(physics)
    xy = jnp.asarray(xy, jnp.float32)
    return z + self._span * surface_height(elevations, self._half, xy)[0]

  def max_height_near(self, physics, xy, radius):
    """The highest grid point within `radius` of `xy`, or `height_at`."""
    xs, ys = self.grid()
    xy = jnp.asarray(xy, jnp.float32)
    near = (xs[None, :] - xy[0]) ** 2 + (ys[:, None] - xy[1]) ** 2 <= (
        radius**2
    )
    elevations, z = self._elevations(physics)
    highest = z + self._span * jnp.max(jnp.where(near, elevations, -jnp.inf))
    return jnp.maximum(highest, self.height_at(physics, xy))


class HeightFieldArena(arena.Arena):
  """An arena whose ground is one `HeightField` (`self._field`, set by the
  subclass's `_build`)."""

  _field: HeightField

  @property
  def ground_geoms(self):
    return (self._field.geom,)

  @property
  def ground(self):
    """The `HeightField` (where the ground is, on the device)."""
    return self._field

  def height_at(self, physics, xy):
    """The ground's height below world `xy` (2,), as MuJoCo's collision
    sees it (device; outside the grid, the nearest edge's)."""
    return self._field.height_at(physics, xy)
