"""Observables reading a real `Physics`: MJCFFeature (mjcf_test) and
MujocoFeature (base_test), checked against MuJoCo's C `mj_forward`."""

import collections

import jax
import mujoco
from mujoco import mjx
import numpy as np
import pytest

from mjx_composer.model import element_index
from mjx_composer import physics as physics_lib
from mjx_composer.observation import updater as updater_lib
from mjx_composer.observation.observable import base
from mjx_composer.observation.observable import mjcf


class _Model:
  """A small arm and a free ball, with host data after `mj_forward`."""

  def __init__(self):
    spec = mujoco.MjSpec()
    no_contacts = dict(contype=0, conaffinity=0)  # keeps forward cheap
    self.arm = spec.worldbody.add_body(name='arm', pos=[0, 0, 1])
    self.shoulder = self.arm.add_joint(
        name='shoulder', type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 1, 0]
    )
    self.slider = self.arm.add_joint(
        name='slider', type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[1, 0, 0]
    )
    self.upper = self.arm.add_geom(
        name='upper',
        type=mujoco.mjtGeom.mjGEOM_CAPSULE,
        size=[0.05, 0, 0],
        fromto=[0, 0, 0, 0.3, 0, 0],
        **no_contacts,
    )
    self.hand = self.arm.add_site(name='hand', pos=[0.3, 0, 0])
    self.ball = spec.worldbody.add_body(name='ball', pos=[1, 0, 1])
    self.ball_joint = self.ball.add_freejoint(name='ball_free')
    self.ball_geom = self.ball.add_geom(
        name='ball_geom',
        type=mujoco.mjtGeom.mjGEOM_SPHERE,
        size=[0.1, 0, 0],
        **no_contacts,
    )
    self.hand_pos = spec.add_sensor(
        name='hand_pos',
        type=mujoco.mjtSensor.mjSENS_FRAMEPOS,
        objtype=mujoco.mjtObj.mjOBJ_SITE,
        objname='hand',
    )
    self.shoulder_pos = spec.add_sensor(
        name='shoulder_pos',
        type=mujoco.mjtSensor.mjSENS_JOINTPOS,
        objtype=mujoco.mjtObj.mjOBJ_JOINT,
        objname='shoulder',
    )
    self.model = spec.compile()
    handles = [
        ('body', self.arm),
        ('joint', self.shoulder),
        ('joint', self.slider),
        ('geom', self.upper),
        ('site', self.hand),
        ('body', self.ball),
        ('joint', self.ball_joint),
        ('geom', self.ball_geom),
        ('sensor', self.hand_pos),
        ('sensor', self.shoulder_pos),
    ]
    self.index = element_index.ElementIndex(
        self.model, {id(h): (h, kind, h.name) for kind, h in handles}
    )
    self.data = mujoco.MjData(self.model)
    quat = np.array([0.9, 0.1, 0.2, 0.3])
    self.data.qpos[:] = np.concatenate(
        [[0.3, 0.1, 1.0, 0.2, 1.5], quat / np.linalg.norm(quat)]
    )
    self.data.qvel[:] = np.arange(8) * 0.1
    mujoco.mj_forward(self.model, self.data)
    self.mjx_model = mjx.put_model(self.model)

  def physics(self, data=None):
    """A Physics holding the host's forward results (exact comparisons)."""
    if data is None:
      data = mjx.put_data(self.model, self.data)
    return physics_lib.Physics(
        model=self.mjx_model, data=data, index=self.index
    )


@pytest.fixture(scope='module')
def model():
  return _Model()


def test_mjcf_feature_matches_host_values(model):
  physics = model.physics()
  d = model.data
  cases = [
      (mjcf.MJCFFeature('qpos', model.shoulder), d.qpos[:1]),
      (mjcf.MJCFFeature('qpos', model.ball_joint), d.qpos[2:9]),
      (mjcf.MJCFFeature('qvel', model.ball_joint), d.qvel[2:8]),
      (mjcf.MJCFFeature('qpos', [model.shoulder, model.slider]), d.qpos[:2]),
      (mjcf.MJCFFeature('xpos', model.upper), d.geom_xpos[0]),
      (
          mjcf.MJCFFeature('xpos', [model.upper, model.ball_geom]),
          d.geom_xpos[:2],
      ),
      (mjcf.MJCFFeature('xpos', model.hand), d.site_xpos[0]),
      (mjcf.MJCFFeature('xpos', model.ball), d.xpos[2]),
      (mjcf.MJCFFeature('sensordata', model.hand_pos), d.sensordata[:3]),
      (
          mjcf.MJCFFeature('sensordata', [model.hand_pos, model.shoulder_pos]),
          d.sensordata,
      ),
      (mjcf.MJCFFeature('size', model.ball_geom), model.model.geom_size[1]),
  ]
  for feature, expected in cases:
    np.testing.assert_allclose(
        feature(physics),
        expected,
        rtol=1e-6,
        atol=1e-6,
        err_msg=f'{feature.kind} of {feature.index}',
    )
  # Same as the named access.
  np.testing.assert_array_equal(
      mjcf.MJCFFeature('qpos', model.shoulder)(physics),
      physics.named.data.qpos['shoulder'],
  )
  np.testing.assert_array_equal(
      mjcf.MJCFFeature('xpos', [model.arm, model.ball])(physics),
      physics.named.data.xpos[['arm', 'ball']],
  )


