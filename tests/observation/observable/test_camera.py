"""Camera observables: ray-cast images against MuJoCo's ray casting and OpenGL."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.host import rendering
from mjx_composer.observation import observable

_H, _W = 24, 32


class CameraTask(composer.Task):
  """A floor, three primitives and a camera looking down at them."""

  def __init__(self):
    self.arena = composer.Arena()
    spec = self.arena.mjcf_model
    spec.worldbody.add_geom(
        name='floor',
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[2, 2, 0.1],
        rgba=[0.5, 0.5, 0.5, 1],
    )
    body = spec.worldbody.add_body(name='props', pos=[0, 0, 0.1])
    # MJX steps models with degrees of freedom only.
    body.add_joint(
        name='lift', type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[0, 0, 1]
    )
    body.add_geom(
        name='red_box',
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[0.1, 0.1, 0.1],
        pos=[0.2, 0, 0],
        rgba=[1, 0, 0, 1],
    )
    body.add_geom(
        name='green_ball',
        type=mujoco.mjtGeom.mjGEOM_SPHERE,
        size=[0.12, 0, 0],
        pos=[-0.2, 0.1, 0.02],
        rgba=[0, 1, 0, 1],
    )
    body.add_geom(
        name='blue_capsule',
        type=mujoco.mjtGeom.mjGEOM_CAPSULE,
        size=[0.05, 0.15, 0],
        pos=[0, -0.3, 0],
        euler=[0, 1.57, 0],
        rgba=[0, 0, 1, 1],
    )
    self.camera = spec.worldbody.add_camera(
        name='eye', pos=[0.3, -0.9, 0.9], xyaxes=[1, 0.3, 0, -0.2, 0.7, 0.7],
        fovy=50,
    )  # fmt: skip
    camera = lambda **kw: observable.MJCFCamera(self.camera, _H, _W, **kw)
    self.images = {
        'rgb': camera(),
        'depth': camera(depth=True),
        'segmentation': camera(segmentation=True),
        'by_name': observable.MujocoCamera('eye', _H, _W, depth=True),
    }
    for image in self.images.values():
      image.enabled = True

  @property
  def root_entity(self):
    return self.arena

  @property
  def task_observables(self):
    return self.images

  def get_reward(self, physics):
    return jnp.zeros(())


@pytest.fixture(scope='module')
def rendered():
  env = composer.Environment(CameraTask())
  state = jax.jit(env.reset)(jax.random.key(0))
  data = mujoco.MjData(env.mj_model)
  data.qpos[:] = np.asarray(state.data.qpos)
  mujoco.mj_forward(env.mj_model, data)
  # Without an aggregator an observation is a buffer of one sample.
  images = {name: np.asarray(v)[0] for name, v in state.observation.items()}
  return env, images, data


def _host_rays(model, data, camera):
  """MuJoCo's own ray casting (float64) for the same pinhole rays."""
  tan_half = np.tan(np.deg2rad(model.cam_fovy[camera]) / 2)
  depth = np.zeros((_H, _W))
  geoms = np.zeros((_H, _W), np.int32)
  geom_id = np.zeros(1, np.int32)
  groups = np.array([1, 1, 1, 0, 0, 0], np.uint8)
  for r in range(_H):
    for c in range(_W):
      local = np.array([
          (2 * (c + 0.5) / _W - 1) * tan_half * _W / _H,
          (1 - 2 * (r + 0.5) / _H) * tan_half,
          -1.0,
      ])  # fmt: skip
      local /= np.linalg.norm(local)
      direction = data.cam_xmat[camera].reshape(3, 3) @ local
      dist = mujoco.mj_ray(
          model, data, data.cam_xpos[camera], direction, groups, 1, -1, geom_id
      )
      geoms[r, c] = geom_id[0]
      depth[r, c] = dist * -local[2] if geom_id[0] >= 0 else np.nan
  return depth, geoms


def test_specs_and_shapes(rendered):
  env, observation, _ = rendered
  spec = env.observation_spec()
  assert spec['rgb'].shape == (1, _H, _W, 3) and spec['rgb'].dtype == np.uint8
  assert spec['depth'].shape == (1, _H, _W)
  assert spec['depth'].dtype == np.float32
  assert spec['segmentation'].shape == (1, _H, _W, 2)
  for name, value in observation.items():
    assert (1,) + value.shape == spec[name].shape
    assert value.dtype == spec[name].dtype


def test_depth_and_segmentation_are_mujocos_ray_casting(rendered):
  env, observation, data = rendered
  model = env.mj_model
  depth, geoms = _host_rays(model, data, model.camera('eye').id)
  segmentation = np.asarray(observation['segmentation'])
  # Every geom is seen; float32 against float64 may flip a silhouette pixel.
  assert set(np.unique(geoms)) == set(range(model.ngeom))
  same = segmentation[..., 0] == geoms
  assert same.mean() > 0.99
  np.testing.assert_array_equal(
      segmentation[..., 1][same], int(mujoco.mjtObj.mjOBJ_GEOM)
  )
  ours = np.asarray(observation['depth'])
  np.testing.assert_allclose(ours[same], depth[same], rtol=1e-4)
  np.testing.assert_array_equal(ours, np.asarray(observation['by_name']))


def test_images_agree_with_mujocos_opengl_renderer(rendered):
  env, observation, data = rendered
  model = env.mj_model
  camera = model.camera('eye').id
  with rendering.make_renderer(model, _H, _W) as renderer:
    renderer.enable_segmentation_rendering()
    renderer.update_scene(data, camera=camera)
    segmentation = renderer.render()
    renderer.disable_segmentation_rendering()
    renderer.enable_depth_rendering()
    renderer.update_scene(data, camera=camera)
    depth = renderer.render()
  ours = np.asarray(observation['segmentation'])
  # Rasterization and ray casting differ on silhouette pixels only.
  same = ours[..., 0] == segmentation[..., 0]
  assert same.mean() > 0.95
  # OpenGL draws spheres and capsules as polygons: their depth differs by
  # up to about 0.5% from the exact surface; everything else agrees closely.
  ours_depth = np.asarray(observation['depth'])[same]
  assert np.isclose(ours_depth, depth[same], rtol=2e-3).mean() > 0.98
  np.testing.assert_allclose(ours_depth, depth[same], rtol=1e-2)


def test_colours_are_the_geoms_under_a_headlight(rendered):
  env, observation, _ = rendered
  rgb = np.asarray(observation['rgb']).astype(int)
  geoms = np.asarray(observation['segmentation'])[..., 0]
  model = env.mj_model
  for name, channel in (('red_box', 0), ('green_ball', 1), ('blue_capsule', 2)):
    pixels = rgb[geoms == model.geom(name).id]
    assert len(pixels)
    others = np.delete(pixels, channel, axis=1)
    assert np.all(pixels[:, channel] >= 0.3 * 255 - 1)  # at least ambient
    assert np.all(others == 0)
  floor = rgb[geoms == model.geom('floor').id]
  assert np.all(floor[:, 0] == floor[:, 1]) and np.all(
      floor[:, 1] == floor[:, 2]
  )


def test_bad_arguments_are_refused():
  task = CameraTask()
  with pytest.raises(ValueError, match='cannot both be True'):
    observable.MJCFCamera(task.camera, depth=True, segmentation=True)
  with pytest.raises(ValueError, match='expects a `mujoco.MjsCamera`'):
    observable.MJCFCamera(task.arena.mjcf_model.worldbody)
