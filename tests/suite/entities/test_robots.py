"""The bundled `Arm` robot, checked with MuJoCo's C implementation."""

import mujoco
import numpy as np
import pytest

from mjx_composer.suite.entities import arenas
from mjx_composer.suite.entities import robots


@pytest.fixture(scope='module')
def model():
  arena = arenas.Floor()
  arm = robots.Arm()
  arena.attach(arm)
  spec, _ = arena.compose()
  return spec.compile()


def test_joint_ranges_are_radians(model):
  np.testing.assert_allclose(model.joint('arm/shoulder').range, [-1.6, 1.6])
  np.testing.assert_allclose(model.joint('arm/elbow').range, [-2.5, 2.5])


def test_no_contacts_at_rest(model):
  data = mujoco.MjData(model)
  mujoco.mj_forward(model, data)
  pairs = [
      (model.geom(c.geom1).name, model.geom(c.geom2).name)
      for c in data.contact[: data.ncon]
  ]
  assert not pairs, pairs


@pytest.mark.parametrize('ctrl', [(1.0, 1.0, 1.0), (-1.0, -1.0, -1.0)])
def test_full_torque_swings_every_joint(model, ctrl):
  data = mujoco.MjData(model)
  data.ctrl[:] = ctrl
  for _ in range(int(2.0 / model.opt.timestep)):
    mujoco.mj_step(model, data)
  shoulder = data.joint('arm/shoulder').qpos[0]
  elbow = data.joint('arm/elbow').qpos[0]
  # The pitch joints swing far (ranges read as degrees stopped them at
  # 0.03 and 0.04 rad); the shoulder stops where the arm meets the floor.
  assert abs(shoulder) > 0.8 and abs(elbow) > 1.3, (shoulder, elbow)
  assert abs(elbow) <= 2.5 + 0.05
  assert abs(data.joint('arm/yaw').qpos[0]) > 0.5
  assert np.all(np.isfinite(data.qpos))
  assert data.site('arm/hand').xpos[2] < 0.5