def test_mjcf_feature_indexing(model):
  physics = model.physics()
  # Bindings give xmat flat, (9,), as dm_control's do.
  xmat = np.asarray(physics.bind(model.ball_geom).xmat)
  assert xmat.shape == (9,)
  np.testing.assert_allclose(
      xmat, model.data.geom_xmat[1], rtol=1e-6, atol=1e-7
  )
  flat = xmat
  feature = mjcf.MJCFFeature('sensordata', [model.hand_pos, model.shoulder_pos])
  sensors = model.data.sensordata
  np.testing.assert_allclose(
      feature[[1, 3]](physics), sensors[[1, 3]], rtol=1e-6
  )
  np.testing.assert_allclose(feature[1:3](physics), sensors[1:3], rtol=1e-6)
  xmat_feature = mjcf.MJCFFeature('xmat', model.ball_geom)
  np.testing.assert_allclose(xmat_feature[[1, 2]](physics), xmat[[1, 2]])
  np.testing.assert_allclose(xmat_feature[1:3](physics), xmat[1:3])
  np.testing.assert_allclose(
      mjcf.MJCFFeature('xmat', model.ball_geom, index=6)(physics), flat[6]
  )
  np.testing.assert_allclose(xmat_feature[6:](physics), flat[6:])
  feature = xmat_feature
  assert feature.index is None  # Indexing returns a copy.
  with pytest.raises(NotImplementedError):
    feature[1:3][0]  # pylint: disable=expression-not-assigned


@pytest.mark.parametrize('bad', ['hand', ['hand'], 3, None])
def test_mjcf_feature_rejects_non_elements(bad):
  with pytest.raises(ValueError, match='expected an `mjcf.Element`'):
    mjcf.MJCFFeature('xpos', bad)


def test_mujoco_feature_matches_named_data(model):
  physics = model.physics()
  by_name = base.MujocoFeature('qpos', 'shoulder')
  np.testing.assert_array_equal(
      by_name(physics), physics.named.data.qpos['shoulder']
  )
  names = ['arm', 'ball']
  by_list = base.MujocoFeature('xpos', names)
  np.testing.assert_array_equal(
      by_list(physics), physics.named.data.xpos[names]
  )
  by_callable = base.MujocoFeature('xpos', lambda: names)
  np.testing.assert_array_equal(
      by_callable(physics), physics.named.data.xpos[names]
  )
  np.testing.assert_allclose(by_list(physics), model.data.xpos[1:3], rtol=1e-6)


def test_updater_on_mjx_forward_matches_host(model):
  observables = collections.OrderedDict(
      hand=mjcf.MJCFFeature('xpos', model.hand),
      joints=mjcf.MJCFFeature(
          'qpos', [model.shoulder, model.slider], buffer_size=2
      ),
      sensors=base.MujocoFeature(
          'sensordata',
          ['hand_pos', 'shoulder_pos'],
          aggregator='mean',
          buffer_size=3,
      ),
      noisy=mjcf.MJCFFeature(
          'qvel',
          model.ball_joint,
          corruptor=lambda v, key: v + 0.01 * jax.random.normal(key, v.shape),
      ),
  )
  for obs in observables.values():
    obs.enabled = True
  updater = updater_lib.Updater(observables, 2, pad_with_initial_value=True)
  spec = updater.observation_spec(jax.eval_shape(model.physics))
  assert spec['hand'].shape == (1, 3)
  assert spec['joints'].shape == (2, 2)
  assert spec['sensors'].shape == (4,)
  assert spec['noisy'].shape == (1, 6)

  # The device starts from qpos/qvel only and runs mjx.forward.
  blank = mujoco.MjData(model.model)
  blank.qpos[:] = model.data.qpos
  blank.qvel[:] = model.data.qvel

  @jax.jit
  def observe(data, key):
    physics = model.physics(data).forward()
    return updater.get_observation(updater.reset(physics, key))

  observation = observe(mjx.put_data(model.model, blank), jax.random.key(0))
  d = model.data
  np.testing.assert_allclose(observation['hand'], d.site_xpos[:1], atol=1e-5)
  np.testing.assert_allclose(
      observation['joints'], [d.qpos[:2]] * 2, atol=1e-6
  )  # initial-value padding
  np.testing.assert_allclose(observation['sensors'], d.sensordata, atol=1e-5)
  noise = observation['noisy'][0] - d.qvel[2:8]
  assert 0 < np.abs(noise).max() < 0.1
  for key, value in observation.items():
    spec[key].validate(np.asarray(value))
