"""Entity: attach/detach, iteration order, frames and poses (inventory 8.2)."""

import jax
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from tests import conftest


class Part(conftest.SpecEntity):
  """A body with a sphere geom, a site to attach things to, and a joint."""

  def _build(self, name):
    spec = self._new_spec(name)
    body = spec.worldbody.add_body(name='body')
    body.add_geom(
        type=mujoco.mjtGeom.mjGEOM_SPHERE,
        size=[0.1, 0, 0],
        contype=0,
        conaffinity=0,
    )
    self.joint = body.add_joint(name='slide', type=mujoco.mjtJoint.mjJNT_SLIDE)
    # A site whose frame maps global y to local x (composer's frame test).
    self.site = spec.worldbody.add_site(name='mount', pos=[0.5, 0, 0])
    self.site.alt.type = mujoco.mjtOrientation.mjORIENTATION_XYAXES
    self.site.alt.xyaxes = [0, 1, 0, -1, 0, 0]


def _physics(root):
  env = composer.Environment(composer.NullTask(root))
  return env, env.physics(jax.jit(env.reset)(jax.random.key(0)))


def _forward(physics):
  return jax.jit(lambda p: p.forward())(physics)


def test_attach_parents_and_iteration_order():
  e0, e1, e2, e3 = (Part(f'e{i}') for i in range(4))
  frame = e0.attach(e1)
  e1.attach(e2)
  e0.attach(e3)
  assert isinstance(frame, mujoco.MjsBody) and frame.name == 'e1/'
  assert e1.parent is e0 and e2.parent is e1 and e3.parent is e0
  assert e0.parent is None
  assert list(e0.iter_entities()) == [e0, e1, e2, e3]
  assert list(e0.iter_entities(exclude_self=True)) == [e1, e2, e3]
  assert e2.full_identifier == 'e1/e2/'
  env, _ = _physics(e0)
  names = {env.mj_model.body(i).name for i in range(env.mj_model.nbody)}
  assert {
      'e0/',
      'body',
      'e1/',
      'e1/body',
      'e1/e2/',
      'e1/e2/body',
      'e3/',
      'e3/body',
  } <= names | {'e0/'}
  assert env.mj_model.joint('e1/e2/slide').id >= 0


def test_detach_restores_the_tree():
  e0, e1, e2, e3 = (Part(f'e{i}') for i in range(4))
  env_before, _ = _physics(e0)
  xml_before = e0.mjcf_model.to_xml()
  e0.attach(e1)
  e1.attach(e2)
  e0.attach(e3)
  e1.detach()
  assert e1.parent is None and e2.parent is e1
  assert list(e0.iter_entities()) == [e0, e3]
  with pytest.raises(RuntimeError, match='not attached'):
    e1.detach()
  e3.detach()
  assert e0.mjcf_model.to_xml() == xml_before
  # A detached entity can be attached again, with its own subtree: e1's
  # frame and body plus e2's frame and body.
  e0.attach(e1)
  env_after, _ = _physics(e0)
  assert env_after.mj_model.nbody == env_before.mj_model.nbody + 4
  assert env_after.mj_model.body('e1/e2/body').id > 0


def test_same_class_many_times_and_clear_errors():
  root = Part('root')
  parts = [Part(f'p{i}') for i in range(3)]
  for p in parts:
    root.attach(p)
  env, physics = _physics(root)
  for p in parts:
    assert physics.index.full_name(p.joint) == f'{p.name}/slide'
  with pytest.raises(ValueError, match='already attached'):
    root.attach(parts[0])
  with pytest.raises(ValueError, match='distinct name'):
    root.attach(Part('p1'))
  with pytest.raises(ValueError, match='itself or its descendant'):
    parts[0].attach(root)


