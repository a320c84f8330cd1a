"""HeightScan: equal to MuJoCo C's `mj_ray` on the same scene and rays.

The scene: a height field with random elevations, boxes (one rotated, one
transparent, one in a group the scan leaves out) and a free probe body the
scan's grid is attached to, placed at a random tilted pose per world. One
environment of 2 worlds is built for the module.
"""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.suite.locomotion import height_scan
from mjx_composer.utils import transformations

_WORLDS = 2


class _Probe(composer.Entity):

  def _build(self):
    self._spec = mujoco.MjSpec()
    self._spec.modelname = 'probe'
    self.body = self._spec.worldbody.add_body(name='body')
    self.body.add_geom(
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[0.1, 0.05, 0.03],
        group=3,
        contype=0,
        conaffinity=0,
    )

  @property
  def mjcf_model(self):
    return self._spec


class _ScanTask(composer.NullTask):

  def __init__(self, alignment):
    arena = composer.Arena()
    spec = arena.mjcf_model
    elevation = np.random.RandomState(0).uniform(size=(10, 12))
    spec.add_hfield(
        name='ground',
        size=[0.6, 0.5, 0.3, 0.1],
        nrow=10,
        ncol=12,
        userdata=elevation.ravel().tolist(),
    )
    world = spec.worldbody
    # A material (mjx.ray needs one in the model) on a scanned box.
    spec.add_material(name='stone', rgba=[0.5, 0.5, 0.5, 1])
    world.add_geom(
        type=mujoco.mjtGeom.mjGEOM_HFIELD,
        hfieldname='ground',
        pos=[0.1, 0.0, -0.05],
        quat=[np.cos(0.2), 0, 0, np.sin(0.2)],
    )
    box = mujoco.mjtGeom.mjGEOM_BOX
    world.add_geom(
        type=box, size=[0.1, 0.2, 0.3], pos=[0.2, 0.1, 0.1], material='stone'
    )
    world.add_geom(
        type=box,
        size=[0.15, 0.05, 0.2],
        pos=[-0.3, -0.2, 0.05],
        quat=[np.cos(0.4), 0, 0, np.sin(0.4)],
    )
    world.add_geom(  # Transparent: rays pass through it, as mj_ray's.
        type=box,
        size=[0.3, 0.3, 0.5],
        pos=[0.0, 0.3, 0.0],
        rgba=[1, 1, 1, 0],
    )
    world.add_geom(  # Another group: not scanned.
        type=box,
        size=[0.2, 0.2, 0.6],
        pos=[-0.4, 0.3, 0.0],
        group=2,
    )
    self.probe = _Probe()
    arena.add_free_entity(self.probe)
    super().__init__(arena)
    self.scan = height_scan.HeightScan(
        self.probe.body,
        size=(0.8, 0.6),
        resolution=0.2,
        alignment=alignment,
    )
    self.scan.enabled = True

  @property
  def task_observables(self):
    return {'height_scan': self.scan}

  def initialize_episode(self, physics, key):
    position_key, angle_key = jax.random.split(key)
    position = (
        jax.random.uniform(position_key, (3,), minval=-0.3, maxval=0.3)
        .at[2]
        .add(0.8)
    )
    angles = jax.random.uniform(angle_key, (3,), minval=-0.4, maxval=0.4)
    angles = angles.at[2].mul(8.0)  # Any heading.
    axis = (
        lambda i, a: jnp.zeros(4)
        .at[0]
        .set(jnp.cos(a / 2))
        .at[i + 1]
        .set(jnp.sin(a / 2))
    )
    quat = transformations.quat_mul(
        axis(2, angles[2]),
        transformations.quat_mul(axis(1, angles[1]), axis(0, angles[0])),
    )
    return self.probe.set_pose(physics, position, quat)


