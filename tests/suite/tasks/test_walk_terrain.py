"""TerrainWalk: the humanoid walk composed from the locomotion kit.

One environment (a tiny terrain of 3 levels x 2 kinds of 2 m tiles, 2
worlds, episodes of 10 control steps) is built and stepped for the module;
what the tests compare against is computed on the host with MuJoCo C's
`mj_ray` on the same compiled model.
"""

from dm_control.utils import rewards
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from mjx_composer.suite.tasks import registry
from mjx_composer.suite.tasks import walk_terrain
from mjx_composer.training import config
from tests.suite.tasks import terrain_tasks

_WORLDS = 2
_STEPS = 10  # One episode: the last state is its LAST.
_LEVELS = 3
_TILE = 2.0
_CURRICULUM = 'terrain_curriculum'


@pytest.fixture(scope='module')
def run():
  task = walk_terrain.TerrainWalk(
      kinds=('flat', 'pyramid_stairs'),
      levels=_LEVELS,
      tile_size=_TILE,
      initial_levels=(1, 1),
      scan_size=(0.4, 0.2),
      push_interval=0,
  )
  env, states, step = terrain_tasks.rollout(
      task,
      worlds=_WORLDS,
      steps=_STEPS,
      time_limit=_STEPS * task.control_timestep,
      seed=3,  # World 0 starts on the flat tile, world 1 on the stairs.
  )
  return env, jax.device_get(states), step, states[-2:]


class _Host:
  """The compiled model on the host: names to ids, rays at the terrain."""

  def __init__(self, env):
    self.model = env.mj_model
    self.data = mujoco.MjData(self.model)
    mujoco.mj_kinematics(self.model, self.data)  # The terrain is static.
    self.mask = np.asarray(env.task.terrain.geomgroup, np.uint8)

  def ground(self, xy, above):
    """The terrain's height below `xy`, by a ray from height `above`."""
    geom = np.zeros(1, np.int32)
    start = np.array([xy[0], xy[1], above], np.float64)
    down = np.array([0.0, 0.0, -1.0])
    distance = mujoco.mj_ray(
        self.model, self.data, start, down, self.mask, 1, -1, geom
    )
    assert distance >= 0, f'no terrain below {xy}'
    return above - distance


def test_worlds_spawn_on_a_tile_of_their_level(run):
  env, states, *_ = run
  # Walk's start: the torso initial_height above the platform, no spread.
  terrain_tasks.assert_spawned_on_its_level(
      env, states[0], env.task.humanoid.initial_height, spread=0.0
  )
  np.testing.assert_array_equal(states[0].metrics['terrain_level'], [1, 1])


def test_the_humanoid_lands_on_the_terrain(run):
  """It drops onto the flat tile (world 0) and the stairs (world 1), both
  in the height field, and its feet stay on them."""
  env, states, *_ = run
  np.testing.assert_array_equal(
      states[0].persistent[f'{_CURRICULUM}/kind'], [0, 1]  # flat, stairs
  )
  host = _Host(env)
  geoms = [
      i
      for i in range(host.model.ngeom)
      if host.model.geom(i).name.startswith('humanoid/')
  ]
  # Per state and world: the lowest geom's clearance above the terrain.
  clearance = np.zeros((len(states), _WORLDS))
  for i, state in enumerate(states):
    for world in range(_WORLDS):
      gaps = []
      for geom in geoms:
        centre = state.data.geom_xpos[world, geom]
        axis = state.data.geom_xmat[world, geom].reshape(3, 3)[:, 2]
        radius, half_length = host.model.geom_size[geom, :2]
        if host.model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_SPHERE:
          half_length = 0.0
        # The lower end's centre: the lowest point lies right below it.
        end = centre - np.sign(axis[2]) * half_length * axis
        gaps.append(end[2] - radius - host.ground(end[:2], end[2] + 1.0))
      clearance[i, world] = min(gaps)
  # Walk's start (Playground's qpos0) holds the feet about 0.2 m up; in
  # free fall they would be 0.31 m lower after the episode's 0.25 s, some
  # 0.1 m below the surface.
  assert np.all(clearance[0] > 0.15), clearance
  fall = 0.5 * 9.81 * (_STEPS * env.task.control_timestep) ** 2
  assert np.all(clearance[0] - fall < -0.05), clearance
  # They land and stay on it: the soft contacts (the XML's solref 0.015 s)
  # let a foot sink into the surface at the impact of that drop (1.4 cm
  # here, 2.2 cm with other draws).
  assert np.all(clearance > -0.025), clearance
  assert np.all(clearance[-1] < 0.02), clearance


