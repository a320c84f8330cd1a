"""benchmarks/compile_ablation.py without compiling: its patches and programs."""

import os
import sys

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from mjx_composer import kinematics
from mjx_composer.compiler import inertia
from mjx_composer.compiler import set_const
from mjx_composer.variation import distributions

sys.path.insert(
    0, os.path.join(os.path.dirname(os.path.dirname(__file__)), 'benchmarks')
)
# pylint: disable=g-import-not-at-top,wrong-import-position
import compile_ablation
import compile_time

# pylint: enable=g-import-not-at-top,wrong-import-position


@pytest.fixture(scope='module')
def reach_env():
  return compile_time.make_task_env('reach')


def test_no_draws_replaces_uniform_draws_by_their_midpoint(monkeypatch):
  uniform = distributions.Uniform(1.0, 3.0)
  key = jax.random.key(0)
  drawn = uniform(initial_value=jnp.zeros(4), key=key)
  assert np.unique(np.asarray(drawn)).size == 4
  compile_ablation.remove('no_draws', monkeypatch.setattr)
  np.testing.assert_array_equal(
      uniform(initial_value=jnp.zeros(4), key=key), np.full(4, 2.0)
  )


def test_no_set_const_and_no_inertia_skip_their_re_derivations(monkeypatch):
  compile_ablation.remove('no_set_const', monkeypatch.setattr)
  compile_ablation.remove('no_inertia', monkeypatch.setattr)
  assert set_const.update(None, None, None, None) is None
  assert not inertia.bodies_inertial(None, (1,), None)


def test_no_hook_kinematics_skips_only_the_hooks_call(monkeypatch):
  m = mujoco.MjModel.from_xml_string(
      '<mujoco><worldbody><body pos="0 0 1"><freejoint/>'
      '<geom size="0.1"/></body></worldbody></mujoco>'
  )
  from mujoco import mjx  # pylint: disable=g-import-not-at-top

  model = mjx.put_model(m)
  data = mjx.make_data(model)
  reference = kinematics.ReferenceKinematics(m)
  compile_ablation.remove('no_hook_kinematics', monkeypatch.setattr)
  assert reference.apply(model, data) is data  # the hooks' call
  computed = reference.apply(model, data, written=('body_mass',))
  np.testing.assert_allclose(computed.xpos[1], [0, 0, 1])  # set_const's


def test_unknown_part_raises():
  with pytest.raises(ValueError):
    compile_ablation.remove('no_physics')


def test_batched_model_step_batches_the_carried_model_fields(reach_env):
  fn, args = compile_ablation.batched_model_step(reach_env, worlds=3, steps=1)
  fields, data, ctrl = args
  carried = jax.eval_shape(reach_env.reset, jax.random.key(0)).model_fields
  assert set(fields) == set(carried)
  for leaf in jax.tree.leaves(fields):
    assert leaf.shape[0] == 3
  out_data, _ = jax.eval_shape(fn, fields, data, ctrl)
  assert out_data.qpos.shape == (3, reach_env.mjx_model.nq)
