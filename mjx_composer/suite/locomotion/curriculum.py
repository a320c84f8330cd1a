"""TerrainCurriculum: each world's terrain level, moved by its last episode.

Isaac Lab's `terrain_levels_vel` as a pure part: every world keeps a
terrain level in a persistent entry (it survives auto-resets) and, at each
episode's start, the level moves from what the previous episode achieved:

* up one level if the robot walked farther from its spawn point than
  `up_distance` (default: half a tile, Isaac Lab's rule);
* down one level if it walked less than `down_fraction` of the distance its
  commands asked for (the commanded speed integrated over the episode),
  and did not move up;
* a world that moves up from the last level goes to a level drawn
  uniformly (Isaac Lab's), so the hardest tiles never hoard worlds.

The episode's kind (column) is drawn uniformly at each episode's start; the
world spawns at tile (level, kind)'s spawn point. A world's first episode
starts at a level drawn from `initial_levels`.

The task calls `reset(physics, key)` in `initialize_episode` (it returns the
spawn point), `record(physics, position, command_speed, dt)` in
`after_step`, and reports `metrics(physics)` from `get_metrics` (the level
per world: its distribution over the batch is the curriculum's state).
"""

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer.suite.locomotion import terrain as terrain_lib
from mjx_composer.utils import validation

_OWNER = 'TerrainCurriculum'


def next_level(
    level, distance, commanded, up_distance, down_fraction, levels, key
):
  """The level after an episode (a pure function, jittable).

  Args:
    level: the episode's level (int32 scalar).
    distance: how far the robot got from its spawn point, metres.
    commanded: the distance its commands asked for, metres.
    up_distance: the distance that moves a world up.
    down_fraction: the share of `commanded` below which it moves down.
    levels: the number of levels.
    key: a PRNG key (the level of a world that passes the last level).
  """
  level = jnp.asarray(level, jnp.int32)
  up = jnp.asarray(distance) > up_distance
  down = jnp.logical_and(~up, distance < down_fraction * commanded)
  new = level + up.astype(jnp.int32) - down.astype(jnp.int32)
  beyond = new >= levels
  anywhere = jax.random.randint(key, (), 0, levels, jnp.int32)
  return jnp.clip(jnp.where(beyond, anywhere, new), 0, levels - 1)


class TerrainCurriculum:
  """Per-world terrain levels on a `TerrainGenerator` (module docstring).

  Args:
    terrain: the `TerrainGenerator`.
    initial_levels: (low, high), inclusive: a world's first level is drawn
      uniformly from them.
    up_distance: metres from the spawn point that move a world up (None:
      half a tile).
    down_fraction: a world moves down if it covered less than this share
      of its commanded distance.
    name: the persistent entries' prefix.
  """

  def __init__(
      self,
      terrain,
      initial_levels=(0, 0),
      up_distance=None,
      down_fraction=0.5,
      name='terrain_curriculum',
  ):
    if not isinstance(terrain, terrain_lib.TerrainGenerator):
      raise TypeError(
          f'{_OWNER}: terrain must be a TerrainGenerator, got {terrain!r}. '
          'Pass the arena the task builds, e.g. TerrainGenerator(levels=5).'
      )
    self.terrain = terrain
    levels = terrain.levels
    if (
        isinstance(initial_levels, (str, bytes))
        or np.ndim(initial_levels) != 1
        or len(initial_levels) != 2
    ):
      raise TypeError(
          f'{_OWNER}: initial_levels must be a (low, high) pair of levels, '
          f'got {initial_levels!r}. Pass e.g. (0, 0).'
      )
    low, high = (
        validation.check_integer(
            f'initial_levels[{i}]', v, owner=_OWNER, minimum=0
        )
        for i, v in enumerate(initial_levels)
    )
    if low > high or high >= levels:
      raise ValueError(
          f'{_OWNER}: initial_levels must satisfy 0 <= low <= high < levels '
          f'({levels}), got {initial_levels!r}.'
      )
    self.initial_levels = (low, high)
    self.up_distance = (
        terrain.tile_size / 2
        if up_distance is None
        else validation.check_positive('up_distance', up_distance, owner=_OWNER)
    )
    self.down_fraction = validation.check_nonnegative(
        'down_fraction', down_fraction, owner=_OWNER
    )
    if not isinstance(name, str) or not name:
      raise TypeError(
          f'{_OWNER}: name must be a non-empty string, got {name!r}.'
      )
    self.name = name

  def _entry(self, field):
    return f'{self.name}/{field}'

  def level(self, physics):
    """This world's current level (int32 scalar)."""
    return physics.get_persistent(self._entry('level'))

  def kind(self, physics):
    """This episode's kind (column) index (int32 scalar)."""
    return physics.get_persistent(self._entry('kind'))

  def reset(self, physics, key):
    """Moves the level from the last episode's record; draws the kind.

    Returns:
      `(physics, spawn point (3,))`.
    """
    level_key, kind_key, first_key = jax.random.split(key, 3)
    zero = jnp.zeros((), jnp.float32)
    get = lambda field, default: physics.get_persistent(
        self._entry(field), default
    )
    low, high = self.initial_levels
    first = jax.random.randint(first_key, (), low, high + 1, jnp.int32)
    level = get('level', first)
    started = get('started', jnp.zeros((), bool))
    moved = next_level(
        level,
        get('distance', zero),
        get('commanded', zero),
        self.up_distance,
        self.down_fraction,
        self.terrain.levels,
        level_key,
    )
    level = jnp.where(started, moved, level)
    kind = jax.random.randint(
        kind_key, (), 0, len(self.terrain.kinds), jnp.int32
    )
    spawn = jnp.asarray(self.terrain.spawn_points, jnp.float32)[level, kind]
    for field, value in (
        ('level', level),
        ('kind', kind),
        ('started', jnp.ones((), bool)),
        ('spawn', spawn),
        ('distance', zero),
        ('commanded', zero),
    ):
      physics = physics.set_persistent(self._entry(field), value)
    return physics, spawn

  def record(self, physics, position, command_speed, dt):
    """Records the episode's progress (call in `after_step`).

    Args:
      physics: one world's `Physics`.
      position: the robot's position (at least x, y).
      command_speed: the commanded planar speed of this step, m/s.
      dt: the control timestep, seconds.
    """
    spawn = physics.get_persistent(self._entry('spawn'))
    distance = jnp.linalg.norm(jnp.asarray(position)[:2] - spawn[:2])
    commanded = physics.get_persistent(self._entry('commanded'))
    physics = physics.set_persistent(
        self._entry('distance'), distance.astype(jnp.float32)
    )
    return physics.set_persistent(
        self._entry('commanded'),
        (commanded + command_speed * dt).astype(jnp.float32),
    )

  def metrics(self, physics):
    """`{'terrain_level': level}` for `Task.get_metrics`."""
    return {'terrain_level': self.level(physics).astype(jnp.float32)}
