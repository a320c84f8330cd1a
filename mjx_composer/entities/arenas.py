"""Arenas: the root entities of bundled scenes.

`Floor` is locomotion's flat checkered floor; `WalledArena` adds four walls
around it; `RoughTerrain` is a height field whose profile each world samples.
Where a composer arena's `regenerate` changed the MJCF and needed a
recompile every episode, here `regenerate_world(physics, key)` writes the
equivalent per-world model fields instead (the arena's `initialize_episode`
calls it), so a world matches the model compiled with the sampled layout.
Composer's host-side `regenerate(random_state)` keeps its meaning: a build
time edit of the spec (a no-op for `Floor` and `WalledArena`).
"""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjx_composer import arena
from mjx_composer.model import element_index
from mjx_composer.variation import base as variation_base

_GROUNDPLANE_QUAD_SIZE = 0.25


class Floor(arena.Arena):
  """A flat, checkered floor with a light: composer's arena plus a ground.

  Args:
    size: (half-x, half-y) extent of the floor plane in metres (the plane
      collides as an infinite plane; its size is visual).
    reflectance: the floor material's reflectance.
    name: the arena's name.
    top_camera_distance: height of the top-down camera.
    top_camera_y_padding_factor: how much more than the floor's y extent the
      top camera's field of view covers.
  """

  def _build(
      self,
      size=(2.0, 2.0),
      reflectance=0.2,
      name='floor',
      top_camera_distance=10.0,
      top_camera_y_padding_factor=1.1,
  ):
    super()._build(name=name)
    self._size = tuple(float(s) for s in size)
    spec = self.mjcf_model
    _add_grid_and_light(
        spec,
        rgb1=[0.2, 0.3, 0.4],
        rgb2=[0.1, 0.2, 0.3],
        texrepeat=[4, 4],
        reflectance=reflectance,
    )
    self._ground = spec.worldbody.add_geom(
        name='ground',
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[self._size[0], self._size[1], _GROUNDPLANE_QUAD_SIZE],
        material='grid',
    )
    spec.worldbody.add_camera(
        name='overview', pos=[1.6, -1.6, 1.4], xyaxes=[1, 1, 0, -0.4, 0.4, 1]
    )
    # A field of view that always fits the floor, as locomotion's Floor.
    fovy = 2 * np.arctan2(
        top_camera_y_padding_factor * self._size[1], top_camera_distance
    )
    self._top_camera = spec.worldbody.add_camera(
        name='top_camera',
        pos=[0, 0, top_camera_distance],
        fovy=float(np.rad2deg(fovy)),
    )

  @property
  def ground_geoms(self):
    return (self._ground,)

  @property
  def size(self):
    return self._size

  @property
  def top_camera(self):
    return self._top_camera

  def regenerate(self, random_state=None):
    """Composer's build-time layout change: a flat floor has none."""
    del random_state

  def regenerate_world(self, physics, key):
    """This world's layout: a flat floor has nothing to sample."""
    del key
    return physics


