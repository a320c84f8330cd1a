"""Host rendering of chosen worlds of a (batched) `State` with `mujoco.Renderer`.

    frames = rendering.render(env, states, worlds=[0, 1, 2, 3])  # (4, H, W, 3)
    rendering.save_image('worlds.png', rendering.image_grid(frames))

Each world is drawn with its own model: the per-world model fields that the
state carries (`State.model_fields`: colours, sizes, masses varied per
episode) are written into a host copy of the compiled `MjModel`, the world's
`qpos`/`qvel`/`act`/`ctrl`/mocap poses into a host `MjData`, and
`mj_forward` derives the rest, so what you see is the world the device
simulates. Task state that has no geometry (a sampled target, say) can be
drawn as `markers`. `render` makes an OpenGL context for each call; to draw
many frames (a video), keep one `WorldRenderer`, which reuses its context,
model and data and writes a world's model fields only when they change:

    with rendering.WorldRenderer(env, height=120, width=160) as renderer:
      for states in trajectory:
        frames.append(renderer.render(states))

Rendering is offscreen OpenGL. With no display (servers, CI) and `MUJOCO_GL`
unset, the first render picks a headless backend, EGL then OSMesa, by trying
each in a subprocess (a failed OpenGL platform cannot be retried in the same
process), and uses it for every later `mujoco.Renderer` in this process. Set
`MUJOCO_GL` before importing mujoco to choose yourself. If none works, the
error says what to install.
"""

from __future__ import annotations

import dataclasses
import importlib
import logging
import os
import platform
import subprocess
import sys
from typing import Any, Iterable, Sequence

import jax
import mujoco
import numpy as np

_HEADLESS_BACKENDS = ('egl', 'osmesa')
_INSTALL_HINT = (
    'Install a headless OpenGL: EGL (Debian/Ubuntu: apt-get install libegl1 '
    "libgl1-mesa-dri; NVIDIA machines: the driver's libEGL) or OSMesa "
    '(apt-get install libosmesa6), then set MUJOCO_GL=egl or MUJOCO_GL=osmesa '
    'before importing mujoco.'
)
_PROBE = (
    'import mujoco\n'
    'm = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom '
    "size='.1'/></worldbody></mujoco>\")\n"
    'r = mujoco.Renderer(m, 8, 8)\n'
    'r.update_scene(mujoco.MjData(m))\n'
    'r.render()\n'
    'r.close()\n'
)

_LOG = logging.getLogger(__name__)
_backend = None  # The backend chosen in this process.
_logged_skips = set()


def gl_backend() -> str:
  """The OpenGL backend renders use, choosing a headless one if needed.

  Raises:
    RuntimeError: if no display is available and neither EGL nor OSMesa
      works; the message says what to install.
  """
  global _backend
  if _backend is not None:
    return _backend
  chosen = os.environ.get('MUJOCO_GL', '').lower().strip()
  headless = (
      platform.system() == 'Linux'
      and not os.environ.get('DISPLAY')
      and not os.environ.get('WAYLAND_DISPLAY')
  )
  if chosen or not headless:
    # mujoco chose its context class from MUJOCO_GL when it was imported.
    _backend = chosen or 'default'
    return _backend
  errors = {}
  for backend in _HEADLESS_BACKENDS:
    env = dict(os.environ, MUJOCO_GL=backend)
    env.pop('PYOPENGL_PLATFORM', None)
    try:
      result = subprocess.run(
          [sys.executable, '-c', _PROBE],
          env=env,
          capture_output=True,
          text=True,
          timeout=120,
      )
    except subprocess.TimeoutExpired:
      errors[backend] = 'timed out'
      continue
    if result.returncode == 0:
      _use_backend(backend)
      _backend = backend
      return backend
    lines = (result.stderr or result.stdout).strip().splitlines()
    errors[backend] = lines[-1] if lines else f'exit {result.returncode}'
  tried = '; '.join(f'{k}: {v}' for k, v in errors.items())
  raise RuntimeError(
      f'No headless OpenGL backend works here ({tried}). ' f'{_INSTALL_HINT}'
  )


def _use_backend(backend: str):
  """Points mujoco.Renderer at `backend`'s GL context, as MUJOCO_GL would."""
  os.environ['MUJOCO_GL'] = backend  # for subprocesses (e.g. kernels)
  module = importlib.import_module(f'mujoco.{backend}')
  # mujoco binds its GLContext class when it is imported (from MUJOCO_GL);
  # mujoco was imported before we could choose, so rebind it here.
  gl_context = importlib.import_module('mujoco.rendering.classic.gl_context')
  gl_context.GLContext = module.GLContext


