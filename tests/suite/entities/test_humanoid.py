"""The `Humanoid` robot, against its vendored XML compiled by MuJoCo itself."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from mjx_composer import environment
from mjx_composer import task
from mjx_composer.suite.entities import arenas
from mjx_composer.suite.entities import humanoid


@pytest.fixture(scope='module')
def composed():
  """A humanoid on a floor: (environment, robot, reference MjModel)."""
  arena = arenas.Floor()
  robot = humanoid.Humanoid()
  frame = arena.add_free_entity(robot)
  frame.pos = [0.0, 0.0, robot.initial_height]
  robot.apply_simulation_options(arena.mjcf_model)
  env = environment.Environment(task.NullTask(arena))
  reference = mujoco.MjModel.from_xml_path(str(humanoid.XML_PATH))
  return env, robot, reference


def _named(model, obj, reference, prefix='humanoid/'):
  """Ids in both models of the `obj` elements named in both, in order."""
  count = {
      mujoco.mjtObj.mjOBJ_BODY: reference.nbody,
      mujoco.mjtObj.mjOBJ_JOINT: reference.njnt,
      mujoco.mjtObj.mjOBJ_ACTUATOR: reference.nu,
  }[obj]
  ids, ref_ids = [], []
  for i in range(count):
    name = mujoco.mj_id2name(reference, obj, i)
    composed_id = mujoco.mj_name2id(model, obj, prefix + (name or ''))
    if name and composed_id >= 0:
      ids.append(composed_id)
      ref_ids.append(i)
  return np.array(ids), np.array(ref_ids)


def test_composed_model_is_the_vendored_xml(composed):
  env, _, ref = composed
  model = env.mj_model
  assert (
      (model.nq, model.nv, model.nu)
      == (ref.nq, ref.nv, ref.nu)
      == (
          28,
          27,
          21,
      )
  )
  # The free joint sits where the XML's did: qpos0 is the XML's.
  np.testing.assert_allclose(model.qpos0, ref.qpos0, atol=1e-12)
  bodies, ref_bodies = _named(model, mujoco.mjtObj.mjOBJ_BODY, ref)
  assert len(bodies) == ref.nbody - 1  # All but the world.
  for field in ('body_mass', 'body_inertia', 'body_ipos', 'body_pos'):
    got, want = getattr(model, field)[bodies], getattr(ref, field)[ref_bodies]
    if field == 'body_pos':  # The torso sits in its frame, at the origin.
      got, want = got[1:], want[1:]
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12, err_msg=field)
  joints, ref_joints = _named(model, mujoco.mjtObj.mjOBJ_JOINT, ref)
  assert len(joints) == 21  # All but the free joint (now the frame's).
  for field in ('jnt_range', 'jnt_stiffness', 'jnt_axis'):
    np.testing.assert_allclose(
        getattr(model, field)[joints], getattr(ref, field)[ref_joints]
    )
  np.testing.assert_allclose(model.dof_damping, ref.dof_damping)
  np.testing.assert_allclose(model.dof_armature, ref.dof_armature)
  actuators, ref_actuators = _named(model, mujoco.mjtObj.mjOBJ_ACTUATOR, ref)
  np.testing.assert_array_equal(actuators, ref_actuators)
  np.testing.assert_allclose(model.actuator_gear, ref.actuator_gear)
  np.testing.assert_allclose(model.actuator_ctrlrange, ref.actuator_ctrlrange)
  # Playground's MJX settings reach the composed root.
  for name in ('timestep', 'iterations', 'ls_iterations', 'disableflags'):
    assert getattr(model.opt, name) == getattr(ref.opt, name), name
  for name in ('max_contact_points', 'max_geom_pairs'):
    np.testing.assert_array_equal(
        model.numeric(name).data, ref.numeric(name).data
    )


def test_composition_keeps_the_dynamics(composed):
  """The same controls drive both models the same way, floor contact too."""
  env, _, ref = composed
  model = env.mj_model
  data, ref_data = mujoco.MjData(model), mujoco.MjData(ref)
  ctrl = np.random.default_rng(0).uniform(-1, 1, (100, model.nu))
  contacts = 0
  for u in ctrl:
    data.ctrl[:], ref_data.ctrl[:] = u, u
    mujoco.mj_step(model, data)
    mujoco.mj_step(ref, ref_data)
    contacts = max(contacts, ref_data.ncon)
  assert contacts > 0  # It landed on the floor.
  # The only difference: the attachment frame's 1e-5 kg bound mass.
  np.testing.assert_allclose(data.qpos, ref_data.qpos, atol=2e-3)


def test_observables_match_mujoco(composed):
  env, robot, _ = composed
  model = env.mj_model
  rng = np.random.default_rng(1)
  qpos = model.qpos0.copy()
  qpos[7:] += rng.uniform(-0.2, 0.2, model.nq - 7)
  qvel = rng.uniform(-0.5, 0.5, model.nv)
  ctrl = rng.uniform(-1, 1, model.nu)
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
    return values, robot.upright(physics)

  got, upright = jax.device_get(
      observe(jnp.asarray(qpos), jnp.asarray(qvel), jnp.asarray(ctrl))
  )
  data = mujoco.MjData(model)
  data.qpos[:], data.qvel[:], data.ctrl[:] = qpos, qvel, ctrl
  mujoco.mj_forward(model, data)
  assert data.ncon == 0  # In the air: accelerations are contact-free.
  torso = data.body('humanoid/torso')
  torso_mat = torso.xmat.reshape(3, 3)
  limbs = np.stack(
      [data.body('humanoid/' + name).xpos for name in humanoid.EXTREMITIES]
  )
  sensor = lambda name: data.sensor('humanoid/' + name).data
  want = {
      'joint_positions': qpos[7:],
      'joint_velocities': qvel[6:],
      'root_velocity': qvel[:6],
      'head_height': data.body('humanoid/head').xpos[2:],
      'extremities': ((limbs - torso.xpos) @ torso_mat).ravel(),
      'torso_vertical': torso_mat[2],
      'center_of_mass_velocity': sensor('torso_subtreelinvel'),
      'torso_velocity': sensor('torso_vel'),
      'gyro': sensor('torso_gyro'),
      'accelerometer': sensor('torso_accel'),
      'actuator_forces': data.actuator_force,
  }
  assert set(got) == set(want)
  for name, value in want.items():
    tolerance = 2e-3 if name == 'accelerometer' else 1e-4
    np.testing.assert_allclose(
        got[name], value, rtol=tolerance, atol=tolerance, err_msg=name
    )
  assert float(upright) == pytest.approx(torso_mat[2, 2], abs=1e-5)


def test_robot_without_simulation_options_keeps_the_root_ones():
  """Nothing of the robot's solver settings leaks without the root's say."""
  arena = arenas.Floor()
  robot = humanoid.Humanoid(name='other')
  arena.add_free_entity(robot)
  spec, _ = arena.compose()
  with pytest.warns(UserWarning, match='keeping parent value'):
    model = spec.compile()
  assert model.opt.timestep == 0.002  # The arena's, not the XML's 0.005.
  assert robot.simulation_options['timestep'] == 0.005
  names = [model.numeric(i).name for i in range(model.nnumeric)]
  assert 'other/max_contact_points' not in names
  assert robot.name == 'other' and model.body('other/torso').id > 0
