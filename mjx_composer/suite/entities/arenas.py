"""Arenas: the root entities of bundled scenes.

`Floor` is locomotion's flat checkered floor; `WalledArena` adds four walls
around it. The terrain arenas (`RoughTerrain`, `TerrainGenerator`) live in
`mjx_composer.suite.locomotion.terrain`.
Where a composer arena's `regenerate` changed the MJCF and needed a
recompile every episode, here `regenerate_world(physics, key)` writes the
equivalent per-world model fields instead (the arena's `initialize_episode`
calls it), so a world matches the model compiled with the sampled layout.
Composer's host-side `regenerate(random_state)` keeps its meaning: a build
time edit of the spec (a no-op for `Floor` and `WalledArena`).
"""

import warnings

import jax.numpy as jnp
import mujoco
import numpy as np

from mjx_composer import arena
from mjx_composer.variation import structures

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
    add_grid_and_light(
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
            structures.evaluate(
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


def add_grid_and_light(spec, rgb1, rgb2, **material):
  """The ground's checker material 'grid' and a directional light 'top'.

  The look of the bundled arenas' grounds (`Floor`, the terrain arenas).
  """
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


def __getattr__(name):
  """`arenas.RoughTerrain`, kept for this release: it moved to
  `mjx_composer.suite.locomotion.terrain`."""
  if name != 'RoughTerrain':
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
  warnings.warn(
      'mjx_composer.suite.entities.arenas.RoughTerrain moved to '
      'mjx_composer.suite.locomotion.terrain.RoughTerrain; import it from '
      'there.',
      DeprecationWarning,
      stacklevel=2,
  )
  from mjx_composer.suite.locomotion import terrain  # pylint: disable=g-import-not-at-top

  return terrain.RoughTerrain