def shadow_map_size(model: mujoco.MjModel, height: int, width: int) -> int:
  """The side of the shadow map `make_renderer` draws `height x width` with.

  The model's (`visual/quality/shadowsize`, MuJoCo's default 4096) or, if
  smaller, the power of two at least four times the image's longer side
  (1024 at least). Software OpenGL (llvmpipe, OSMesa: what a server
  without a GPU renders with) draws a 4096-pixel shadow map per light for
  every image; for a 120 x 160 image, a 1024-pixel one cuts the time per
  image about three times and changes the mean pixel by less than a tenth
  of a level out of 255.
  """
  side = max(1024, 1 << (4 * max(height, width) - 1).bit_length())
  return min(int(model.vis.quality.shadowsize), side)


def make_renderer(
    model: mujoco.MjModel, height: int = 240, width: int = 320
) -> mujoco.Renderer:
  """A `mujoco.Renderer` on a headless backend; close it when done.

  Its shadow maps are `shadow_map_size` (the model keeps its own setting).
  """
  gl_backend()
  vis = model.vis.global_
  vis.offwidth = max(vis.offwidth, width)
  vis.offheight = max(vis.offheight, height)
  quality = model.vis.quality
  shadowsize = quality.shadowsize
  quality.shadowsize = shadow_map_size(model, height, width)
  try:
    return mujoco.Renderer(model, height, width)
  except Exception as e:  # pylint: disable=broad-except
    raise RuntimeError(
        f'Could not create an OpenGL context for rendering '
        f'(MUJOCO_GL={os.environ.get("MUJOCO_GL", "")!r}): {e}.'
        f' {_INSTALL_HINT}'
    ) from e
  finally:
    quality.shadowsize = shadowsize


def free_camera(
    model: mujoco.MjModel,
    distance=None,
    azimuth=None,
    elevation=None,
    lookat=None,
) -> mujoco.MjvCamera:
  """The model's default free camera, with any of its parameters replaced."""
  camera = mujoco.MjvCamera()
  mujoco.mjv_defaultFreeCamera(model, camera)
  if distance is not None:
    camera.distance = distance
  if azimuth is not None:
    camera.azimuth = azimuth
  if elevation is not None:
    camera.elevation = elevation
  if lookat is not None:
    camera.lookat[:] = lookat
  return camera


def _composer_state(state):
  # A Brax State from `adapters.brax.BraxEnv` carries ours as pipeline_state.
  return getattr(state, 'pipeline_state', state)


def _environment(env):
  # Accept adapters (BraxEnv) that wrap an Environment.
  return getattr(env, 'environment', env)


def _world_indices(num_worlds, worlds):
  if worlds is None:
    return list(range(num_worlds or 1))
  if isinstance(worlds, (int, np.integer)):
    worlds = [int(worlds)]
  worlds = [int(w) for w in worlds]
  limit = num_worlds or 1
  bad = [w for w in worlds if not -limit <= w < limit]
  if bad:
    raise IndexError(f'worlds {bad} out of range for a batch of {limit}.')
  return [w % limit for w in worlds]


def _same(a, b) -> bool:
  """Whether two host values (arrays, or structs of arrays) are equal."""
  leaves_a, leaves_b = jax.tree.leaves(a), jax.tree.leaves(b)
  return len(leaves_a) == len(leaves_b) and all(
      np.array_equal(x, y) for x, y in zip(leaves_a, leaves_b)
  )


def _set_model_field(model: mujoco.MjModel, name: str, value):
  """Writes one mjx.Model field's value for one world into a host MjModel."""
  if name in ('opt', 'stat'):
    # Option and statistic structs: copy the fields MjModel also has. The
    # statistics (extent, center) move the default free camera.
    target = getattr(model, name)
    for field in dataclasses.fields(value):
      if hasattr(target, field.name) and not field.name.startswith('_'):
        try:
          setattr(target, field.name, np.asarray(getattr(value, field.name)))
        except (TypeError, ValueError):
          pass
    return
  target = getattr(model, name, None)
  if isinstance(target, np.ndarray):
    value = np.asarray(value)
    if value.size == target.size:
      target[...] = value.reshape(target.shape)
      return
  if name not in _logged_skips:
    _logged_skips.add(name)
    _LOG.warning(
        'rendering: per-world model field %r is not drawn (no '
        'matching MjModel array).',
        name,
    )


_DATA_FIELDS = ('qpos', 'qvel', 'act', 'ctrl', 'mocap_pos', 'mocap_quat')


def host_fields(state) -> dict:
  """What drawing a `State` reads, copied to the host as numpy arrays.

  The data fields that `mj_forward` derives the rest from, the time and the
  per-world model fields, with the state's leading axes (worlds, or time
  and worlds). Fetch once and index it (`jax.tree.map(lambda x: x[t], ...)`)
  rather than copying a whole `State` per frame.
  """
  state = _composer_state(state)
  fields = {name: getattr(state.data, name) for name in _DATA_FIELDS}
  fields['time'] = state.data.time
  fields['model_fields'] = state.model_fields
  return jax.tree.map(np.asarray, jax.device_get(fields))


