"""Height scan: the terrain's heights on a grid around a robot, by ray casts.

Isaac Lab's and mjlab's `height_scan` observation (a `RayCaster` with a grid
pattern): rays are cast straight down from a grid of points around a frame
(a body or site of an entity, e.g. a robot's trunk) and each returns the
height of what it hits relative to the frame. Here it is an observable: it
is traced into the step like any other, batched over worlds, and the
observation system's options (noise, delay, history, rate) apply.

What the rays hit: geoms of the groups in `geomgroup` (MuJoCo's
inclusion mask, as `mj_ray` takes it), static or not, with the same
visibility rule as `mj_ray` (a geom whose colour is fully transparent is
skipped). Primitive and mesh geoms are intersected by `mjx.ray`; height
fields, which `mjx.ray` does not intersect, by the height field's surface
triangles (each grid cell split along the diagonal from its lower-left to
its upper-right corner, as MuJoCo's collision and `mj_ray` split it), read
from this world's `hfield_data` so a per-world terrain is scanned as it is.
The result equals `mj_ray`'s on the same scene and rays
(`tests/suite/locomotion/test_height_scan.py`).

The rays always point down the world's z axis (a height scan measures
heights); `alignment` says how the grid follows the frame: 'yaw' (rotated by
the frame's heading only, Isaac Lab's default), 'base' (the frame's full
orientation: the grid tilts with the body) or 'world' (not rotated).
"""

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np

from mjx_composer.model import element_index
from mjx_composer.observation import observable
from mjx_composer.suite.locomotion.terrain import surface as terrain_surface
from mjx_composer.utils import validation

ALIGNMENTS = ('yaw', 'base', 'world')
_OWNER = 'HeightScan'
_DOWN = np.array([0.0, 0.0, -1.0], np.float32)


def grid_pattern(size, resolution):
  """Isaac Lab's grid pattern: (n, 2) points of a `size` rectangle.

  Points every `resolution` metres from `-size / 2` to `size / 2` (both
  included where the size is a multiple of the resolution), x varying
  fastest.
  """
  size = np.asarray(validation.check_positive('size', size, owner=_OWNER))
  if size.shape != (2,):
    raise ValueError(
        f'{_OWNER}: size must be (length, width) in metres, got {size!r}.'
    )
  resolution = validation.check_positive('resolution', resolution, owner=_OWNER)
  xs = np.arange(-size[0] / 2, size[0] / 2 + 1e-6, resolution)
  ys = np.arange(-size[1] / 2, size[1] / 2 + 1e-6, resolution)
  grid_x, grid_y = np.meshgrid(xs, ys, indexing='xy')
  return np.stack([grid_x.ravel(), grid_y.ravel()], axis=-1).astype(np.float32)


def _yaw_matrix(xmat):
  """The rotation about z with the heading of `xmat`'s x axis."""
  heading = jnp.arctan2(xmat[1, 0], xmat[0, 0])
  c, s = jnp.cos(heading), jnp.sin(heading)
  zero, one = jnp.zeros_like(c), jnp.ones_like(c)
  return jnp.stack(
      [
          jnp.stack([c, -s, zero]),
          jnp.stack([s, c, zero]),
          jnp.stack([zero, zero, one]),
      ]
  )