def test_frames_rotate_vectors_into_the_attachment_frame():
  root, child = Part('root'), Part('child')
  root.attach(child, attach_site=root.site)
  _, physics = _physics(root)
  f = lambda v: np.asarray(child.global_vector_to_local_frame(physics, v))
  np.testing.assert_allclose(f([0.0, 1.0, 0.0]), [1.0, 0.0, 0.0], atol=1e-6)
  np.testing.assert_allclose(f([-1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-6)
  np.testing.assert_allclose(f([0.0, 0.0, 1.0]), [0.0, 0.0, 1.0], atol=1e-6)
  np.testing.assert_allclose(f([0.0, 1.0]), [1.0, 0.0], atol=1e-6)
  np.testing.assert_allclose(f([-1.0, 0.0]), [0.0, 1.0], atol=1e-6)
  with pytest.raises(ValueError, match='last dimension'):
    child.global_vector_to_local_frame(physics, [1.0, 2.0, 3.0, 4.0])
  xmat = np.eye(3)[[1, 2, 0]]
  local = np.asarray(child.global_xmat_to_local_frame(physics, xmat))
  flat = np.asarray(child.global_xmat_to_local_frame(physics, xmat.ravel()))
  np.testing.assert_allclose(local.ravel(), flat, atol=1e-6)
  # Bindings give rotation matrices flat, as dm_control's Physics.bind does.
  frame_xmat = np.asarray(physics.bind(child.root_body).xmat)
  assert frame_xmat.shape == (9,)
  np.testing.assert_allclose(
      local, frame_xmat.reshape(3, 3).T @ xmat, atol=1e-6
  )


def _quat(axis, degrees):
  q = np.zeros(4)
  mujoco.mju_axisAngle2Quat(q, np.asarray(axis, float), np.deg2rad(degrees))
  return q


_ROTATIONS = [None, _quat([1, 0, 0], 45), _quat([0, 0, 1], 90)]


@pytest.mark.parametrize('free', [False, True])
def test_set_pose_and_shift_pose(free):
  arena = composer.Arena()
  fixed, loose = Part('fixed'), Part('loose')
  arena.attach(fixed)
  arena.add_free_entity(loose)
  entity = loose if free else fixed
  env = composer.Environment(
      composer.NullTask(arena),
      options=composer.ExecutionOptions(
          per_world_model_fields=() if free else ('body_pos', 'body_quat')
      ),
  )
  base = env.physics(jax.jit(env.reset)(jax.random.key(0)))
  for position in (None, [1.0, 0.0, -1.0]):
    for quat in _ROTATIONS:
      physics = _forward(
          entity.set_pose(base, position=position, quaternion=quat)
      )
      frame = physics.bind(entity.root_body)
      want_pos = [0.0, 0.0, 0.0] if position is None else position
      want_quat = [1.0, 0.0, 0.0, 0.0] if quat is None else quat
      np.testing.assert_allclose(frame.xpos, want_pos, atol=1e-6)
      np.testing.assert_allclose(frame.xquat, want_quat, atol=1e-6)
      pos, q = entity.get_pose(physics)
      np.testing.assert_allclose(pos, want_pos, atol=1e-6)
      np.testing.assert_allclose(q, want_quat, atol=1e-6)

  # shift_pose: positions add; quaternions pre-multiply (new = shift ⊗ old).
  start_quat = _quat([1, 0, 0], 45)
  physics = entity.set_pose(
      base, position=[0.1, 0.2, 0.3], quaternion=start_quat
  )
  for shift in (_quat([0, 1, 0], 90), _quat([0, 0, 1], 90)):
    shifted = _forward(
        entity.shift_pose(physics, position=[1.0, 0.0, 0.0], quaternion=shift)
    )
    expected = np.zeros(4)
    mujoco.mju_mulQuat(expected, shift, start_quat)
    frame = shifted.bind(entity.root_body)
    np.testing.assert_allclose(frame.xpos, [1.1, 0.2, 0.3], atol=1e-6)
    np.testing.assert_allclose(frame.xquat, expected, atol=1e-5)
    # Not the other order (these rotations do not commute).
    wrong = np.zeros(4)
    mujoco.mju_mulQuat(wrong, start_quat, shift)
    assert not np.allclose(expected, wrong, atol=1e-3)
  np.testing.assert_allclose(
      [0.65328, 0.2706, 0.65328, -0.2706],
      _shift_expected(_quat([1, 0, 0], 45), _quat([0, 1, 0], 90)),
      atol=1e-4,
  )


def _shift_expected(original, shift):
  out = np.zeros(4)
  mujoco.mju_mulQuat(out, shift, original)
  return out


@pytest.mark.parametrize('rotate_velocity', [False, True])
def test_shift_pose_rotates_velocity(rotate_velocity):
  arena = composer.Arena()
  ball = Part('ball')
  arena.add_free_entity(ball)
  env, physics = _physics(arena)
  physics = ball.set_velocity(
      physics, velocity=[0.0, 1.0, 0.0], angular_velocity=[0.0, 0.0, 0.0]
  )
  physics = ball.shift_pose(
      physics, quaternion=[0.0, 0.0, 0.0, 1.0], rotate_velocity=rotate_velocity
  )
  physics = _forward(physics)
  linear, _ = ball.get_velocity(physics)
  if rotate_velocity:
    np.testing.assert_allclose(linear, [0.0, -1.0, 0.0], atol=1e-6)
  else:
    np.testing.assert_allclose(linear, [0.0, 1.0, 0.0], atol=1e-6)


def test_pose_errors():
  root, child = Part('root'), Part('child')
  root.attach(child)
  _, physics = _physics(root)
  with pytest.raises(RuntimeError, match='No attachment frame'):
    root.get_pose(physics)
  with pytest.raises(ValueError, match='free entity'):
    child.get_velocity(physics)


def test_model_wrapper_entity_from_xml_string():
  xml = """<mujoco model="box"><worldbody><body name="b">
    <geom name="g" type="box" size=".1 .1 .1"/></body></worldbody></mujoco>"""
  arena = composer.Arena()
  box = composer.ModelWrapperEntity(xml)
  arena.add_free_entity(box)
  env, physics = _physics(arena)
  assert box.name == 'box'
  g = box.mjcf_model.geom('g')
  np.testing.assert_allclose(physics.bind(g).size, [0.1, 0.1, 0.1])
  assert env.mj_model.geom('box/g').id == physics.bind(g).element_ids[0]
