"""TerrainGenerator and TerrainCurriculum.

The generated geometry is checked against its specification (the compiled
height field's heights, slopes, step heights and depths, stone and beam
sizes) and its spawn points against MuJoCo C's `mj_ray`; the curriculum's
level moves on a scripted episode (a ball that travels far, one that stays).
"""

import jax
import jax.numpy as jnp
from dm_env import specs
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.entities import props
from mjx_composer.locomotion import curriculum
from mjx_composer.locomotion import sub_terrains
from mjx_composer.locomotion import terrain as terrain_lib

_TILE = 2.0
_LEVELS = 3


@pytest.fixture(scope='module')
def generated():
  terrain = terrain_lib.TerrainGenerator(
      levels=_LEVELS, tile_size=_TILE, horizontal_scale=0.1, border=0.5
  )
  model = terrain.mjcf_model.compile()
  return terrain, model


def _tile_heights(terrain, level, kind):
  """The tile's (21, 21) height-field heights."""
  heights = terrain.heights
  centre = terrain.tile_centre(level, terrain.kinds.index(kind))
  half = np.array(heights.shape[::-1]) // 2
  col, row = (np.round(centre / 0.1).astype(int) + half).tolist()
  return heights[row - 10 : row + 11, col - 10 : col + 11]


def test_the_compiled_height_field_has_the_generated_heights(generated):
  terrain, model = generated
  geom = model.geom('ground')
  size = model.hfield_size[0]
  compiled = model.hfield_data.reshape(terrain.heights.shape) * size[2]
  np.testing.assert_allclose(compiled + geom.pos[2], terrain.heights, atol=1e-5)
  assert model.ngeom == 1 + len(terrain.boxes)
  assert set(model.geom_group) == {terrain.group}


def test_height_field_kinds_follow_their_parameters(generated):
  terrain, _ = generated
  config = sub_terrains.SubTerrainConfig()
  local = np.linspace(-1.0, 1.0, 21)
  off_platform = ~(
      (np.abs(local)[None, :] <= 0.5) & (np.abs(local)[:, None] <= 0.5)
  )
  interior = np.zeros((21, 21), bool)
  interior[1:-1, 1:-1] = True
  off_platform &= interior
  for level in range(_LEVELS):
    d = terrain.difficulty(level)
    assert d == pytest.approx(level / (_LEVELS - 1))
    tile = lambda kind: _tile_heights(terrain, level, kind)
    for kind in sub_terrains.HFIELD_KINDS:  # Tiles meet at height 0.
      assert np.all(tile(kind)[~interior] == 0.0), kind
    np.testing.assert_array_equal(tile('flat'), 0.0)
    noise = tile('random_uniform')[off_platform]
    assert noise.min() >= 0 and noise.max() <= config.at('noise', d)
    assert noise.max() > 0.5 * config.at('noise', d)
    slope = config.at('slope', d)
    row = tile('pyramid_slope')[10]  # Along x through the centre.
    np.testing.assert_allclose(row[:6], slope * (local[:6] + 1.0), atol=1e-6)
    np.testing.assert_allclose(
        tile('inverted_pyramid_slope'), -tile('pyramid_slope'), atol=1e-9
    )
    waves = tile('waves')
    amplitude = config.at('wave_amplitude', d)
    assert np.abs(waves).max() <= amplitude + 1e-9
    wave = lambda u: np.sin(2 * np.pi * 2 * (u + 1) / 2)  # 2 periods.
    np.testing.assert_allclose(
        waves[1, 1:6],
        amplitude / 2 * (wave(local[1:6]) + wave(local[1])),
        atol=1e-9,
    )
    obstacles = np.unique(np.round(tile('discrete_obstacles'), 9))
    height = config.at('obstacle_height', d)
    assert set(obstacles) <= {-round(height, 9), 0.0, round(height, 9)}


def _tile_boxes(terrain, level, kind):
  boxes = terrain.boxes
  centre = terrain.tile_centre(level, terrain.kinds.index(kind))
  inside = np.all(np.abs(boxes[:, :2] - centre) < _TILE / 2, axis=1)
  boxes = boxes[inside].copy()
  boxes[:, :2] -= centre
  return boxes


def test_box_kinds_follow_their_parameters(generated):
  terrain, _ = generated
  config = sub_terrains.SubTerrainConfig()
  for level in range(_LEVELS):
    d = terrain.difficulty(level)
    step = config.at('step_height', d)
    stairs = _tile_boxes(terrain, level, 'pyramid_stairs')
    tops = np.sort(stairs[:, 2] + stairs[:, 5])
    np.testing.assert_allclose(np.diff(tops), step, atol=1e-9)
    widths = np.sort(stairs[:, 3])[::-1]
    assert widths[0] == pytest.approx(_TILE / 2)
    np.testing.assert_allclose(
        widths[0] - widths[1], config.step_width, atol=1e-9
    )
    pit = _tile_boxes(terrain, level, 'inverted_pyramid_stairs')
    np.testing.assert_allclose(
        np.unique(np.round(pit[:, 2] + pit[:, 5], 9)), step, atol=1e-9
    )
    stones = _tile_boxes(terrain, level, 'stepping_stones')
    stones = stones[stones[:, 3] < 0.5]  # Not the platform.
    size = config.at('stone_size', d)
    np.testing.assert_allclose(stones[:, 3:5], size / 2, atol=1e-9)
    xs = np.unique(np.round(stones[:, 0], 9))
    np.testing.assert_allclose(
        np.diff(xs), size + config.at('stone_gap', d), atol=1e-9
    )
    np.testing.assert_allclose(stones[:, 2] + stones[:, 5], 0.2, atol=1e-9)
    beams = _tile_boxes(terrain, level, 'narrow_beams')[1:]
    np.testing.assert_allclose(
        np.min(beams[:, 3:5], axis=1), config.at('beam_width', d) / 2
    )
    grid = _tile_boxes(terrain, level, 'random_grid')
    tops = grid[:, 2] + grid[:, 5]
    assert tops.max() <= config.at('grid_height', d) + 1e-9
    np.testing.assert_allclose(grid[:, 3:5], config.grid_cell / 2)