def test_reward_is_walks_formula_with_the_head_above_the_terrain(run):
  env, states, *_ = run
  host = _Host(env)
  head = host.model.body('humanoid/head').id
  torso = host.model.body('humanoid/torso').id
  sensor = host.model.sensor('humanoid/torso_subtreelinvel')
  adr = sensor.adr[0]
  for state in states[1:]:
    for world in range(_WORLDS):
      head_xyz = state.data.xpos[world, head]
      height = head_xyz[2] - host.ground(head_xyz[:2], head_xyz[2] + 1.0)
      assert state.metrics['head_height'][world] == pytest.approx(
          height, abs=1e-4
      )
      # Walk's documented reward (the `walk` module's docstring: stand at
      # 1.4 m, walk at 1 m/s), term by term, with dm_control's tolerance.
      standing = rewards.tolerance(
          height,
          bounds=(1.4, np.inf),
          margin=1.4 / 4,
          sigmoid='gaussian',
          value_at_margin=0.1,
      )
      upright = rewards.tolerance(
          state.data.xmat[world, torso].reshape(9)[8],
          bounds=(0.9, np.inf),
          margin=1.9,
          sigmoid='linear',
          value_at_margin=0,
      )
      control = rewards.tolerance(
          state.data.ctrl[world],
          bounds=(0, 0),
          margin=1,
          sigmoid='quadratic',
          value_at_margin=0,
      )
      speed = np.linalg.norm(state.data.sensordata[world, adr : adr + 2])
      move = rewards.tolerance(
          speed,
          bounds=(1.0, np.inf),
          margin=1.0,
          sigmoid='linear',
          value_at_margin=0,
      )
      expected = (
          standing * upright * (4 + np.mean(control)) / 5 * (5 * move + 1) / 6
      )
      assert state.reward[world] == pytest.approx(float(expected), rel=1e-5)


def test_policy_sees_the_height_scan_and_the_critic_its_clean_twin(run):
  env, states, *_ = run
  host = _Host(env)
  torso = host.model.body('humanoid/torso').id
  points = env.task.height_scan.points
  rays = len(points)
  assert rays == 5 * 3
  for state in states[-2:]:
    for world in range(_WORLDS):
      xyz = state.data.xpos[world, torso]
      xmat = state.data.xmat[world, torso].reshape(3, 3)
      yaw = np.arctan2(xmat[1, 0], xmat[0, 0])
      c, s = np.cos(yaw), np.sin(yaw)
      grid = xyz[:2] + points @ np.array([[c, s], [-s, c]])
      expected = [host.ground(p, xyz[2] + 1.0) - xyz[2] for p in grid]
      np.testing.assert_allclose(
          state.observation['critic'][world, -rays:], expected, atol=1e-4
      )
  # The policy's: the previous step's scan (a sample visible one sub-step
  # after it is taken), with U(-0.1, 0.1) m noise.
  previous = states[-2].observation['critic'][:, -rays:]
  error = np.abs(states[-1].observation['policy'][:, -rays:] - previous)
  assert np.all(error <= 0.1 + 1e-5) and np.any(error > 1e-3)


def test_the_curriculum_moves_levels_after_an_episode(run):
  env, states, step, (before, last_on_device) = run
  zeros = jnp.zeros((_WORLDS,) + env.action_spec().shape, jnp.float32)
  entry = lambda field: f'{_CURRICULUM}/{field}'

  # As it went: the record is the torso's distance from the spawn point
  # and 1 m/s over the episode's 0.25 s; the level moves by the rule.
  last = states[-1]
  torso = env.mj_model.body('humanoid/torso').id
  spawn = last.persistent[entry('spawn')]
  distance = last.persistent[entry('distance')]
  np.testing.assert_allclose(
      distance,
      np.linalg.norm(last.data.xpos[:, torso, :2] - spawn[:, :2], axis=-1),
      atol=1e-5,
  )
  np.testing.assert_allclose(
      last.persistent[entry('commanded')], _STEPS * 0.025, rtol=1e-5
  )
  up = distance > _TILE / 2
  down = ~up & (distance < 0.5 * _STEPS * 0.025)
  restarted = jax.device_get(step(last_on_device, zeros))
  np.testing.assert_array_equal(
      restarted.metrics['terrain_level'], 1 + up.astype(int) - down
  )

  # Scripted: world 0's spawn point moved 10 m away (it then walked more
  # than half a tile: up), world 1 asked for 100 m more (down).
  persistent = dict(before.persistent)
  persistent[entry('spawn')] = persistent[entry('spawn')].at[0, 0].add(10.0)
  persistent[entry('commanded')] = (
      persistent[entry('commanded')].at[1].add(100.0)
  )
  state = step(before.replace(persistent=persistent), zeros)  # LAST
  state = jax.device_get(step(state, zeros))  # The next episode's start.
  np.testing.assert_array_equal(state.metrics['terrain_level'], [2, 0])
  terrain_tasks.assert_spawned_on_its_level(
      env, state, env.task.humanoid.initial_height, spread=0.0
  )


def test_registered_with_walks_training_defaults():
  assert 'walk_terrain' in registry.names()
  walk = config.defaults('walk')
  assert config.defaults('walk_terrain') == walk.replace(task='walk_terrain')
  with pytest.raises(TypeError, match='height_scan'):
    walk_terrain.TerrainWalk(height_scan='yes')
