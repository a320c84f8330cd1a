"""Camera observables: images of a world, rendered on the device by ray casting.

composer's `MJCFCamera` and `MujocoCamera` render with OpenGL on the host. A
batched world lives on the device, so here each pixel casts one ray from the
camera with MJX's `mjx.ray`, under `jit` and `vmap` like every observable:

* the pinhole model is MuJoCo's: the camera looks along its frame's -z axis,
  +x right and +y up, with its vertical field of view `cam_fovy`; row 0 is
  the top of the image, as `mujoco.Renderer` returns it;
* `depth=True`: the distance along the optical axis to the first surface
  hit (as MuJoCo's depth rendering, linearized), `zfar * extent` where a ray
  hits nothing;
* `segmentation=True`: `(geom id, mjOBJ_GEOM)` of the geom hit, `(-1, -1)`
  for the background;
* otherwise an RGB image: each geom's `rgba` colour lit by a headlight (the
  surface normal is estimated from the neighbouring pixels' hit points),
  black background.

What differs from an OpenGL image: geoms are those `mjx.ray` intersects
(planes, spheres, capsules, ellipsoids, boxes and meshes; not cylinders or
height fields), in the geom groups MuJoCo shows by default (0, 1 and 2),
transparent ones (alpha 0) skipped; no textures, materials, shadows, lights
or skybox. Depth and segmentation are what MuJoCo's own ray casting
(`mj_ray`) gives for the same rays
(`tests/observation/observable/test_camera.py`).
Each pixel tests every geom, so the cost is `height x width x ngeom` ray-geom
tests per sample: keep images small (tens of pixels a side) for training.
"""

from __future__ import annotations

from dm_env import specs
import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np

from mjx_composer.model import pymjcf
from mjx_composer.observation.observable import base

# MuJoCo shows geom groups 0-2 by default (`mjvOption.geomgroup`).
_VISIBLE_GROUPS = (1, 1, 1, 0, 0, 0)
_AMBIENT = 0.3  # the share of a colour that the headlight does not scale


def camera_rays(model, data, camera_id, height, width):
  """World-frame unit ray directions (H, W, 3) and their optical-axis cosines."""
  tan_half = jnp.tan(jnp.deg2rad(model.cam_fovy[camera_id]) / 2)
  rows = (1 - 2 * (jnp.arange(height) + 0.5) / height) * tan_half
  cols = (2 * (jnp.arange(width) + 0.5) / width - 1) * tan_half * width / height
  x, y = jnp.meshgrid(cols, rows)
  local = jnp.stack([x, y, -jnp.ones_like(x)], axis=-1)
  local = local / jnp.linalg.norm(local, axis=-1, keepdims=True)
  world = local @ data.cam_xmat[camera_id].T
  return world, -local[..., 2]


def cast(model, data, camera_id, height, width):
  """Per pixel: (distance along the ray, geom id, direction, axis cosine)."""
  directions, cosines = camera_rays(model, data, camera_id, height, width)
  origin = data.cam_xpos[camera_id]
  if model.mat_rgba.shape[0] == 0:
    # MJX 3.17's `ray` reads `mat_rgba[geom_matid]` even where no geom has a
    # material, which fails for a model without materials; one dummy row
    # (read only through `geom_matid == -1`, which it ignores) avoids it.
    model = model.replace(mat_rgba=jnp.ones((1, 4), model.geom_rgba.dtype))
  distance, geom = jax.vmap(
      lambda v: mjx.ray(model, data, origin, v, geomgroup=_VISIBLE_GROUPS)
  )(directions.reshape(-1, 3))
  shape = (height, width)
  return distance.reshape(shape), geom.reshape(shape), directions, cosines


def render_depth(model, data, camera_id, height, width, far):
  distance, geom, _, cosines = cast(model, data, camera_id, height, width)
  return jnp.where(geom >= 0, distance * cosines, far).astype(jnp.float32)


def render_segmentation(model, data, camera_id, height, width):
  _, geom, _, _ = cast(model, data, camera_id, height, width)
  kind = jnp.where(geom >= 0, int(mujoco.mjtObj.mjOBJ_GEOM), -1)
  return jnp.stack([geom, kind], axis=-1).astype(jnp.int32)