def test_spawn_points_lie_on_the_surface(generated):
  terrain, model = generated
  data = mujoco.MjData(model)
  mujoco.mj_kinematics(model, data)
  spawns = terrain.spawn_points
  assert spawns.shape == (_LEVELS, len(sub_terrains.KINDS), 3)
  for point in spawns.reshape(-1, 3):
    for dx, dy in ((0, 0), (0.2, -0.2)):  # Anywhere on the platform.
      origin = point + [dx, dy, 2.0]
      distance = mujoco.mj_ray(
          model,
          data,
          origin,
          np.array([0.0, 0, -1]),
          None,
          1,
          -1,
          np.zeros(1, np.int32),
      )
      assert distance == pytest.approx(2.0, abs=1e-6)


@pytest.mark.parametrize(
    'kwargs, match',
    [
        ({'kinds': ('lava',)}, 'kinds'),
        ({'levels': 0}, 'levels'),
        ({'tile_size': 1.05}, 'tile_size'),
        ({'difficulty_range': (0.5, 0.2)}, 'difficulty_range'),
        ({'difficulty_range': (0.0, 2.0)}, 'difficulty_range'),
        ({'border': -1.0}, 'border'),
    ],
)
def test_bad_arguments_are_refused_by_name(kwargs, match):
  with pytest.raises((TypeError, ValueError), match=match):
    terrain_lib.TerrainGenerator(**kwargs)


# -- curriculum ----------------------------------------------------------------


def test_next_level_moves_up_down_and_wraps():
  key = jax.random.key(0)
  move = lambda level, distance, commanded: int(
      curriculum.next_level(level, distance, commanded, 1.0, 0.5, 4, key)
  )
  assert move(1, 1.5, 10.0) == 2  # Far enough: up, whatever the command.
  assert move(1, 0.8, 1.0) == 1  # Not far, but most of what was asked.
  assert move(1, 0.4, 1.0) == 0  # Less than half of it: down.
  assert move(0, 0.0, 1.0) == 0  # Not below level 0.
  wrapped = [
      int(curriculum.next_level(3, 2.0, 0.0, 1.0, 0.5, 4, jax.random.key(k)))
      for k in range(40)
  ]
  assert set(wrapped) == {0, 1, 2, 3}


class _Walker(composer.Task):
  """A ball that the action moves along x each step, on a generated terrain.

  The action is the metres per step: the curriculum records the distance
  from the spawn point and a commanded speed of 1 m/s.
  """

  def __init__(self):
    self.terrain = terrain_lib.TerrainGenerator(
        kinds=('flat', 'pyramid_stairs'),
        levels=_LEVELS,
        tile_size=_TILE,
        border=0.0,
    )
    self.ball = props.Sphere(radius=0.05, name='ball')
    self.terrain.add_free_entity(self.ball)
    self.curriculum = curriculum.TerrainCurriculum(
        self.terrain, initial_levels=(1, 1)
    )
    self.set_timesteps(control_timestep=0.1, physics_timestep=0.05)

  @property
  def root_entity(self):
    return self.terrain

  def action_spec(self, physics):
    return specs.BoundedArray((1,), np.float32, 0.0, 1.0)

  def initialize_episode(self, physics, key):
    physics, spawn = self.curriculum.reset(physics, key)
    return self.ball.set_pose(physics, spawn + jnp.array([0, 0, 0.05]))

  def before_step(self, physics, action, key):
    position = self.ball.get_pose(physics)[0]
    return self.ball.set_pose(physics, position.at[0].add(action[0]))

  def after_step(self, physics, key):
    position = self.ball.get_pose(physics)[0]
    return self.curriculum.record(physics, position, 1.0, 0.1)

  def get_reward(self, physics):
    return 0.0

  def get_metrics(self, physics):
    return self.curriculum.metrics(physics)


def test_the_level_moves_on_a_scripted_episode():
  env = composer.Environment(_Walker(), time_limit=0.3)  # 3 steps.
  state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), 2))
  step = jax.jit(jax.vmap(env.step))
  # World 0 travels 0.5 m a step (1.5 m > half a tile), world 1 stays
  # (0 m of 0.3 m asked).
  action = jnp.array([[0.5], [0.0]])
  levels = [np.asarray(state.metrics['terrain_level'])]
  spawns = [np.asarray(state.data.qpos[:, :3])]
  for _ in range(2):  # Two episodes of 3 steps, then the auto-reset.
    for _ in range(4):
      state = step(state, action)
    levels.append(np.asarray(state.metrics['terrain_level']))
    spawns.append(np.asarray(state.data.qpos[:, :3]))
  np.testing.assert_array_equal(levels[0], [1, 1])
  np.testing.assert_array_equal(levels[1], [2, 0])
  # World 0 passes the last level: a random level; world 1 stays at 0.
  assert levels[2][1] == 0 and 0 <= levels[2][0] < _LEVELS
  points = env.task.terrain.spawn_points
  for level, spawn in zip(levels, spawns):
    for world in range(2):
      xs = points[int(level[world]), :, 0]
      assert np.min(np.abs(xs - spawn[world, 0])) < 1e-5
