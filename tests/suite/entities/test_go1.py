"""The `Go1` robot, against Menagerie's XML compiled by MuJoCo itself."""

import copy
import struct

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from mjx_composer import environment
from mjx_composer import task
from mjx_composer.suite.entities import arenas
from mjx_composer.suite.entities import go1

_MESHES = ('trunk', 'hip', 'thigh_mirror', 'calf', 'thigh')


def _tetrahedron_stl():
  """A tiny binary STL: stands in for Menagerie's (not vendored) meshes."""
  vertices = np.array(
      [[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01]], np.float32
  )
  faces = ((0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3))
  out = b'\0' * 80 + struct.pack('<I', len(faces))
  for face in faces:
    out += struct.pack('<3f', 0, 0, 0) + vertices[list(face)].tobytes()
    out += b'\0\0'
  return out


@pytest.fixture(scope='module')
def reference():
  """Menagerie's go1.xml as MuJoCo compiles it (meshes replaced)."""
  mesh = _tetrahedron_stl()
  return mujoco.MjModel.from_xml_path(
      str(go1.XML_PATH), assets={f'{n}.stl': mesh for n in _MESHES}
  )


def _compose(**robot_kwargs):
  arena = arenas.Floor()
  robot = go1.Go1(**robot_kwargs)
  frame = arena.add_free_entity(robot)
  frame.pos = [0.0, 0.0, robot.home_height]
  robot.apply_simulation_options(arena.mjcf_model)
  return arena, robot


@pytest.fixture(scope='module')
def composed():
  arena, robot = _compose()
  return environment.Environment(task.NullTask(arena)), robot


def _ids(model, obj, names, prefix='go1/'):
  ids = [mujoco.mj_name2id(model, obj, prefix + n) for n in names]
  assert min(ids) >= 0, names
  return np.array(ids)


def test_composed_model_is_menageries(composed, reference):
  env, robot = composed
  model, ref = env.mj_model, reference
  assert (
      (model.nq, model.nv, model.nu)
      == (ref.nq, ref.nv, ref.nu)
      == (
          19,
          18,
          12,
      )
  )
  body_names = [ref.body(i).name for i in range(1, ref.nbody)]
  bodies = _ids(model, mujoco.mjtObj.mjOBJ_BODY, body_names)
  for field in ('body_mass', 'body_inertia', 'body_ipos', 'body_iquat'):
    np.testing.assert_allclose(
        getattr(model, field)[bodies],
        getattr(ref, field)[1:],
        atol=1e-12,
        err_msg=field,
    )
  joint_names = [ref.joint(i).name for i in range(1, ref.njnt)]
  joints = _ids(model, mujoco.mjtObj.mjOBJ_JOINT, joint_names)
  np.testing.assert_allclose(model.jnt_range[joints], ref.jnt_range[1:])
  for field in ('dof_damping', 'dof_armature', 'dof_frictionloss'):
    np.testing.assert_allclose(getattr(model, field), getattr(ref, field))
  for field in (
      'actuator_gainprm',
      'actuator_biasprm',
      'actuator_ctrlrange',
      'actuator_forcerange',
  ):
    np.testing.assert_allclose(getattr(model, field), getattr(ref, field))
  # The home keyframe, as the robot's defaults.
  home = ref.key('home').qpos
  np.testing.assert_allclose(robot.home_joint_positions, home[7:])
  assert robot.home_height == pytest.approx(home[2])


def test_pd_gains_are_set_on_the_model(reference):
  arena, _ = _compose(kp=35.0, kd=0.5)
  spec, _ = arena.compose()
  model = spec.compile()
  np.testing.assert_allclose(model.actuator_gainprm[:, 0], 35.0)
  np.testing.assert_allclose(model.actuator_biasprm[:, :3], [[0, -35, 0]] * 12)
  np.testing.assert_allclose(model.dof_damping[6:], 0.5)
  np.testing.assert_allclose(
      model.actuator_forcerange, reference.actuator_forcerange
  )


def test_only_feet_and_trunk_touch_the_ground(composed):
  env, robot = composed
  model = env.mj_model
  colliding = {
      model.geom(i).name
      for i in range(model.ngeom)
      if model.geom_contype[i] or model.geom_conaffinity[i]
  }
  assert colliding == {'ground', 'go1/trunk_collision'} | {
      f'go1/{f}' for f in go1.FEET
  }
  # Only robot-ground pairs: feet never collide with each other.
  for i in range(model.ngeom):
    for j in range(i + 1, model.ngeom):
      if (model.geom_contype[i] & model.geom_conaffinity[j]) or (
          model.geom_contype[j] & model.geom_conaffinity[i]
      ):
        assert 'ground' in (model.geom(i).name, model.geom(j).name)
  # Falling on its back, the trunk lands on the floor (it does not sink).
  data = mujoco.MjData(model)
  data.qpos[2] = 0.3
  data.qpos[3:7] = [0, 1, 0, 0]  # Upside down.
  for _ in range(300):
    mujoco.mj_step(model, data)
  assert data.qpos[2] > 0.0
  assert data.sensor('go1/trunk_contact').data[0] > 0
  assert robot.simulation_options['iterations'] == model.opt.iterations


def test_full_collisions_keep_menageries_geoms(reference):
  arena, _ = _compose(collisions='full')
  model = arena.compose()[0].compile()
  colliding = lambda m: sum(
      1 for i in range(m.ngeom) if m.geom_contype[i] or m.geom_conaffinity[i]
  )
  # Menagerie's collision geoms plus the floor; its visual meshes are gone.
  assert colliding(model) == colliding(reference) + 1
  meshes = int(np.sum(reference.geom_type == mujoco.mjtGeom.mjGEOM_MESH))
  assert meshes > 0 and model.ngeom == reference.ngeom - meshes + 1
  assert model.nmesh == 0
  with pytest.raises(ValueError, match='collisions'):
    go1.Go1(collisions='none')


