"""Tests for `kinematics.ReferenceKinematics` against MJX's own kinematics."""

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np
import pytest

from mjx_composer.model import kinematics
from mjx_composer.platform import internals

_XML = """
<mujoco>
  <worldbody>
    <body name="mocap" mocap="true" pos="0.3 0 1"><geom size="0.05"/></body>
    <body name="upper" pos="0 0 1" quat="0.9 0.1 0 0.2">
      <joint name="shoulder" axis="0 1 0" pos="0 0 0.1"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.04"/>
      <geom type="box" pos="0.3 0 0" size="0.05 0.05 0.05"/>
      <site name="elbow" pos="0.3 0 0.05"/>
      <body name="lower" pos="0.3 0 0">
        <joint name="elbow" axis="0 0 1"/>
        <geom type="sphere" pos="0.2 0 0" size="0.05"/>
        <site name="hand" pos="0.25 0 0" quat="0.7 0.7 0 0"/>
      </body>
    </body>
    <body name="ball" pos="0.5 0.5 0.2">
      <freejoint/>
      <geom type="sphere" size="0.1"/>
    </body>
  </worldbody>
</mujoco>
"""

_OUTPUTS = (
    'xpos',
    'xquat',
    'xmat',
    'xanchor',
    'xaxis',
    'xipos',
    'ximat',
    'geom_xpos',
    'geom_xmat',
    'site_xpos',
    'site_xmat',
    'subtree_com',
    'cdof',
)


@pytest.fixture(scope='module')
def setup():
  m = mujoco.MjModel.from_xml_string(_XML)
  m.qpos0[0] = 0.3  # a qpos0 that is not all zeros
  model = mjx.put_model(m)
  data = mjx.make_data(model)
  return m, model, data, kinematics.ReferenceKinematics(m)


def _mjx(model, data):
  return mjx.com_pos(model, mjx.kinematics(model, data))


def _assert_same(got, want):
  for name in _OUTPUTS:
    np.testing.assert_allclose(
        getattr(got, name), getattr(want, name), atol=2e-6, err_msg=name
    )
  np.testing.assert_allclose(
      internals.data_impl(got).cinert,
      internals.data_impl(want).cinert,
      atol=2e-6,
  )


def _eqns(fn, *args):
  return len(jax.make_jaxpr(fn)(*args).jaxpr.eqns)


@pytest.mark.parametrize(
    'fields',
    [
        {},
        {'body_mass': lambda x: x * 1.7, 'body_inertia': lambda x: x * 1.3},
        {
            'body_ipos': lambda x: x + 0.02,
            'body_iquat': lambda x: x.at[:, 1].add(0.1)
            / jnp.linalg.norm(x.at[:, 1].add(0.1), axis=-1, keepdims=True),
        },
        {'geom_pos': lambda x: x + 0.1, 'site_quat': lambda x: x[:, ::-1]},
    ],
    ids=['constant', 'masses', 'inertial_frames', 'geom_and_site_frames'],
)
def test_matches_mjx_when_only_non_tree_fields_vary(setup, fields):
  _, model, data, reference = setup

  def varied(values):  # traced: per-world
    return model.replace(**{name: values[name] for name in fields})

  ours = lambda v: reference.apply(varied(v), data)
  theirs = lambda v: _mjx(varied(v), data)
  values = {name: f(getattr(model, name)) for name, f in fields.items()}
  _assert_same(jax.jit(ours)(values), jax.jit(theirs)(values))
  # The tree (joint anchors and body frames) is never recomputed: the
  # program is a fraction of MJX's.
  assert _eqns(ours, values) < _eqns(theirs, values) / 3


def test_body_frames_that_vary_fall_back_to_mjx(setup):
  _, model, data, reference = setup
  body_pos = model.body_pos + 0.1

  def fn(body_pos):
    varied = model.replace(body_pos=body_pos)
    return reference.apply(varied, data), _mjx(varied, data)

  got, want = jax.jit(fn)(body_pos)
  _assert_same(got, want)
  assert not np.allclose(got.xpos, setup[3].apply(model, data).xpos)


def test_other_configurations_fall_back_to_mjx(setup):
  _, model, data, reference = setup
  moved = data.replace(qpos=data.qpos.at[0].add(0.5))
  assert not reference.matches(moved.replace(qpos=jnp.asarray(moved.qpos)))
  got = reference.apply(model, moved)
  _assert_same(got, _mjx(model, moved))
  traced = jax.jit(lambda q: reference.apply(model, data.replace(qpos=q)))
  _assert_same(traced(moved.qpos), _mjx(model, moved))


def test_fields_written_in_the_call_count_as_varying(setup):
  _, model, data, reference = setup
  heavier = model.replace(body_mass=model.body_mass * 2)  # concrete, changed
  _assert_same(reference.apply(heavier, data), _mjx(heavier, data))
  # Equal values that a caller is about to write are recomputed, not read.
  same = reference.apply(model, data, written=('body_pos',))
  _assert_same(same, _mjx(model, data))


def test_a_model_changed_after_compiling_is_not_mistaken_for_the_host(setup):
  _, model, data, reference = setup
  moved = model.replace(jnt_axis=model.jnt_axis[:, ::-1])
  _assert_same(reference.apply(moved, data), _mjx(moved, data))