class WalledArena(Floor):
  """A floor enclosed by four walls, optionally resized per world.

  The walls are planes facing inwards, as locomotion's corridors build
  theirs: MJX collides planes with every primitive cheaply, and nothing can
  tunnel through or climb over an (infinite) plane. `wall_height` is only
  what is rendered.

  Args:
    size: (half-x, half-y) of the floor inside the walls, in metres.
    wall_height: the rendered height of the walls, in metres.
    wall_rgba: the walls' colour.
    size_variation: optional `Variation` producing a (2,) interior half-size
      per world and episode (evaluated with `size` as initial value), e.g.
      `distributions.Uniform((0.4, 0.4), (0.6, 0.6))`. Composer would
      regenerate the MJCF and recompile; here the walls' and floor's
      `geom_pos`/`geom_size` become per-world model fields, equal to those of
      a model compiled with that size.
    name: the arena's name.
    **floor_kwargs: passed to `Floor` (reflectance, camera options).
  """

  def _build(
      self,
      size=(0.5, 0.5),
      wall_height=0.1,
      wall_rgba=(0.45, 0.45, 0.5, 1.0),
      size_variation=None,
      name='walled_arena',
      **floor_kwargs,
  ):
    super()._build(size=size, name=name, **floor_kwargs)
    self._wall_half_height = float(wall_height) / 2
    self._size_variation = size_variation
    positions, sizes = self._wall_layout(np.asarray(self._size))
    # Plane normals (their z axes) point into the arena.
    # Each plane's x axis runs along its wall and its y axis up.
    half = np.sqrt(0.5)
    quats = (
        [-0.5, -0.5, 0.5, 0.5],
        [0.5, 0.5, 0.5, 0.5],
        [half, half, 0.0, 0.0],
        [0.0, 0.0, half, half],
    )
    self._walls = tuple(
        self.mjcf_model.worldbody.add_geom(
            name=f'wall_{side}',
            type=mujoco.mjtGeom.mjGEOM_PLANE,
            pos=positions[i],
            size=sizes[i],
            quat=quats[i],
            rgba=wall_rgba,
        )
        for i, side in enumerate(('px', 'nx', 'py', 'ny'))
    )

  def _wall_layout(self, size):
    """Wall centres and plane sizes (4, 3) for an interior half-size (2,).

    Works on numpy and jax arrays alike.
    """
    xp = jnp if isinstance(size, jnp.ndarray) else np
    h = self._wall_half_height
    sx, sy = size[0], size[1]
    zero = sx * 0
    positions = xp.stack(
        [
            xp.stack([sx, zero, zero + h]),
            xp.stack([-sx, zero, zero + h]),
            xp.stack([zero, sy, zero + h]),
            xp.stack([zero, -sy, zero + h]),
        ]
    )
    quad = zero + _GROUNDPLANE_QUAD_SIZE
    sizes = xp.stack(
        [
            xp.stack([sy, zero + h, quad]),
            xp.stack([sy, zero + h, quad]),
            xp.stack([sx, zero + h, quad]),
            xp.stack([sx, zero + h, quad]),
        ]
    )
    return positions, sizes

  @property
  def walls(self):
    """The four wall geoms (+x, -x, +y, -y)."""
    return self._walls

  @property
  def size_variation(self):
    return self._size_variation

  def interior_size(self, physics):
    """This world's interior half-size (2,), from the +x/+y wall positions."""
    pos = physics.bind([self._walls[0], self._walls[2]]).pos
    return jnp.stack([pos[0, 0], pos[1, 1]])

  def regenerate_world(self, physics, key):
    """Samples this world's layout from `size_variation` (if any).

    Returns the physics with the walls moved and the walls and floor resized
    (planes collide as infinite planes, so only `geom_pos` changes what
    collides; the sizes are what would be rendered).
    """
    if self._size_variation is None:
      return physics
    nominal = jnp.asarray(self._size, jnp.float32)
    size = jnp.broadcast_to(
        jnp.asarray(
            variation_base.evaluate(
                self._size_variation,
                initial_value=nominal,
                current_value=nominal,
                key=key,
            ),
            jnp.float32,
        ),
        (2,),
    )
    positions, sizes = self._wall_layout(size)
    physics = physics.bind(list(self._walls)).set(pos=positions, size=sizes)
    ground = physics.bind(self._ground).size
    return physics.bind(self._ground).set(size=ground.at[:2].set(size))

  def initialize_episode(self, physics, key):
    return self.regenerate_world(physics, key)


