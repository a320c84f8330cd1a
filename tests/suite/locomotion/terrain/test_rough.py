"""`RoughTerrain`: per-world height fields, checked with MuJoCo itself."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from mjx_composer import environment
from mjx_composer import task
from mjx_composer.suite.entities import arenas
from mjx_composer.suite.entities import props
from mjx_composer.suite.locomotion import terrain

_BALL_XY = (0.3, -0.7)
_RADIUS = 0.05
_SINK = 0.01  # How deep the ball starts in the terrain.


class _BallOnTerrain(task.NullTask):
  """Samples the world's terrain, then sets a ball into it at `_BALL_XY`."""

  def __init__(self):
    self.arena = terrain.RoughTerrain(
        size=(2.0, 3.0), resolution=(24, 16), auto_regenerate=False
    )
    self.ball = props.Sphere(radius=_RADIUS, name='ball')
    self.arena.add_free_entity(self.ball)
    super().__init__(self.arena)

  def initialize_episode(self, physics, key):
    physics = self.arena.regenerate_world(physics, key)
    ground = self.arena.height_at(physics, jnp.asarray(_BALL_XY))
    position = jnp.array([*_BALL_XY, 0.0]).at[2].set(ground + _RADIUS - _SINK)
    return self.ball.set_pose(physics, position)


@pytest.fixture(scope='module')
def worlds():
  env = environment.Environment(_BallOnTerrain())
  states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), 3))
  return env, jax.device_get(states)


def test_mujoco_normalizes_elevations_as_the_profile_does():
  arena = terrain.RoughTerrain(size=(2.0, 3.0), resolution=(24, 16))
  random_state = np.random.RandomState(4)
  bumps = random_state.uniform(size=arena.coarse_shape)
  noise = random_state.uniform(size=arena.resolution)
  profile = arena.profile(bumps, noise)
  assert profile.shape == (24, 16)
  assert profile.min() == 0.0 and profile.max() == pytest.approx(1.0)
  # MuJoCo rescales any elevation data to [0, 1]: an affine copy of the
  # profile compiles to the profile.
  spec = arena.mjcf_model
  spec.hfields[0].userdata = (3.0 * profile.ravel() + 5.0).tolist()
  model = spec.compile()
  np.testing.assert_allclose(model.hfield_data, profile.ravel(), atol=1e-6)
  # Composer's host-side regenerate draws a new compiled profile.
  arena.regenerate(np.random.RandomState(5))
  regenerated = arena.mjcf_model.compile().hfield_data
  assert not np.allclose(regenerated, model.hfield_data)


def test_every_world_collides_with_its_own_terrain(worlds):
  env, states = worlds
  data = states.model_fields['hfield_data']
  assert data.shape == (3, 24 * 16)
  assert not np.allclose(data[0], data[1]) and not np.allclose(data[1], data[2])
  np.testing.assert_allclose(data.min(axis=1), 0.0, atol=1e-6)
  np.testing.assert_allclose(data.max(axis=1), 1.0, atol=1e-6)
  arena = env.task.arena
  ball = env.mj_model.body('ball/').id
  for world in range(3):
    # MuJoCo's C collision on the model compiled with this world's profile.
    model = env.spec.compile()
    model.hfield_data[:] = data[world]
    mj_data = mujoco.MjData(model)
    mj_data.qpos[:] = states.data.qpos[world]
    mujoco.mj_forward(model, mj_data)
    # The terrain height below the ball: a ray cast, skipping the ball.
    geom = np.zeros(1, np.int32)
    distance = mujoco.mj_ray(
        model,
        mj_data,
        np.array([*_BALL_XY, 2.0]),
        np.array([0.0, 0.0, -1.0]),
        None,
        1,
        ball,
        geom,
    )
    assert geom[0] == model.geom('ground').id
    ground = 2.0 - distance
    ball_z = states.data.qpos[world, 2]
    assert ball_z == pytest.approx(ground + _RADIUS - _SINK, abs=1e-5)
    assert 0.0 <= ground <= arena.max_height
    # MJX's contacts against this world's terrain match MuJoCo's.
    depths = [c.dist for c in mj_data.contact[: mj_data.ncon]]
    assert depths and min(depths) < 0
    # Contacts are not read at reset, so the reset's stage of the forward
    # pass skips them: `env.physics` completes it.
    contact = env.physics(states).data._impl.contact  # pylint: disable=protected-access
    mjx_depths = contact.dist[world]
    assert np.min(mjx_depths) == pytest.approx(min(depths), abs=1e-5)


def _built(arena):
  """An environment around `arena` and a ball (built, nothing compiled)."""
  arena.add_free_entity(props.Sphere(radius=_RADIUS, name='ball'))
  return environment.Environment(task.NullTask(arena))


