"""TerrainGenerator and TerrainCurriculum.

The generated geometry is checked against its specification (the compiled
height field's heights, slopes, step heights and depths, stone and beam
sizes) and its spawn points against MuJoCo C's `mj_ray`; a foot dropped on
the stairs, stones and beams written into the height field comes to rest
in MuJoCo C where it rests on the same blocks built as box geoms; the
curriculum's level moves on a scripted episode (a ball that travels far,
one that stays).
"""

import jax
import jax.numpy as jnp
from dm_env import specs
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.suite.entities import props
from mjx_composer.suite.locomotion import curriculum
from mjx_composer.suite.locomotion import terrain as terrain_lib
from mjx_composer.suite.locomotion.terrain import sub_terrains

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
  assert model.ngeom == 1  # Every kind is in the one height field.
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
    for kind in sub_terrains.KINDS:  # Tiles meet at height 0.
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


def test_block_kinds_follow_their_parameters(generated):
  terrain, _ = generated
  config = sub_terrains.SubTerrainConfig()
  cell = terrain.horizontal_scale
  centre_row = lambda kind: _tile_heights(terrain, level, kind)[10]
  for level in range(_LEVELS):
    d = terrain.difficulty(level)
    step = config.at('step_height', d)
    # Along x through the centre: one step_width (3 cells) tread, `step`
    # high, then the platform; a tread's edge point is the higher one's.
    stairs = centre_row('pyramid_stairs')[1:11]
    np.testing.assert_allclose(
        stairs, step * np.repeat([1, 2], [2, 8]), atol=1e-9
    )
    pit = centre_row('inverted_pyramid_stairs')[1:11]
    np.testing.assert_allclose(pit, step * np.repeat([1, 0], [3, 7]), atol=1e-9)
    stones = _tile_heights(terrain, level, 'stepping_stones')
    assert set(np.round(np.unique(stones), 9)) <= {0.0, 0.2}
    beams = centre_row('narrow_beams')
    np.testing.assert_allclose(beams[1:-1], 0.2)  # Along a beam.
    across = _tile_heights(terrain, level, 'narrow_beams')[:, 2]
    width = np.sum(across > 0) - 1  # Cells between the outermost tops.
    assert width == max(1, round(config.at('beam_width', d) / cell))
    grid = _tile_heights(terrain, level, 'random_grid')
    assert 0 < grid.max() <= config.at('grid_height', d) + 1e-9


@pytest.mark.parametrize('seed', [0, 1])
def test_blocks_become_heights_with_their_tops_whole(seed):
  """Every grid point on or in a snapped block's footprint has its top."""
  config = sub_terrains.SubTerrainConfig()
  cell, half = 0.05, 2.0
  xs = np.linspace(-half, half, int(2 * half / cell) + 1)
  for kind in sub_terrains.BLOCK_KINDS:
    rng = np.random.default_rng(seed)
    blocks, spawn = sub_terrains.blocks(kind, 0.7, half, rng, config, cell)
    heights, tile_spawn = sub_terrains.tile(
        kind, 0.7, xs, xs, np.random.default_rng(seed), config
    )
    assert tile_spawn == spawn
    for x, y, z, hx, hy, hz in blocks:
      # Footprints on grid lines, whole numbers of cells wide.
      for edge in (x - hx, x + hx, y - hy, y + hy):
        assert abs((edge + half) / cell - round((edge + half) / cell)) < 1e-6
      inside = (np.abs(xs[None, :] - x) <= hx + 1e-6) & (
          np.abs(xs[:, None] - y) <= hy + 1e-6
      )
      inside[[0, -1], :] = inside[:, [0, -1]] = False  # The tile's rim.
      assert np.all(heights[inside] >= z + hz - 1e-9), kind


_FOOT = 0.023  # The Go1's foot sphere.


def _drop_model(ground_xml):
  return mujoco.MjModel.from_xml_string(f"""
      <mujoco>
        <option timestep="0.002"/>
        <asset>{ground_xml[0]}</asset>
        <worldbody>
          {ground_xml[1]}
          <body name="foot" pos="0 0 1">
            <freejoint/>
            <geom type="sphere" size="{_FOOT}" mass="0.5" condim="3"/>
          </body>
        </worldbody>
      </mujoco>""")


def _rest_heights(model, points, seconds=0.6):
  """The foot's centre height after `seconds`, dropped at each point."""
  data = mujoco.MjData(model)
  rests = []
  for point in points:
    mujoco.mj_resetData(model, data)
    data.qpos[:3] = point
    mujoco.mj_forward(model, data)
    while data.time < seconds:
      mujoco.mj_step(model, data)
    rests.append(data.qpos[2])
  return np.array(rests)


@pytest.mark.parametrize(
    'kind', ['pyramid_stairs', 'stepping_stones', 'narrow_beams']
)
def test_a_foot_rests_on_the_height_field_as_on_the_boxes(kind):
  """MuJoCo C: a Go1 foot dropped on a tile written into a height field
  comes to rest as on the same blocks built as boxes, on treads and at
  their very edges, and never sinks 2 cm into the height field."""
  config = sub_terrains.SubTerrainConfig()
  cell, half = 0.05, 1.5
  xs = np.linspace(-half, half, int(2 * half / cell) + 1)
  heights, _ = sub_terrains.tile(
      kind, 1.0, xs, xs, np.random.default_rng(0), config
  )
  blocks, _ = sub_terrains.blocks(
      kind, 1.0, half, np.random.default_rng(0), config, cell
  )
  top = heights.max()
  elevation = ' '.join(f'{h / top:.9f}' for h in np.ravel(heights))
  hfield = _drop_model(
      (
          f'<hfield name="t" nrow="{len(xs)}" ncol="{len(xs)}" '
          f'size="{half} {half} {top} 0.5" elevation="{elevation}"/>',
          '<geom type="hfield" hfield="t"/>',
      )
  )
  boxes = _drop_model(
      (
          '',
          '<geom type="plane" size="5 5 0.1"/>'
          + ''.join(
              f'<geom type="box" pos="{x} {y} {z}" size="{hx} {hy} {hz}"/>'
              for x, y, z, hx, hy, hz in blocks
          ),
      )
  )
  # Along y = 0.3 (across the treads and beams, through stones), every
  # grid point whose box-version surface is flat for a foot around it, and
  # a foot over each top's edge (its centre a third of its radius inside).
  y, interior = 0.3, 1.5 - 2 * cell
  surface = lambda x: np.max(
      [
          z + hz
          for bx, by, z, hx, hy, hz in blocks
          if abs(x - bx) <= hx + 1e-9 and abs(y - by) <= hy + 1e-9
      ]
      + [0.0]
  )
  flat = [
      x
      for x in xs
      if abs(x) < interior
      and len({surface(x + dx) for dx in np.linspace(-2 * cell, 2 * cell, 9)})
      == 1
  ]
  edges = [
      bx + sign * (hx - _FOOT / 3)
      for bx, by, z, hx, hy, hz in blocks
      for sign in (1, -1)
      if abs(y - by) <= hy - _FOOT and abs(bx + sign * hx) < interior
  ]
  assert len(flat) > 10 and edges
  points = [[x, y, surface(x) + _FOOT + 0.02] for x in flat + edges]
  on_field = _rest_heights(hfield, points)
  on_boxes = _rest_heights(boxes, points)
  np.testing.assert_allclose(on_field, on_boxes, atol=2e-3)
  below = np.array([p[2] - 0.02 for p in points])  # Centre on the surface.
  assert np.all(on_field > below - 0.02)


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
        ({'tile_size': 1.03}, 'tile_size'),
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
