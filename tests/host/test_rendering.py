"""Tests for `mjx_composer.host.rendering`: host renders of chosen worlds."""

import os

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.host import rendering
from tests import conftest

_COLOURS = np.eye(3, 4, dtype=np.float32) + np.array([0, 0, 0, 1], np.float32)


class _ColourTask(composer.Task):
  """Per world: a pure red, green or blue bead at a random height."""

  def __init__(self):
    self.arena = composer.Arena()
    self.arena.mjcf_model.worldbody.add_geom(
        name='floor',
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[2, 2, 0.1],
        rgba=[0.5, 0.5, 0.5, 1],
        contype=0,
        conaffinity=0,
    )
    # A sphere that collides with nothing (keeps the compile small).
    self.bead = conftest.Ball(
        name='bead', radius=0.3, mass=None, collides=False
    )
    self.arena.add_free_entity(self.bead)

  @property
  def root_entity(self):
    return self.arena

  def initial_task_state(self):
    return {'colour': jnp.zeros((), jnp.int32)}

  def initialize_episode(self, physics, key):
    colour_key, height_key = jax.random.split(key)
    colour = jax.random.randint(colour_key, (), 0, 3)
    physics = physics.bind(self.bead.geom).set(
        rgba=jnp.asarray(_COLOURS)[colour]
    )
    height = jax.random.uniform(height_key, (), minval=0.5, maxval=1.5)
    physics = self.bead.set_pose(
        physics, position=jnp.array([0.0, 0.0, 1.0]) * height
    )
    return physics.update_task_state(colour=colour)

  def get_reward(self, physics):
    return jnp.zeros(())


# Look straight down at the bead from above.
_TOP_VIEW = dict(
    distance=4.0, azimuth=90.0, elevation=-90.0, lookat=[0.0, 0.0, 0.0]
)


@pytest.fixture(scope='module')
def env():
  return composer.Environment(_ColourTask())


@pytest.fixture(scope='module')
def states(env):
  return jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(3), 6))


def test_render_shapes_and_world_selection(env, states):
  images = rendering.render(env, states, worlds=[0, 2], height=48, width=64)
  assert images.shape == (2, 48, 64, 3) and images.dtype == np.uint8
  one = rendering.render(env, states, worlds=2, height=48, width=64)
  assert one.shape == (48, 64, 3)
  np.testing.assert_array_equal(one, images[1])
  assert rendering.render(env, states, height=24, width=32).shape == (
      6,
      24,
      32,
      3,
  )
  single = jax.tree.map(lambda x: x[2], states)
  np.testing.assert_array_equal(
      rendering.render(env, single, height=48, width=64), one
  )
  with pytest.raises(IndexError, match='out of range'):
    rendering.render(env, states, worlds=[6])


def test_each_world_is_drawn_with_its_own_model_fields(env, states):
  assert 'geom_rgba' in states.model_fields  # varied per world
  rgba_before = env.mj_model.geom_rgba.copy()
  images = rendering.render(env, states, height=64, width=64, camera=_TOP_VIEW)
  colours = np.asarray(states.task_state['colour'])
  assert len(set(colours.tolist())) > 1, 'pick a seed with several colours'
  centre = images[:, 28:36, 28:36].reshape(len(colours), -1, 3).mean(axis=1)
  np.testing.assert_array_equal(np.argmax(centre, axis=-1), colours)
  # The environment's own host model keeps its defaults.
  np.testing.assert_array_equal(env.mj_model.geom_rgba, rgba_before)


def test_each_world_is_drawn_at_its_own_pose(env, states):
  side = dict(distance=5.0, azimuth=90.0, elevation=0.0, lookat=[0, 0, 1])
  images = rendering.render(env, states, height=64, width=64, camera=side)
  heights = np.asarray(states.data.qpos[:, 2])
  # The bead's mean image row moves up as the bead rises.
  rows = []
  for image in images:
    mask = image.max(axis=-1).astype(int) - image.min(axis=-1) > 100
    rows.append(np.nonzero(mask)[0].mean())
  assert np.all(np.diff(np.asarray(rows)[np.argsort(heights)]) < 0)


def test_markers_are_drawn(env, states):
  plain = rendering.render(
      env, states, worlds=0, height=64, width=64, camera=_TOP_VIEW
  )
  marked = rendering.render(
      env,
      states,
      worlds=0,
      height=64,
      width=64,
      camera=_TOP_VIEW,
      markers=np.tile([[1.0, 0.0, 0.1]], (6, 1)),
      marker_radius=0.2,
      marker_rgba=(1, 1, 0, 1),
  )
  changed = np.any(plain != marked, axis=-1)
  assert 0 < changed.sum() < changed.size / 4
  yellow = marked[changed].astype(int)
  assert np.mean(yellow[:, 2]) < np.mean(yellow[:, 0]) / 2


