"""The attribute catalogue (compiler.attributes) is consistent.

Every record is checked on real elements of a small spec: its spec read and
write round-trip, its fields are per-world `mjx.Model` fields that the
compiler changes when the spec value changes, its device write writes
exactly those fields, and inertial attributes make the planner recompute
the body's inertial.
"""

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np
import pytest

from mjx_composer.model import element_index
from mjx_composer.compiler import attributes
from mjx_composer.compiler import context
from mjx_composer.compiler import effects
from mjx_composer.compiler import planner

_G = mujoco.mjtGeom


def _spec():
  """One element per kind that every supported attribute may vary."""
  spec = mujoco.MjSpec()
  spec.option.density = 1.2
  spec.option.viscosity = 1e-5
  spec.option.wind = [0.1, 0, 0]
  free = spec.worldbody.add_body(name='free', pos=[0, 0, 1])
  free.add_freejoint()
  free.add_geom(
      name='ball', type=_G.mjGEOM_SPHERE, size=[0.1, 0, 0], density=800
  )
  free.add_geom(
      name='box',
      type=_G.mjGEOM_BOX,
      size=[0.05, 0.05, 0.05],
      pos=[0.2, 0, 0],
      mass=0.5,
  )
  arm = spec.worldbody.add_body(name='arm', pos=[1, 0, 1])
  arm.mass = 1.0
  arm.ipos = [0, 0, 0.1]
  arm.inertia = [0.1, 0.1, 0.1]
  arm.iquat = [1, 0, 0, 0]
  arm.explicitinertial = True
  arm.add_joint(
      name='hinge',
      type=mujoco.mjtJoint.mjJNT_HINGE,
      range=[-1, 1],
      damping=0.1,
      stiffness=1.0,
      armature=0.01,
      frictionloss=0.1,
  )
  arm.add_site(name='tip', pos=[0, 0, 0.2])
  servo = spec.add_actuator(
      name='servo', target='hinge', trntype=mujoco.mjtTrn.mjTRN_JOINT
  )
  servo.set_to_position(kp=10, kv=1)
  servo.ctrlrange = [-1, 1]
  servo.forcerange = [-5, 5]
  return spec


def _element(spec, record):
  if record.kind == 'option':
    return spec.option
  if record.kind == 'geom':
    return spec.geom('box' if record.name == 'mass' else 'ball')
  if record.kind == 'body':
    return spec.body('free' if record.name in ('pos', 'quat') else 'arm')
  return {'site': spec.site, 'joint': spec.joint, 'actuator': spec.actuator}[
      record.kind
  ]({'site': 'tip', 'joint': 'hinge', 'actuator': 'servo'}[record.kind])


def _other_value(value):
  return value * 1.25 + 0.05


def _compiled(m, field):
  if field.startswith('opt.'):
    return np.array(getattr(m.opt, field[4:]))
  return np.array(getattr(m, field))


_IDS = [f'{r.kind}.{r.name}' for r in attributes.CATALOGUE]


def test_catalogue_is_indexed_by_kind_and_name():
  assert len({(r.kind, r.name) for r in attributes.CATALOGUE}) == len(
      attributes.CATALOGUE
  )
  for record in attributes.CATALOGUE:
    assert attributes.BY_KIND[record.kind][record.name] is record


@pytest.mark.parametrize('record', attributes.CATALOGUE, ids=_IDS)
def test_fields_are_per_world_model_fields(record):
  model_fields = {f.name: f.type for f in dataclasses.fields(mjx.Model)}
  option_fields = {f.name: f.type for f in dataclasses.fields(mjx.Option)}
  assert record.fields
  for field in record.fields:
    if field.startswith('opt.'):
      assert option_fields.get(field[4:]) is jax.Array, field
    else:
      assert model_fields.get(field) is jax.Array, field
  if record.set_model is None:
    # Derived by inertia.body_inertial.
    assert record.effects & (
        effects.Effect.BODY_INERTIAL | effects.Effect.GEOM_INERTIA
    )
    assert set(record.fields) <= {
        'body_mass',
        'body_inertia',
        'body_ipos',
        'body_iquat',
    }


@pytest.mark.parametrize('record', attributes.CATALOGUE, ids=_IDS)
def test_spec_round_trip_and_compiled_fields(record):
  spec = _spec()
  element = _element(spec, record)
  assert attributes.check_attribute(element, record.name) == record.kind
  before = spec.compile()
  value = record.spec_value(element)
  assert value.shape == record.shape and value.dtype == np.float64
  new = _other_value(value)
  record.set_spec_value(element, new)
  # rtol: some attributes (rgba) are float32 in the spec.
  np.testing.assert_allclose(record.spec_value(element), new, rtol=1e-6)
  after = spec.compile()
  changed = [
      f
      for f in record.fields
      if not np.allclose(_compiled(before, f), _compiled(after, f))
  ]
  assert changed, f'none of {record.fields} changed'
  record.set_spec_value(element, value)
  np.testing.assert_array_equal(record.spec_value(element), value)


def _index(spec):
  m = spec.compile()
  handles = {
      id(h): (h, kind, h.name)
      for kind, h in element_index.iter_elements(spec)
      if h.name
  }
  return element_index.ElementIndex(m, handles)


@pytest.mark.parametrize('record', attributes.CATALOGUE, ids=_IDS)
def test_device_write_writes_the_fields(record):
  spec = _spec()
  element = _element(spec, record)
  index = _index(spec)
  compiler = planner.ModelCompiler(index, [(element, record.name, 'x')])
  if record.set_model is None:
    body = 'free' if record.kind == 'geom' else 'arm'
    assert compiler.plan.inertia_bodies == (
        mujoco.mj_name2id(index.mj_model, mujoco.mjtObj.mjOBJ_BODY, body),
    )
    return
  obj_id = -1
  if record.kind != 'option':
    kind = element_index.KINDS_BY_NAME[record.kind]
    obj_id = index.element_id(kind, element)
  fields = context.Fields(context.Host(index), mjx.put_model(index.mj_model))
  value = jnp.asarray(_other_value(record.spec_value(element)), jnp.float32)
  record.set_model(fields, obj_id, value)
  written = set(fields.fields) | {f'opt.{k}' for k in fields.opt}
  assert written == set(record.fields)