def test_the_arenas_own_hook_samples_per_world_unless_told_not_to(worlds):
  env, _ = worlds
  physics = env.initial_physics()
  key = jax.random.key(1)
  # The fixture's arena leaves the sampling to its task.
  unchanged = env.task.arena.initialize_episode(physics, key)
  assert unchanged.model.hfield_data is physics.model.hfield_data
  # By default, the arena's own hook writes a profile drawn from the key.
  arena = terrain.RoughTerrain(size=(2.0, 3.0), resolution=(24, 16))
  physics = _built(arena).initial_physics()
  regenerated = arena.initialize_episode(physics, key)
  np.testing.assert_allclose(
      regenerated.model.hfield_data,
      np.ravel(arena.sample_profile(key)),
      atol=1e-6,
  )
  assert not np.allclose(
      regenerated.model.hfield_data, physics.model.hfield_data
  )
  # Shared terrain: every world keeps the compiled profile.
  shared = terrain.RoughTerrain(per_world=False)
  physics = _built(shared).initial_physics()
  assert shared.initialize_episode(physics, key) is physics
  assert shared.regenerate_world(physics, key) is physics


def test_mjx_refuses_shapes_it_cannot_collide_with_height_fields():
  arena = terrain.RoughTerrain(size=(1.0, 1.0), resolution=(8, 8))
  arena.add_free_entity(props.Cylinder(radius=0.05, half_length=0.05))
  with pytest.raises(NotImplementedError, match='HFIELD'):
    environment.Environment(task.NullTask(arena))


def test_highest_point_near_a_spot(worlds):
  env, states = worlds
  arena = env.task.arena
  xs = np.linspace(-2.0, 2.0, 16)
  ys = np.linspace(-3.0, 3.0, 24)
  for world in range(3):
    physics = env.physics(jax.tree.map(lambda x: x[world], states))
    heights = arena.max_height * states.model_fields['hfield_data'][
        world
    ].reshape(24, 16)
    for xy, radius in (((0.3, -0.7), 0.6), ((-1.0, 2.0), 1.0)):
      near = (xs[None] - xy[0]) ** 2 + (ys[:, None] - xy[1]) ** 2 <= radius**2
      got = arena.max_height_near(physics, jnp.asarray(xy), radius)
      assert float(got) == pytest.approx(heights[near].max(), abs=1e-6)


def test_each_world_is_rendered_with_its_own_terrain(worlds):
  from mjx_composer.host import rendering  # pylint: disable=g-import-not-at-top

  env, states = worlds
  profiles = np.asarray(states.model_fields['hfield_data'])
  assert not np.allclose(profiles[0], profiles[1])
  images = rendering.render(env, states, worlds=[0, 1], height=48, width=64)
  camera = rendering.free_camera(env.mj_model)
  for world, image in enumerate(images):
    # Independent reference: a host model holding only this world's
    # profile (and pose), drawn by a renderer of its own.
    model = env.mj_model.__copy__()
    model.hfield_data[:] = profiles[world]
    data = mujoco.MjData(model)
    data.qpos[:] = np.asarray(states.data.qpos)[world]
    mujoco.mj_forward(model, data)
    renderer = rendering.make_renderer(model, 48, 64)
    try:
      renderer.update_scene(data, camera=camera)
      np.testing.assert_array_equal(image, renderer.render())
    finally:
      renderer.close()
  assert not np.array_equal(images[0], images[1])


def test_the_old_import_path_warns_and_gives_the_same_class():
  with pytest.warns(DeprecationWarning, match='locomotion.terrain'):
    moved = arenas.RoughTerrain
  assert moved is terrain.RoughTerrain


def test_bumps_closer_than_the_grid_are_refused_naming_the_cell():
  """A tiny spacing asked for a control grid of terabytes (a MemoryError)."""
  # Cells: 4 / 15 m along x, 6 / 23 m along y; the coarser one is x's.
  with pytest.raises(
      ValueError, match=r'`bump_spacing` must be at least .* 0\.2667 m.*1e-09'
  ):
    terrain.RoughTerrain(
        size=(2.0, 3.0), resolution=(24, 16), bump_spacing=1e-9
    )
  with pytest.raises(ValueError, match=r'bump_spacing >= 0\.2667'):
    terrain.RoughTerrain(size=(2.0, 3.0), resolution=(24, 16), bump_spacing=0.2)
  arena = terrain.RoughTerrain(
      size=(2.0, 3.0), resolution=(24, 16), bump_spacing=4.0 / 15
  )
  assert arena.coarse_shape[1] <= 16 and arena.coarse_shape[0] <= 24