class HeightScan(observable.Observable):
  """Heights of the terrain below a grid of points around a frame.

  Each ray starts `ray_start` metres above its grid point and the
  observation is, per ray, the height of the hit relative to the frame's
  origin (`hit_z - frame_z`, so the ground below a standing robot reads
  about minus its height); a ray that hits nothing within `max_distance`
  reads `ray_start - max_distance` below its grid point.

  Args:
    frame: an MjSpec body or site (e.g. `robot.root_body`) the grid is
      attached to.
    size: (length along x, width along y) of the grid, metres.
    resolution: spacing of the grid's points, metres.
    points: alternatively, the pattern's (n, 2) points in the frame
      (overrides `size` and `resolution`).
    alignment: 'yaw', 'base' or 'world' (module docstring).
    geomgroup: MuJoCo's geom group mask (6 flags): the groups the rays hit.
      Leave the robot's own geoms' groups out.
    ray_start: height of the rays' origins above the grid points, metres.
    max_distance: the farthest a ray sees, metres.
    **options: the observable's options (`update_interval`, `buffer_size`,
      `delay`, `aggregator`, `corruptor`).
  """

  def __init__(
      self,
      frame,
      size=(1.6, 1.0),
      resolution=0.1,
      points=None,
      alignment='yaw',
      geomgroup=(1, 0, 0, 0, 0, 0),
      ray_start=1.0,
      max_distance=5.0,
      **options,
  ):
    try:
      kind = element_index.element_kind(frame).name
    except TypeError:
      kind = None
    if kind not in ('body', 'site'):
      raise TypeError(
          f'{_OWNER}: frame must be an MjSpec body or site (e.g. '
          f'robot.root_body), got {frame!r}.'
      )
    self._frame = frame
    if points is None:
      points = grid_pattern(size, resolution)
    else:
      points = np.asarray(
          validation.check_finite('points', points, owner=_OWNER), np.float32
      )
      if points.ndim != 2 or points.shape[1] != 2 or not len(points):
        raise ValueError(
            f'{_OWNER}: points must be an (n, 2) array of (x, y) in the '
            f'frame, got shape {points.shape}.'
        )
    self._points = np.concatenate(
        [points, np.zeros((len(points), 1), np.float32)], axis=1
    )
    self._alignment = validation.check_choice(
        'alignment', alignment, ALIGNMENTS, owner=_OWNER
    )
    mask = np.asarray(geomgroup)
    if mask.shape != (mujoco.mjNGROUP,) or not all(
        isinstance(g, (bool, int, float)) and g in (0, 1) for g in mask.tolist()
    ):
      raise ValueError(
          f'{_OWNER}: geomgroup must be {mujoco.mjNGROUP} flags, each 0 or 1 '
          f'(or a bool), got {geomgroup!r}. Pass e.g. (1, 0, 0, 0, 0, 0) for '
          'group 0 only.'
      )
    self._geomgroup = tuple(int(bool(g)) for g in mask)
    self._ray_start = validation.check_finite(
        'ray_start', ray_start, owner=_OWNER
    )
    self._max_distance = validation.check_positive(
        'max_distance', max_distance, owner=_OWNER
    )
    unknown = set(options) - {
        'update_interval',
        'buffer_size',
        'delay',
        'aggregator',
        'corruptor',
    }
    if unknown:
      raise TypeError(
          f'{_OWNER}: unknown arguments {sorted(unknown)}; the observable '
          'options are update_interval, buffer_size, delay, aggregator and '
          'corruptor.'
      )
    super().__init__(
        options.get('update_interval', 1),
        options.get('buffer_size'),
        options.get('delay'),
        options.get('aggregator'),
        options.get('corruptor'),
    )

  @property
  def points(self):
    """The pattern's (n, 2) points in the frame."""
    return self._points[:, :2].copy()

  @property
  def alignment(self):
    return self._alignment

  def _callable(self, physics):
    return lambda: self.scan(physics)[0]

  def ray_origins(self, physics):
    """This world's rays' origins (n, 3) and the frame's position (3,)."""
    frame = physics.bind(self._frame)
    position, xmat = frame.xpos, frame.xmat.reshape(3, 3)
    if self._alignment == 'yaw':
      rotation = _yaw_matrix(xmat)
    elif self._alignment == 'base':
      rotation = xmat
    else:
      rotation = jnp.eye(3, dtype=position.dtype)
    points = position + jnp.asarray(self._points) @ rotation.T
    return points.at[:, 2].add(self._ray_start), position

  def scan(self, physics):
    """`(heights (n,), distances (n,), geom ids (n,))` of this world's rays.

    A distance is -1 and a geom id -1 where the ray hits nothing within
    `max_distance` (as `mj_ray` reports a miss).
    """
    origins, position = self.ray_origins(physics)
    model = physics.mj_model
    groups = np.asarray(self._geomgroup, bool)[
        np.clip(model.geom_group, 0, mujoco.mjNGROUP - 1)
    ]
    # mj_ray's visibility rule: a transparent geom (or material) is skipped.
    visible = model.geom_rgba[:, 3] != 0
    if model.nmat:
      visible = np.where(
          model.geom_matid >= 0,
          model.mat_rgba[np.maximum(model.geom_matid, 0), 3] != 0,
          visible,
      )
    selected = groups & visible
    hfields = np.flatnonzero(
        selected & (model.geom_type == mujoco.mjtGeom.mjGEOM_HFIELD)
    )
    down = jnp.asarray(_DOWN)
    distance = jnp.full(origins.shape[0], jnp.inf, origins.dtype)
    geom = jnp.full(origins.shape[0], -1, jnp.int32)
    if np.any(selected & (model.geom_type != mujoco.mjtGeom.mjGEOM_HFIELD)):
      ray = lambda origin: mjx.ray(
          physics.model, physics.data, origin, down, self._geomgroup
      )
      dist, ids = jax.vmap(ray)(origins)
      hit = dist >= 0
      distance = jnp.where(hit, dist, distance)
      geom = jnp.where(hit, ids, geom)
    for hfield_geom in hfields:
      _check_flat(model, hfield_geom)
      dist = jax.vmap(
          lambda origin, g=int(hfield_geom): self._hfield_distance(
              physics, g, origin
          )
      )(origins)
      closer = dist < distance
      distance = jnp.where(closer, dist, distance)
      geom = jnp.where(closer, int(hfield_geom), geom)
    missed = distance > self._max_distance
    geom = jnp.where(missed, -1, geom)
    distance = jnp.where(missed, -1.0, distance)
    seen = jnp.where(missed, self._max_distance, distance)
    heights = origins[:, 2] - seen - position[2]
    return heights, distance, geom

  def _hfield_distance(self, physics, geom, origin):
    """How far down from `origin` a vertical ray meets height field `geom`."""
    model = physics.mj_model
    hfield = int(model.geom_dataid[geom])
    nrow, ncol = int(model.hfield_nrow[hfield]), int(model.hfield_ncol[hfield])
    start = int(model.hfield_adr[hfield])
    size = model.hfield_size[hfield]
    data = physics.model.hfield_data[start : start + nrow * ncol]
    xmat = physics.data.geom_xmat[geom]
    local = xmat.T @ (origin - physics.data.geom_xpos[geom])
    # Interpolated elevation, then scaled: the grid itself is not scaled.
    elevation, inside = terrain_surface.surface_height(
        data.reshape(nrow, ncol), size[:2], local[:2]
    )
    distance = local[2] - size[2] * elevation
    return jnp.where(inside & (distance >= 0), distance, jnp.inf)


def _check_flat(model, geom):
  """A height field in the world body must face up for vertical rays."""
  if model.geom_bodyid[geom] != 0:
    return
  xmat = np.zeros(9)
  mujoco.mju_quat2Mat(xmat, model.geom_quat[geom])
  if abs(xmat[8] - 1.0) > 1e-6:
    raise ValueError(
        f'{_OWNER}: the height field geom {model.geom(geom).name!r} is tilted'
        " (its z axis is not the world's): the scan casts vertical rays "
        'through height fields that face up only. Rotate it about z only.'
    )