class WorldRenderer:
  """Draws worlds of one environment's states with one reused renderer.

  Holds a host copy of the compiled `MjModel`, an `MjData` and a
  `mujoco.Renderer` for its whole life, so drawing many frames (a video)
  creates no OpenGL context, model or data per frame: each world's
  per-world model fields are written into the model only where they differ
  from what it holds, its pose into the data, and `mj_forward` derives the
  rest. Close it when done (or use it as a context manager).

  A renderer uploads height fields to the GPU when it is made, so with
  per-world terrain each world gets a renderer of its own, made again only
  when its profile changes.
  """

  def __init__(
      self,
      env,
      height: int = 240,
      width: int = 320,
      *,
      camera: Any = None,
      marker_radius: float = 0.03,
      marker_rgba=(0.9, 0.1, 0.1, 0.8),
      scene_option: mujoco.MjvOption | None = None,
  ):
    """Makes the renderer.

    Args:
      env: the `Environment` (or a `BraxEnv`) whose states it draws.
      height, width: image size in pixels.
      camera: None (the model's free camera), a camera name or id, a
        `mujoco.MjvCamera`, or a dict of `free_camera` arguments.
      marker_radius, marker_rgba: the size and colour of `markers`' spheres.
      scene_option: an optional `mujoco.MjvOption` (e.g. to show sites).
    """
    env = _environment(env)
    # Per-world fields are written into a copy: the environment's host model
    # must keep its defaults.
    self.model = env.mj_model.__copy__()
    self.data = mujoco.MjData(self.model)
    if isinstance(camera, dict):
      camera = free_camera(self.model, **camera)
    elif camera is None:
      camera = free_camera(self.model)
    self._camera = camera
    self._scene_option = scene_option
    self._marker = (
        np.array([marker_radius, 0.0, 0.0]),
        np.asarray(marker_rgba, np.float32),
    )
    self._size = (height, width)
    self._written = {}  # field name -> the value the model holds
    self._renderer = make_renderer(self.model, height, width)
    self._terrain = {}  # world -> (its renderer, the profile it uploaded)

  def close(self):
    """Frees the OpenGL contexts."""
    # Close now: EGL's atexit teardown would otherwise run before the
    # renderer's finalizer and print errors at interpreter exit.
    for renderer, _ in self._terrain.values():
      renderer.close()
    self._terrain = {}
    if self._renderer is not None:
      self._renderer.close()
      self._renderer = None

  def __enter__(self):
    return self

  def __exit__(self, *unused_exc):
    self.close()

  def _write_model_fields(self, model_fields):
    for name, value in model_fields.items():
      if name not in self._written or not _same(self._written[name], value):
        _set_model_field(self.model, name, value)
        self._written[name] = jax.tree.map(np.copy, value)

  def _renderer_for(self, world, model_fields):
    if 'hfield_data' not in model_fields:
      return self._renderer
    profile = model_fields['hfield_data']
    renderer, uploaded = self._terrain.get(world, (None, None))
    if renderer is None or not np.array_equal(uploaded, profile):
      if renderer is not None:
        renderer.close()
      renderer = make_renderer(self.model, *self._size)
      self._terrain[world] = (renderer, np.copy(profile))
    return renderer

  def render(self, state, worlds=None, *, markers=None, out=None):
    """Draws chosen worlds of a `State` (or of `host_fields` of one).

    Args:
      state: a `State` batched over worlds (leading axis) or for one world,
        a Brax state made by `BraxEnv`, or `host_fields` of either.
      worlds: an index or indices into the batch; None for every world.
      markers: optional positions to draw as spheres, per world of the
        batch: shape `(num_worlds, 3)` or `(num_worlds, K, 3)` (without the
        world axis for an unbatched state), e.g.
        `state.task_state['target']`.
      out: optional uint8 array `(len(worlds), height, width, 3)` to draw
        into (saves an allocation per call).

    Returns:
      uint8 images `(len(worlds), height, width, 3)`; `(height, width, 3)`
      if `worlds` is an int or the state is for one world and `worlds` is
      None.
    """
    if self._renderer is None:
      raise RuntimeError('This WorldRenderer is closed; make a new one.')
    host = state if isinstance(state, dict) else host_fields(state)
    batched = np.ndim(host['time']) == 1
    num_worlds = np.shape(host['time'])[0] if batched else None
    single = isinstance(worlds, (int, np.integer)) or (
        worlds is None and not batched
    )
    indices = _world_indices(num_worlds, worlds)
    if markers is not None:
      markers = np.asarray(markers, np.float64)
      if not batched:
        markers = markers[None]
      markers = markers.reshape(markers.shape[0], -1, 3)
    if out is None:
      out = np.empty((len(indices),) + self._size + (3,), np.uint8)
    for i, world in enumerate(indices):
      pick = (lambda x, w=world: x[w]) if batched else (lambda x: x)
      model_fields = jax.tree.map(pick, host['model_fields'])
      self._write_model_fields(model_fields)
      renderer = self._renderer_for(world, model_fields)
      for name in _DATA_FIELDS:
        target = getattr(self.data, name)
        if target.size:
          target[...] = pick(host[name]).reshape(target.shape)
      self.data.time = float(pick(host['time']))
      mujoco.mj_forward(self.model, self.data)
      renderer.update_scene(
          self.data, camera=self._camera, scene_option=self._scene_option
      )
      if markers is not None:
        for position in markers[world if batched else 0]:
          _add_sphere(renderer.scene, position, *self._marker)
      renderer.render(out=out[i])
    return out[0] if single else out