def test_one_renderer_draws_what_fresh_renders_draw(env, states):
  """A `WorldRenderer` kept across frames and worlds (each world's colour
  written only when it changes) draws what a fresh renderer draws."""
  fresh = rendering.render(env, states, height=32, width=32, camera=_TOP_VIEW)
  order = [0, 1, 1, 5, 2, 0, 4, 3, 3]
  host = rendering.host_fields(states)
  out = np.zeros((1, 32, 32, 3), np.uint8)
  with rendering.WorldRenderer(env, 32, 32, camera=_TOP_VIEW) as renderer:
    for world in order:
      image = renderer.render(states, world)
      np.testing.assert_array_equal(image, fresh[world])
      drawn = renderer.render(host, [world], out=out)
      assert drawn is out
      np.testing.assert_array_equal(out[0], fresh[world])
    np.testing.assert_array_equal(
        renderer.render(states, [4, 1, 4]), fresh[[4, 1, 4]]
    )
  with pytest.raises(RuntimeError, match='closed'):
    renderer.render(states, 0)


def test_shadow_maps_are_sized_to_the_image():
  model = mujoco.MjModel.from_xml_string(
      '<mujoco><worldbody><light pos="0 0 3" castshadow="true"/>'
      '<geom size=".1"/></worldbody></mujoco>'
  )
  assert model.vis.quality.shadowsize == 4096  # MuJoCo's default
  assert rendering.shadow_map_size(model, 120, 160) == 1024
  assert rendering.shadow_map_size(model, 240, 320) == 2048
  assert rendering.shadow_map_size(model, 1080, 1920) == 4096  # the model's
  model.vis.quality.shadowsize = 512
  assert rendering.shadow_map_size(model, 240, 320) == 512
  model.vis.quality.shadowsize = 4096
  rendering.make_renderer(model, 24, 32).close()
  assert model.vis.quality.shadowsize == 4096  # the model keeps its own


def test_grid_png_and_gif(env, states, tmp_path):
  from PIL import Image  # pylint: disable=g-import-not-at-top

  images = rendering.render(env, states, worlds=[0, 1, 2], height=20, width=30)
  grid = rendering.image_grid(images, columns=2, padding=1)
  assert grid.shape == (2 * 20 + 1, 2 * 30 + 1, 3)
  np.testing.assert_array_equal(grid[21:, 31:], 255)  # the empty cell
  np.testing.assert_array_equal(rendering.image_grid(images)[:, :30], images[0])
  rendering.save_image(str(tmp_path / 'grid.png'), grid)
  np.testing.assert_array_equal(
      np.asarray(Image.open(tmp_path / 'grid.png').convert('RGB')), grid
  )
  frames = np.zeros((3, 20, 30, 3), np.uint8)
  frames[np.arange(3), :, :, np.arange(3)] = 255  # red, green, blue
  rendering.save_gif(str(tmp_path / 'clip.gif'), frames, fps=10)
  with Image.open(tmp_path / 'clip.gif') as gif:
    assert gif.n_frames == 3 and gif.size == (30, 20)


def test_no_backend_error_says_what_to_install(monkeypatch):
  monkeypatch.setattr(rendering, '_backend', None)
  monkeypatch.setattr(rendering, '_HEADLESS_BACKENDS', ('not-a-backend',))
  for name in ('MUJOCO_GL', 'DISPLAY', 'WAYLAND_DISPLAY'):
    monkeypatch.delenv(name, raising=False)
  monkeypatch.setattr(rendering.platform, 'system', lambda: 'Linux')
  with pytest.raises(RuntimeError, match='apt-get install libegl1'):
    rendering.gl_backend()
  assert os.environ.get('MUJOCO_GL') is None


def test_per_world_statistics_are_drawn(caplog):
  # Varying a geom size makes `stat` per world (the variator re-derives the
  # extent and centre); the render must take it, not warn and drop it.
  from mujoco import mjx  # pylint: disable=g-import-not-at-top

  model = mujoco.MjModel.from_xml_string(
      '<mujoco><worldbody><geom size=".1"/></worldbody></mujoco>'
  )
  stat = mjx.put_model(model).stat.replace(
      extent=np.float32(7.0), center=np.array([1.0, 2.0, 3.0], np.float32)
  )
  with caplog.at_level('WARNING'):
    rendering._set_model_field(model, 'stat', stat)  # pylint: disable=protected-access
  assert not caplog.records
  assert model.stat.extent == 7.0
  np.testing.assert_array_equal(model.stat.center, [1.0, 2.0, 3.0])