def render_rgb(model, data, camera_id, height, width):
  """Each geom's colour under a headlight; black where nothing is hit."""
  distance, geom, directions, _ = cast(model, data, camera_id, height, width)
  hit = geom >= 0
  points = data.cam_xpos[camera_id] + directions * distance[..., None]

  # Surface normals from neighbouring hits on the same geom (forward
  # differences, backward at the last row and column).
  def difference(axis):
    ahead = jnp.roll(points, -1, axis=axis)
    behind = jnp.roll(points, 1, axis=axis)
    same_ahead = jnp.roll(geom, -1, axis=axis) == geom
    last = jnp.arange(points.shape[axis]) == points.shape[axis] - 1
    last = last[:, None] if axis == 0 else last[None, :]
    use_ahead = jnp.logical_and(same_ahead, jnp.logical_not(last))
    return jnp.where(use_ahead[..., None], ahead - points, points - behind)

  normal = jnp.cross(difference(1), difference(0))
  length = jnp.linalg.norm(normal, axis=-1, keepdims=True)
  facing = jnp.abs(jnp.sum(normal * directions, axis=-1, keepdims=True))
  light = jnp.where(length > 0, facing / jnp.maximum(length, 1e-12), 1.0)
  colour = model.geom_rgba[jnp.maximum(geom, 0), :3]
  shaded = colour * (_AMBIENT + (1 - _AMBIENT) * light)
  image = jnp.where(hit[..., None], shaded, 0.0)
  return jnp.round(jnp.clip(image, 0.0, 1.0) * 255).astype(jnp.uint8)


class _Camera(base.Observable):
  """What `MJCFCamera` and `MujocoCamera` share: options, specs, rendering."""

  def __init__(
      self,
      height,
      width,
      update_interval,
      buffer_size,
      delay,
      aggregator,
      corruptor,
      depth,
      segmentation,
  ):
    if depth and segmentation:
      raise ValueError(
          '`depth` and `segmentation` cannot both be True: make one camera '
          'observable for each.'
      )
    self._height = int(height)
    self._width = int(width)
    self._depth = bool(depth)
    self._segmentation = bool(segmentation)
    super().__init__(update_interval, buffer_size, delay, aggregator, corruptor)

  @property
  def height(self):
    return self._height

  @height.setter
  def height(self, value):
    self._height = int(value)

  @property
  def width(self):
    return self._width

  @width.setter
  def width(self, value):
    self._width = int(value)

  @property
  def depth(self):
    return self._depth

  @property
  def segmentation(self):
    return self._segmentation

  @property
  def array_spec(self):
    h, w = self._height, self._width
    if self._depth:
      return specs.BoundedArray((h, w), np.float32, 0.0, np.inf)
    if self._segmentation:
      return specs.BoundedArray((h, w, 2), np.int32, -1, np.iinfo(np.int32).max)
    return specs.BoundedArray((h, w, 3), np.uint8, 0, 255)

  def _camera_id(self, physics) -> int:
    raise NotImplementedError

  def _callable(self, physics):
    camera_id = self._camera_id(physics)
    h, w = self._height, self._width
    model, data = physics.model, physics.data
    if self._depth:
      mj_model = physics.mj_model
      far = float(mj_model.vis.map.zfar * mj_model.stat.extent)
      return lambda: render_depth(model, data, camera_id, h, w, far)
    if self._segmentation:
      return lambda: render_segmentation(model, data, camera_id, h, w)
    return lambda: render_rgb(model, data, camera_id, h, w)


class MJCFCamera(_Camera):
  """An image from an `MjsCamera` (composer's `MJCFCamera`; see the module).

  Args:
    mjcf_element: the `mujoco.MjsCamera`.
    height, width: the image size in pixels.
    update_interval, buffer_size, delay, aggregator, corruptor: as every
      observable's.
    depth: a depth image (H, W) in metres instead of colours.
    segmentation: a (H, W, 2) image of (geom id, object type) instead.
  """

  def __init__(
      self,
      mjcf_element,
      height=240,
      width=320,
      update_interval=1,
      buffer_size=None,
      delay=None,
      aggregator=None,
      corruptor=None,
      depth=False,
      segmentation=False,
  ):
    if not isinstance(mjcf_element, mujoco.MjsCamera) and not (
        pymjcf.is_element(mjcf_element)
        and pymjcf.kind_name(mjcf_element) == 'camera'
    ):
      raise ValueError(
          'MJCFCamera expects a `mujoco.MjsCamera` (e.g. '
          '`spec.worldbody.add_camera(...)`) or a PyMJCF camera, got '
          f'{type(mjcf_element).__name__} {mjcf_element!r}.'
      )
    self._mjcf_element = mjcf_element
    super().__init__(
        height,
        width,
        update_interval,
        buffer_size,
        delay,
        aggregator,
        corruptor,
        depth,
        segmentation,
    )

  @property
  def mjcf_element(self):
    return self._mjcf_element

  def _camera_id(self, physics) -> int:
    return int(physics.bind(self._mjcf_element).element_ids[0])


class MujocoCamera(_Camera):
  """An image from a camera given by its full name (composer's `MujocoCamera`)."""

  def __init__(
      self,
      camera_name,
      height=240,
      width=320,
      update_interval=1,
      buffer_size=None,
      delay=None,
      aggregator=None,
      corruptor=None,
      depth=False,
      segmentation=False,
  ):
    self._camera_name = camera_name
    super().__init__(
        height,
        width,
        update_interval,
        buffer_size,
        delay,
        aggregator,
        corruptor,
        depth,
        segmentation,
    )

  def _camera_id(self, physics) -> int:
    camera = physics.mj_model.camera(self._camera_name)  # KeyError if unknown
    return int(camera.id)
