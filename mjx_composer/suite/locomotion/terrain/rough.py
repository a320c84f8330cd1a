"""RoughTerrain: a height-field ground whose profile each world samples.

Where a composer arena's `regenerate` changed the MJCF and needed a
recompile every episode, `regenerate_world(physics, key)` writes the
world's own elevations into `hfield_data` instead, so a world matches the
model compiled with the sampled profile.
"""

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer.suite.locomotion.terrain import surface
from mjx_composer.utils import validation

_OWNER = 'RoughTerrain'


class RoughTerrain(surface.HeightFieldArena):
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
  builds the arena with `auto_regenerate=False`. Composer's
  `regenerate(random_state)` samples one profile on the host at build time instead, shared by every world (with
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
    bump_spacing: metres between the smooth bumps' control points, at
      least the elevation grid's cell (`2 * size / (resolution - 1)`).
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
    if not isinstance(name, str) or not name:
      raise TypeError(
          f'{_OWNER}: name must be a non-empty string, got {name!r}.'
      )
    super()._build(name=name)
    size = validation.check_positive('size', size, owner=_OWNER)
    if np.shape(size) != (2,):
      raise ValueError(
          f'{_OWNER}: size must be (half-x, half-y) in metres, got {size!r}.'
      )
    self._size = tuple(float(s) for s in size)
    if np.shape(resolution) != (2,):
      raise ValueError(
          f'{_OWNER}: resolution must be (rows, columns), got {resolution!r}.'
      )
    self._rows, self._cols = (
        validation.check_integer(f'resolution[{i}]', r, owner=_OWNER, minimum=2)
        for i, r in enumerate(resolution)
    )
    self._max_height = validation.check_positive(
        'max_height', max_height, owner=_OWNER
    )
    base = validation.check_positive('base', base, owner=_OWNER)
    bump_spacing = validation.check_positive(
        'bump_spacing', bump_spacing, owner=_OWNER
    )
    self._roughness = validation.check_nonnegative(
        'roughness', roughness, owner=_OWNER, fix='0: only smooth bumps.'
    )
    self._per_world = validation.check_bool(
        'per_world', per_world, owner=_OWNER
    )
    self._auto_regenerate = validation.check_bool(
        'auto_regenerate', auto_regenerate, owner=_OWNER
    )
    # Control points closer than the grid's own cannot be drawn (the grid
    # samples them), and their count grows as 1 / bump_spacing**2: a tiny
    # spacing asked for terabytes.
    cell = max(
        2 * self._size[0] / (self._cols - 1),
        2 * self._size[1] / (self._rows - 1),
    )
    if bump_spacing < cell * (1 - 1e-9):
      raise ValueError(
          f"{_OWNER}: `bump_spacing` must be at least the elevation grid's "
          f'cell, {cell:.4g} m (2 * size / (resolution - 1) along the coarser '
          f"axis), got {bump_spacing!r}: bumps closer than the grid's points "
          f'cannot be drawn. Pass bump_spacing >= {cell:.4g}, or a finer '
          '`resolution`; `roughness` adds cell-scale detail.'
      )
    # Bilinear upsampling from the bumps' control grid, as two matrices.
    coarse = [
        max(2, int(np.ceil(2 * s / bump_spacing)) + 1) for s in self._size
    ]
    self._coarse_shape = (coarse[1], coarse[0])
    self._upsample_rows = _linear_upsampling(coarse[1], self._rows)
    self._upsample_cols = _linear_upsampling(coarse[0], self._cols)
    self._field = surface.HeightField(
        self.mjcf_model,
        half_extent=self._size,
        shape=(self._rows, self._cols),
        span=self._max_height,
        base=base,
    )
    self.regenerate(np.random.RandomState(0))
    self.mjcf_model.worldbody.add_camera(
        name='overview', pos=[1.6, -1.6, 1.4], xyaxes=[1, 1, 0, -0.4, 0.4, 1]
    )

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
    self._field.set_elevation(
        self.profile(
            random_state.uniform(size=self._coarse_shape),
            random_state.uniform(size=(self._rows, self._cols)),
        )
    )

  def regenerate_world(self, physics, key):
    """Writes a freshly sampled profile into this world's `hfield_data`.

    Does nothing unless `per_world`.
    """
    if not self._per_world:
      return physics
    start, count = self._field.data_range(physics)
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

  def heights(self, physics):
    """This world's surface heights (rows, cols) in metres, rows along y."""
    return self._field.heights(physics)

  def max_height_near(self, physics, xy, radius):
    """The highest grid point within `radius` of `xy`, or `height_at`."""
    return self._field.max_height_near(physics, xy, radius)


def _linear_upsampling(coarse, fine):
  """(fine, coarse) weights interpolating `coarse` points onto `fine` ones."""
  positions = np.linspace(0.0, coarse - 1.0, fine)
  lower = np.clip(np.floor(positions).astype(int), 0, coarse - 2)
  frac = positions - lower
  weights = np.zeros((fine, coarse), np.float32)
  weights[np.arange(fine), lower] = 1 - frac
  weights[np.arange(fine), lower + 1] += frac
  return weights