class RoughTerrain(arena.Arena):
  """A height-field ground whose profile every world samples per episode.

  The profile is smooth bumps about `bump_spacing` apart plus a fraction
  `roughness` of cell-scale noise, normalized to [0, 1] as MuJoCo's compiler
  normalizes elevation data, so surface heights span [0, `max_height`] above
  the arena's origin. MJX reads a height field's elevations from the
  `mjx.Model` field `hfield_data` (its grid sizes are static), so a world can
  carry its own: `regenerate_world(physics, key)` (run by the arena's
  `initialize_episode` when `per_world`) samples a profile and writes this
  arena's slice of `hfield_data`, which makes that field per-world (one
  float32 per grid point per world: 16 KiB at the default 64 x 64). The
  world then equals the model compiled with that profile as the height
  field's `elevation`. The task's hooks run before the arena's: a task that
  places things on the terrain calls `regenerate_world` itself first, and
  builds the arena with `auto_regenerate=False`. Composer's `regenerate(random_state)` samples one
  profile on the host at build time instead, shared by every world (with
  `per_world=False`, the only one).

  MJX collides height fields with spheres, capsules, boxes and meshes (not
  with planes, cylinders or ellipsoids). Worlds extend `size` around the
  origin; beyond the edges there is no ground. Rendering draws the compiled
  profile, not a world's own.

  Args:
    size: (half-x, half-y) extent in metres.
    resolution: (rows, columns) of the elevation grid (y, x samples).
    max_height: the height of the highest point, in metres (MJCF's
      hfield `size[2]`).
    base: the thickness of the solid below height 0 (`size[3]`).
    bump_spacing: metres between the smooth bumps' control points.
    roughness: the weight of the per-cell noise against the bumps (0: only
      smooth bumps).
    per_world: sample a profile per world and episode (else every world has
      the compiled one).
    auto_regenerate: with `per_world`, whether the arena's own
      `initialize_episode` samples the profile (False: the task calls
      `regenerate_world`).
    name: the arena's name.
  """

  def _build(
      self,
      size=(8.0, 8.0),
      resolution=(64, 64),
      max_height=0.06,
      base=0.5,
      bump_spacing=1.0,
      roughness=0.25,
      per_world=True,
      auto_regenerate=True,
      name='rough_terrain',
  ):
    super()._build(name=name)
    self._size = tuple(float(s) for s in size)
    self._rows, self._cols = (int(r) for r in resolution)
    if self._rows < 2 or self._cols < 2:
      raise ValueError(f'resolution must be at least (2, 2), got {resolution}.')
    self._max_height = float(max_height)
    self._roughness = float(roughness)
    self._per_world = bool(per_world)
    self._auto_regenerate = bool(auto_regenerate)
    # Bilinear upsampling from the bumps' control grid, as two matrices.
    coarse = [
        max(2, int(np.ceil(2 * s / bump_spacing)) + 1) for s in self._size
    ]
    self._coarse_shape = (coarse[1], coarse[0])
    self._upsample_rows = _linear_upsampling(coarse[1], self._rows)
    self._upsample_cols = _linear_upsampling(coarse[0], self._cols)
    spec = self.mjcf_model
    self._hfield = spec.add_hfield(
        name='terrain',
        size=[self._size[0], self._size[1], self._max_height, float(base)],
        nrow=self._rows,
        ncol=self._cols,
    )
    self.regenerate(np.random.RandomState(0))
    _add_grid_and_light(
        spec,
        rgb1=[0.25, 0.3, 0.35],
        rgb2=[0.15, 0.2, 0.25],
        texrepeat=[8, 8],
        texuniform=True,
    )
    self._ground = spec.worldbody.add_geom(
        name='ground',
        type=mujoco.mjtGeom.mjGEOM_HFIELD,
        hfieldname='terrain',
        material='grid',
    )
    spec.worldbody.add_camera(
        name='overview', pos=[1.6, -1.6, 1.4], xyaxes=[1, 1, 0, -0.4, 0.4, 1]
    )

  @property
  def ground_geoms(self):
    return (self._ground,)

  @property
  def size(self):
    return self._size

  @property
  def resolution(self):
    return (self._rows, self._cols)

  @property
  def max_height(self):
    return self._max_height

  @property
  def per_world(self):
    return self._per_world

  # -- profiles --------------------------------------------------------------

  def profile(self, bumps, noise):
    """The normalized elevation grid (rows, cols) from uniform draws.

    Works on numpy and jax arrays alike.

    Args:
      bumps: the control grid's heights, shape `(rows, cols)` of the bumps'
        grid (`coarse_shape`), in [0, 1).
      noise: per-cell noise of shape `resolution`, in [0, 1).
    """
    xp = jnp if isinstance(bumps, jnp.ndarray) else np
    smooth = self._upsample_rows @ bumps @ self._upsample_cols.T
    heights = smooth + self._roughness * noise
    low, high = xp.min(heights), xp.max(heights)
    return (heights - low) / xp.maximum(high - low, 1e-6)

  @property
  def coarse_shape(self):
    """The shape of the bumps' control grid that `profile` takes."""
    return self._coarse_shape

  def sample_profile(self, key):
    """A random profile (rows, cols) in [0, 1], from a JAX key."""
    bump_key, noise_key = jax.random.split(key)
    return self.profile(
        jax.random.uniform(bump_key, self._coarse_shape),
        jax.random.uniform(noise_key, (self._rows, self._cols)),
    )

  def regenerate(self, random_state=None):
    """Composer's build-time regeneration: a new compiled profile."""
    random_state = random_state or np.random
    heights = self.profile(
        random_state.uniform(size=self._coarse_shape),
        random_state.uniform(size=(self._rows, self._cols)),
    )
    # Row-major, rows along y: MuJoCo's elevation layout.
    self._hfield.userdata = np.ravel(heights).tolist()

  def regenerate_world(self, physics, key):
    """Writes a freshly sampled profile into this world's `hfield_data`.

    Does nothing unless `per_world`.
    """
    if not self._per_world:
      return physics
    start, count = self._data_range(physics)
    data = physics.model.hfield_data
    heights = jnp.ravel(self.sample_profile(key)).astype(data.dtype)
    return physics.replace(
        model=physics.model.replace(
            hfield_data=data.at[start : start + count].set(heights)
        )
    )

  def initialize_episode(self, physics, key):
    if not (self._per_world and self._auto_regenerate):
      return physics
    return self.regenerate_world(physics, key)

  # -- queries (device) -----------------------------------------------------

  def _data_range(self, physics):
    model = physics.mj_model
    hfield = model.geom_dataid[
        physics.index.element_id(
            element_index.KINDS_BY_NAME['geom'], self._ground
        )
    ]
    return int(model.hfield_adr[hfield]), self._rows * self._cols

  def heights(self, physics):
    """This world's surface heights (rows, cols) in metres, rows along y."""
    start, count = self._data_range(physics)
    data = physics.model.hfield_data[start : start + count]
    base_z = physics.bind(self._ground).pos[2]
    return base_z + self._max_height * data.reshape(self._rows, self._cols)

  def _grid(self):
    xs = np.linspace(-self._size[0], self._size[0], self._cols)
    ys = np.linspace(-self._size[1], self._size[1], self._rows)
    return xs, ys

  def height_at(self, physics, xy):
    """The surface height below `xy` (2,), as MuJoCo's collision sees it.

    Each grid cell is two triangles split along the diagonal from its
    (row, col) corner to its (row + 1, col + 1) one; outside the grid, the
    nearest edge's height.
    """
    heights = self.heights(physics)
    xy = jnp.asarray(xy, jnp.float32)
    col = (xy[0] + self._size[0]) / (2 * self._size[0]) * (self._cols - 1)
    row = (xy[1] + self._size[1]) / (2 * self._size[1]) * (self._rows - 1)
    col = jnp.clip(col, 0.0, self._cols - 1.0)
    row = jnp.clip(row, 0.0, self._rows - 1.0)
    c0 = jnp.clip(jnp.floor(col).astype(jnp.int32), 0, self._cols - 2)
    r0 = jnp.clip(jnp.floor(row).astype(jnp.int32), 0, self._rows - 2)
    fc, fr = col - c0, row - r0
    h00, h01 = heights[r0, c0], heights[r0 + 1, c0]
    h10, h11 = heights[r0, c0 + 1], heights[r0 + 1, c0 + 1]
    upper = h00 + fc * (h11 - h01) + fr * (h01 - h00)  # fr >= fc
    lower = h00 + fc * (h10 - h00) + fr * (h11 - h10)  # fc >= fr
    return jnp.where(fr >= fc, upper, lower)

  def max_height_near(self, physics, xy, radius):
    """The highest grid point within `radius` of `xy`, or `height_at`."""
    xs, ys = self._grid()
    xy = jnp.asarray(xy, jnp.float32)
    near = (xs[None, :] - xy[0]) ** 2 + (ys[:, None] - xy[1]) ** 2 <= (
        radius**2
    )
    highest = jnp.max(jnp.where(near, self.heights(physics), -jnp.inf))
    return jnp.maximum(highest, self.height_at(physics, xy))


def _linear_upsampling(coarse, fine):
  """(fine, coarse) weights interpolating `coarse` points onto `fine` ones."""
  positions = np.linspace(0.0, coarse - 1.0, fine)
  lower = np.clip(np.floor(positions).astype(int), 0, coarse - 2)
  frac = positions - lower
  weights = np.zeros((fine, coarse), np.float32)
  weights[np.arange(fine), lower] = 1 - frac
  weights[np.arange(fine), lower + 1] += frac
  return weights


def _add_grid_and_light(spec, rgb1, rgb2, **material):
  """The ground's checker material 'grid' and a directional light 'top'."""
  spec.add_texture(
      name='grid',
      type=mujoco.mjtTexture.mjTEXTURE_2D,
      builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
      width=256,
      height=256,
      rgb1=rgb1,
      rgb2=rgb2,
  )
  spec.add_material(name='grid', textures=['', 'grid'] + [''] * 8, **material)
  spec.worldbody.add_light(
      name='top',
      pos=[0, 0, 4],
      dir=[0, 0, -1],
      type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
  )