def test_observables_match_mujoco(composed):
  env, robot = composed
  model = env.mj_model
  rng = np.random.default_rng(2)
  qpos = model.qpos0.copy()
  qpos[2] = robot.home_height - 0.01
  roll = 0.25  # Leaning left: the left feet touch, the right ones do not.
  qpos[3:7] = [np.cos(roll / 2), -np.sin(roll / 2), 0, 0]
  qpos[7:] = robot.home_joint_positions
  qvel = rng.uniform(-0.5, 0.5, model.nv)
  ctrl = robot.home_joint_positions + rng.uniform(-0.2, 0.2, model.nu)
  observables = robot.observables.as_dict(fully_qualified=False)

  @jax.jit
  def observe(qpos, qvel, ctrl):
    physics = env.initial_physics()
    physics = physics.replace(
        data=physics.data.replace(qpos=qpos, qvel=qvel, ctrl=ctrl)
    ).forward()
    values = {
        name: obs.raw_observation_callable(physics)()
        for name, obs in observables.items()
    }
    return values, robot.trunk_contact(physics), robot.foot_heights(physics)

  got, trunk_contact, foot_heights = jax.device_get(
      observe(jnp.asarray(qpos), jnp.asarray(qvel), jnp.asarray(ctrl))
  )
  data = mujoco.MjData(model)
  data.qpos[:], data.qvel[:], data.ctrl[:] = qpos, qvel, ctrl
  mujoco.mj_forward(model, data)
  # Contacts straight from MuJoCo's contact list, not its sensors.
  touching = []
  for foot in go1.FEET:
    geom = model.geom(f'go1/{foot}').id
    touching.append(
        any(
            geom in (c.geom1, c.geom2) and c.dist < 0
            for c in data.contact[: data.ncon]
        )
    )
  assert any(touching) and not all(touching), touching
  imu = data.site('go1/imu')
  sensor = lambda name: data.sensor('go1/' + name).data
  feet = [data.site(f'go1/{f}') for f in go1.FEET]
  want = {
      'joint_positions': qpos[7:],
      'joint_velocities': qvel[6:],
      'gyro': sensor('gyro'),
      'local_linvel': sensor('local_linvel'),
      'accelerometer': sensor('accelerometer'),
      'gravity': imu.xmat.reshape(3, 3).T @ [0, 0, -1],
      'upvector': imu.xmat.reshape(3, 3)[:, 2],
      'global_linvel': sensor('global_linvel'),
      'global_angvel': sensor('global_angvel'),
      'foot_contacts': np.array(touching, np.float32),
      'foot_velocities': np.concatenate(
          [sensor(f'{f}_global_linvel') for f in go1.FEET]
      ),
      'foot_positions': np.stack([s.xpos for s in feet]),
      'actuator_forces': data.actuator_force,
  }
  assert set(got) == set(want)
  for name, value in want.items():
    if name == 'accelerometer':
      continue  # Below, with the solver converged.
    np.testing.assert_allclose(
        got[name], value, rtol=1e-4, atol=1e-4, err_msg=name
    )
  # The accelerometer sees the contact forces of the robot's solver options
  # (`go1.MJX_OPTIONS`): one Newton iteration, whose line search stops
  # where float32 and float64 rounding take it. Measured: 0.0155 m/s^2 (of
  # 2.7) compiled as the tests compile, 0.0041 fully optimized; 0.03
  # allows twice the larger.
  np.testing.assert_allclose(
      got['accelerometer'], want['accelerometer'], rtol=0, atol=0.03
  )
  # The same state with the solver run to convergence on both sides (100
  # Newton iterations, tolerance 1e-10; MuJoCo stops after 3): the float32
  # error is then 4.5e-5 m/s^2 (6.3e-5 fully optimized), and 2e-4 allows
  # three times the larger. The converged value is 0.5 m/s^2 away from
  # the one-iteration one, so this tolerance sees a wrong frame or sensor.
  converged = copy.deepcopy(model)
  converged.opt.iterations, converged.opt.ls_iterations = 100, 50
  converged.opt.tolerance = 1e-10

  @jax.jit
  def accelerometer(qpos, qvel, ctrl):
    physics = env.initial_physics()
    opt = physics.model.opt.replace(
        iterations=100, ls_iterations=50, tolerance=1e-10
    )
    physics = physics.replace(model=physics.model.replace(opt=opt))
    physics = physics.replace(
        data=physics.data.replace(qpos=qpos, qvel=qvel, ctrl=ctrl)
    ).forward()
    return observables['accelerometer'].raw_observation_callable(physics)()

  data = mujoco.MjData(converged)
  data.qpos[:], data.qvel[:], data.ctrl[:] = qpos, qvel, ctrl
  mujoco.mj_forward(converged, data)
  want_converged = data.sensor('go1/accelerometer').data
  assert int(data.solver_niter[0]) < 100
  assert np.abs(want_converged - want['accelerometer']).max() > 0.1
  np.testing.assert_allclose(
      accelerometer(jnp.asarray(qpos), jnp.asarray(qvel), jnp.asarray(ctrl)),
      want_converged,
      rtol=0,
      atol=2e-4,
  )
  assert not trunk_contact
  np.testing.assert_allclose(foot_heights, [s.xpos[2] for s in feet], atol=1e-5)