def render(
    env,
    state,
    worlds=None,
    *,
    height: int = 240,
    width: int = 320,
    camera: Any = None,
    markers=None,
    marker_radius: float = 0.03,
    marker_rgba=(0.9, 0.1, 0.1, 0.8),
    scene_option: mujoco.MjvOption | None = None,
) -> np.ndarray:
  """Renders chosen worlds of a `State` on the host.

  One call makes and closes a `WorldRenderer` (`env`, the size, `camera`,
  the markers' look and `scene_option` are its arguments) and returns its
  `render(state, worlds, markers=markers)`: uint8 images
  `(len(worlds), height, width, 3)`, or `(height, width, 3)` if `worlds` is
  an int or the state is for one world and `worlds` is None. To draw many
  frames (a video), keep one `WorldRenderer` instead.
  """
  with WorldRenderer(
      env,
      height,
      width,
      camera=camera,
      marker_radius=marker_radius,
      marker_rgba=marker_rgba,
      scene_option=scene_option,
  ) as renderer:
    return renderer.render(state, worlds, markers=markers)


_IDENTITY = np.eye(3).reshape(-1)


def _add_sphere(scene: mujoco.MjvScene, position, size, rgba):
  """Appends a sphere (`size`: `[radius, 0, 0]`) to the scene's geoms."""
  if scene.ngeom >= scene.maxgeom:
    return
  mujoco.mjv_initGeom(
      scene.geoms[scene.ngeom],
      type=mujoco.mjtGeom.mjGEOM_SPHERE,
      size=size,
      pos=np.asarray(position, np.float64),
      mat=_IDENTITY,
      rgba=rgba,
  )
  scene.ngeom += 1


def image_grid(
    images: Sequence[np.ndarray] | np.ndarray,
    columns=None,
    padding: int = 2,
    fill: int = 255,
) -> np.ndarray:
  """Tiles images `(N, H, W, C)` into one image, row by row.

  `columns` defaults to all in one row (a strip).
  """
  images = np.asarray(images)
  if images.ndim == 3:
    images = images[None]
  n, h, w, c = images.shape
  columns = n if columns is None else max(1, min(int(columns), n))
  rows = -(-n // columns)
  grid = np.full(
      (
          rows * h + (rows - 1) * padding,
          columns * w + (columns - 1) * padding,
          c,
      ),
      fill,
      images.dtype,
  )
  for i, image in enumerate(images):
    r, col = divmod(i, columns)
    grid[
        r * (h + padding) : r * (h + padding) + h,
        col * (w + padding) : col * (w + padding) + w,
    ] = image
  return grid


def save_image(path: str, image: np.ndarray):
  """Writes an RGB uint8 image as PNG (Pillow if present, else matplotlib)."""
  image = np.asarray(image, np.uint8)
  try:
    from PIL import Image  # pylint: disable=g-import-not-at-top
  except ImportError:
    import matplotlib.pyplot as plt  # pylint: disable=g-import-not-at-top

    plt.imsave(path, image)
    return
  Image.fromarray(image).save(path)


def save_gif(path: str, frames: Iterable[np.ndarray], fps: float = 25.0):
  """Writes frames `(T, H, W, 3)` uint8 as a looping GIF (needs Pillow)."""
  try:
    from PIL import Image  # pylint: disable=g-import-not-at-top
  except ImportError as e:
    raise ImportError('save_gif needs Pillow: pip install pillow') from e
  frames = [Image.fromarray(np.asarray(f, np.uint8)) for f in frames]
  if not frames:
    raise ValueError('save_gif needs at least one frame.')
  frames[0].save(
      path,
      save_all=True,
      append_images=frames[1:],
      loop=0,
      duration=max(1, int(round(1000 / fps))),
  )
