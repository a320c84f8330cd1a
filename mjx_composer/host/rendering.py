"""Host rendering of chosen worlds of a (batched) `State` with `mujoco.Renderer`.

    frames = rendering.render(env, states, worlds=[0, 1, 2, 3])  # (4, H, W, 3)
    rendering.save_image('worlds.png', rendering.image_grid(frames))

Each world is drawn with its own model: the per-world model fields that the
state carries (`State.model_fields`: colours, sizes, masses varied per
episode) are written into a host copy of the compiled `MjModel`, the world's
`qpos`/`qvel`/`act`/`ctrl`/mocap poses into a host `MjData`, and
`mj_forward` derives the rest, so what you see is the world the device
simulates. Task state that has no geometry (a sampled target, say) can be
drawn as `markers`.

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


def make_renderer(
    model: mujoco.MjModel, height: int = 240, width: int = 320
) -> mujoco.Renderer:
  """A `mujoco.Renderer` on a headless backend; close it when done."""
  gl_backend()
  vis = model.vis.global_
  vis.offwidth = max(vis.offwidth, width)
  vis.offheight = max(vis.offheight, height)
  try:
    return mujoco.Renderer(model, height, width)
  except Exception as e:  # pylint: disable=broad-except
    raise RuntimeError(
        f'Could not create an OpenGL context for rendering '
        f'(MUJOCO_GL={os.environ.get("MUJOCO_GL", "")!r}): {e}.'
        f' {_INSTALL_HINT}'
    ) from e


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

  Args:
    env: the `Environment` (or a `BraxEnv`) the state belongs to.
    state: a `State`, batched over worlds (leading axis) or for one world;
      or a Brax state made by `BraxEnv`.
    worlds: an index or indices into the batch; None for every world.
    height, width: image size in pixels.
    camera: None (the model's free camera), a camera name or id, a
      `mujoco.MjvCamera`, or a dict of `free_camera` arguments.
    markers: optional positions to draw as spheres, per world of the batch:
      shape `(num_worlds, 3)` or `(num_worlds, K, 3)` (without the world axis
      for an unbatched state), e.g. `state.task_state['target']`.
    marker_radius, marker_rgba: the spheres' size and colour.
    scene_option: an optional `mujoco.MjvOption` (e.g. to show sites).

  Returns:
    uint8 images `(len(worlds), height, width, 3)`; `(height, width, 3)` if
    `worlds` is an int or the state is for one world and `worlds` is None.
  """
  env = _environment(env)
  state = _composer_state(state)
  host = jax.device_get(
      {
          'qpos': state.data.qpos,
          'qvel': state.data.qvel,
          'act': state.data.act,
          'ctrl': state.data.ctrl,
          'mocap_pos': state.data.mocap_pos,
          'mocap_quat': state.data.mocap_quat,
          'time': state.data.time,
          'model_fields': state.model_fields,
      }
  )
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

  model = _copy_model(env.mj_model)
  data = mujoco.MjData(model)
  if isinstance(camera, dict):
    camera = free_camera(model, **camera)
  elif camera is None:
    camera = free_camera(model)
  images = []
  # A renderer uploads height fields to the GPU when it is made: with
  # per-world terrain, each world gets a renderer made after its profile is
  # written.
  per_world_terrain = 'hfield_data' in host['model_fields']
  renderer = make_renderer(model, height, width)
  try:
    for world in indices:
      pick = (lambda x, w=world: np.asarray(x)[w]) if batched else np.asarray
      for name, value in host['model_fields'].items():
        _set_model_field(model, name, jax.tree.map(pick, value))
      if per_world_terrain:
        renderer.close()
        renderer = make_renderer(model, height, width)
      for name in ('qpos', 'qvel', 'act', 'ctrl', 'mocap_pos', 'mocap_quat'):
        target = getattr(data, name)
        if target.size:
          target[...] = pick(host[name]).reshape(target.shape)
      data.time = float(pick(host['time']))
      mujoco.mj_forward(model, data)
      renderer.update_scene(data, camera=camera, scene_option=scene_option)
      if markers is not None:
        for position in markers[world if batched else 0]:
          _add_sphere(renderer.scene, position, marker_radius, marker_rgba)
      images.append(renderer.render().copy())
  finally:
    # Close now: EGL's atexit teardown would otherwise run before the
    # renderer's finalizer and print errors at interpreter exit.
    renderer.close()
  images = np.stack(images)
  return images[0] if single else images


def _copy_model(model: mujoco.MjModel) -> mujoco.MjModel:
  # Per-world fields are written into a copy: the environment's host model
  # must keep its defaults.
  return model.__copy__()


def _add_sphere(scene: mujoco.MjvScene, position, radius, rgba):
  if scene.ngeom >= scene.maxgeom:
    return
  mujoco.mjv_initGeom(
      scene.geoms[scene.ngeom],
      type=mujoco.mjtGeom.mjGEOM_SPHERE,
      size=np.array([radius, 0.0, 0.0]),
      pos=np.asarray(position, np.float64),
      mat=np.eye(3).reshape(-1),
      rgba=np.asarray(rgba, np.float32),
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
