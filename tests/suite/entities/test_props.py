"""Primitive props: shapes, frame sensors and their observables."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.suite.entities import props

_SHAPES = {
    'sphere': (props.Sphere, dict(radius=0.05), [0.05, 0.0, 0.0]),
    'box': (props.Box, dict(half_lengths=(0.1, 0.05, 0.02)), [0.1, 0.05, 0.02]),
    'capsule': (
        props.Capsule,
        dict(radius=0.03, half_length=0.1),
        [0.03, 0.1, 0.0],
    ),
    'cylinder': (
        props.Cylinder,
        dict(radius=0.04, half_length=0.06),
        [0.04, 0.06, 0.0],
    ),
    'ellipsoid': (
        props.Ellipsoid,
        dict(radii=(0.05, 0.06, 0.07)),
        [0.05, 0.06, 0.07],
    ),
}


def _quat_to_mat(q):
  mat = np.zeros(9)
  mujoco.mju_quat2Mat(mat, np.asarray(q, float) / np.linalg.norm(q))
  return mat.reshape(3, 3)


class PropsTask(composer.Task):
  """Every primitive and a ball, free, flying with random poses/velocities."""

  def __init__(self):
    self.arena = composer.Arena()
    self.props = {}
    for name, (cls, kwargs, _) in _SHAPES.items():
      # No collisions: MJX lacks some pairs (box-ellipsoid), and none matter.
      self.props[name] = cls(name=name, contype=0, conaffinity=0, **kwargs)
    self.props['ball'] = props.Ball()
    for prop in self.props.values():
      self.arena.add_free_entity(prop)
      prop.observables.enable_all()

  @property
  def root_entity(self):
    return self.arena

  def initialize_episode(self, physics, key):
    for i, prop in enumerate(self.props.values()):
      pos_key, quat_key, vel_key = jax.random.split(
          jax.random.fold_in(key, i), 3
      )
      physics = prop.set_pose(
          physics,
          jax.random.normal(pos_key, (3,)),
          jax.random.normal(quat_key, (4,)),
      )
      velocity = jax.random.normal(vel_key, (6,))
      physics = prop.set_velocity(physics, velocity[:3], velocity[3:])
    return physics

  def get_reward(self, physics):
    return 0.0


@pytest.fixture(scope='module')
def flying():
  task = PropsTask()
  env = composer.Environment(task, strip_singleton_obs_buffer_dim=True)
  states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), 8))
  return (
      task,
      env,
      jax.tree.map(
          np.asarray, states.replace(key=jax.random.key_data(states.key))
      ),
  )


@pytest.mark.parametrize('name', list(_SHAPES) + ['ball'])
def test_observables_match_hand_computed_values(flying, name):
  task, env, states = flying
  prop = task.props[name]
  assert isinstance(prop.observables, composer.FreePropObservableMixin)
  adr = env.mj_model.jnt_qposadr[env.mj_model.body(f'{name}/').jntadr[0]]
  dof = env.mj_model.jnt_dofadr[env.mj_model.body(f'{name}/').jntadr[0]]
  for world in range(8):
    qpos = states.data.qpos[world, adr : adr + 7]
    qvel = states.data.qvel[world, dof : dof + 6]
    obs = {
        key: states.observation[f'{name}/{key}'][world]
        for key in (
            'position',
            'orientation',
            'linear_velocity',
            'angular_velocity',
        )
    }
    quat = qpos[3:] / np.linalg.norm(qpos[3:])
    np.testing.assert_allclose(obs['position'], qpos[:3], atol=1e-5)
    # A quaternion and its negative are the same orientation.
    np.testing.assert_allclose(
        abs(np.dot(obs['orientation'], quat)), 1.0, atol=1e-5
    )
    # A freejoint's linear velocity is global, its angular velocity local.
    np.testing.assert_allclose(obs['linear_velocity'], qvel[:3], atol=1e-5)
    np.testing.assert_allclose(
        obs['angular_velocity'], _quat_to_mat(quat) @ qvel[3:], atol=1e-4
    )


def test_primitive_geoms_and_sensors(flying):
  task, env, _ = flying
  model = env.mj_model
  for name, (_, _, size) in _SHAPES.items():
    prop = task.props[name]
    geom = model.geom(f'{name}/geom')
    assert geom.type == prop.geom.type
    np.testing.assert_allclose(geom.size, size)
    # The geom sits in the attachment frame, as composer's (which carries
    # the freejoint).
    assert model.body(geom.bodyid[0]).name == f'{name}/'
    for sensor, kind in (
        (prop.position, mujoco.mjtSensor.mjSENS_FRAMEPOS),
        (prop.orientation, mujoco.mjtSensor.mjSENS_FRAMEQUAT),
        (prop.linear_velocity, mujoco.mjtSensor.mjSENS_FRAMELINVEL),
        (prop.angular_velocity, mujoco.mjtSensor.mjSENS_FRAMEANGVEL),
    ):
      assert sensor.type == kind
      compiled = model.sensor(f'{name}/{sensor.name}')
      assert compiled.objtype == mujoco.mjtObj.mjOBJ_GEOM
      assert compiled.objid == geom.id


def test_primitive_arguments():
  box = props.Primitive(
      'box', [0.1, 0.2, 0.3], name='crate', mass=2.0, rgba=(1, 0, 0, 1)
  )
  assert box.name == 'crate'
  assert box.geom.mass == 2.0
  np.testing.assert_allclose(box.geom.rgba, (1, 0, 0, 1))
  sphere = props.Primitive(mujoco.mjtGeom.mjGEOM_SPHERE, 0.1, mass=None)
  assert sphere.name == 'sphere'
  with pytest.raises(ValueError, match='takes 3 size numbers'):
    props.Primitive('box', [0.1, 0.2])
  with pytest.raises(ValueError, match='Unsupported primitive'):
    props.Primitive('mesh', [0.1])
  with pytest.raises(ValueError, match='Unsupported primitive'):
    props.Primitive(mujoco.mjtGeom.mjGEOM_PLANE, [1.0, 1.0, 1.0])
  # Defaults follow dm_control.manipulation.props.primitive.
  assert props.Box().geom.size.tolist() == [0.05, 0.1, 0.15]
  assert props.Capsule().name == 'capsule'
  assert jnp.shape(props.Ellipsoid().geom.size) == (3,)