def _make(alignment):
  env = composer.Environment(_ScanTask(alignment))
  states = jax.jit(jax.vmap(env.reset))(
      jax.random.split(jax.random.key(1), _WORLDS)
  )

  @jax.jit
  @jax.vmap
  def scan(state):
    physics = env.physics(state)
    origins, frame = env.task.scan.ray_origins(physics)
    return env.task.scan.scan(physics), origins, frame

  return env, jax.device_get(states), jax.device_get(scan(states))


@pytest.fixture(scope='module', params=['yaw', 'base'])
def scanned(request):
  return _make(request.param)


def test_heights_equal_mj_ray(scanned):
  env, states, ((heights, distances, geoms), origins, frame) = scanned
  model = env.mj_model
  data = mujoco.MjData(model)
  hits = set()
  for world in range(_WORLDS):
    data.qpos[:] = states.data.qpos[world]
    mujoco.mj_kinematics(model, data)
    for i, origin in enumerate(origins[world]):
      geomid = np.zeros(1, np.int32)
      want = mujoco.mj_ray(
          model,
          data,
          origin.astype(np.float64),
          np.array([0.0, 0, -1]),
          np.array([1, 0, 0, 0, 0, 0], np.uint8),
          1,
          -1,
          geomid,
      )
      assert geoms[world, i] == geomid[0], (world, i)
      np.testing.assert_allclose(distances[world, i], want, atol=2e-5)
      seen = want if want >= 0 else 5.0
      np.testing.assert_allclose(
          heights[world, i], origin[2] - seen - frame[world, 2], atol=2e-5
      )
      hits.add(int(geomid[0]))
  # The rays met the height field, the scanned boxes and empty space.
  types = {model.geom_type[g] for g in hits if g >= 0}
  assert mujoco.mjtGeom.mjGEOM_HFIELD in types
  assert mujoco.mjtGeom.mjGEOM_BOX in types
  assert -1 in hits
  # The observation is the scan.
  np.testing.assert_allclose(
      states.observation['height_scan'][:, 0], heights, atol=1e-6
  )


def test_the_grid_follows_the_frame(scanned):
  env, states, (_, origins, frame) = scanned
  scan = env.task.scan
  assert origins.shape == (_WORLDS, 4 * 5, 3)
  np.testing.assert_allclose(scan.points[:5, 0], [-0.4, -0.2, 0, 0.2, 0.4])
  quat = states.data.qpos[:, 3:7]
  for world in range(_WORLDS):
    xmat = np.zeros(9)
    mujoco.mju_quat2Mat(xmat, quat[world].astype(np.float64))
    xmat = xmat.reshape(3, 3)
    offsets = origins[world] - frame[world] - [0, 0, 1.0]
    if scan.alignment == 'base':
      want = scan.points @ xmat[:, :2].T
    else:
      yaw = np.arctan2(xmat[1, 0], xmat[0, 0])
      c, s = np.cos(yaw), np.sin(yaw)
      want = np.concatenate(
          [
              scan.points @ np.array([[c, -s], [s, c]]).T,
              np.zeros((len(scan.points), 1)),
          ],
          axis=1,
      )
    np.testing.assert_allclose(offsets, want, atol=1e-5)


@pytest.mark.parametrize(
    'kwargs, match',
    [
        ({'size': (0.0, 1.0)}, 'size'),
        ({'resolution': -0.1}, 'resolution'),
        ({'alignment': 'roll'}, 'alignment'),
        ({'geomgroup': (1, 0)}, 'geomgroup'),
        ({'max_distance': float('inf')}, 'max_distance'),
        ({'points': [[0.0, 0.0, 1.0]]}, 'points'),
        ({'delay_steps': 2}, 'delay_steps'),
    ],
)
def test_bad_arguments_are_refused_by_name(kwargs, match):
  with pytest.raises((TypeError, ValueError), match=match):
    height_scan.HeightScan(_Probe().body, **kwargs)
  with pytest.raises(TypeError, match='frame'):
    height_scan.HeightScan('trunk')
