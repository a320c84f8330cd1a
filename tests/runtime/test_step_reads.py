"""No silent lag: what a control step's observables read is what composer's
physics holds after `Physics.step`.

dm_control's `Physics.step` runs `mj_step2` then `mj_step1`, so after a step
the position and velocity stages (poses, velocities, their sensors) are of
the new state and the acceleration stage (accelerometer, touch) of the
state the step started from. The reference is dm_control's own
`mujoco.Physics` on the same compiled model, started at each control step
from the environment's state and stepped with the same action: the
comparison is of which state each value belongs to, free of any drift
between float32 and float64 trajectories.
"""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.observation import observable
from tests import conftest

_N_STEPS = 12


class _Hopper(conftest.SpecEntity):
  """A box torso on a hinged leg, free to fall on the floor, with an
  accelerometer, a velocimeter and a z axis on the torso and a touch
  sensor on the leg."""

  def _build(self, name='hopper'):
    spec = self._new_spec(name)
    torso = spec.worldbody.add_body(name='torso', pos=[0, 0, 0.22])
    self.torso = torso
    torso.add_geom(
        name='torso', type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.1, 0.08, 0.05]
    )
    torso.add_site(name='imu', size=[0.01, 0, 0])
    leg = torso.add_body(name='leg', pos=[0.1, 0, 0])
    leg.add_site(
        name='pad',
        type=mujoco.mjtGeom.mjGEOM_BOX,
        pos=[0, 0, -0.15],
        size=[0.06, 0.06, 0.1],
    )
    self.hip = leg.add_joint(
        name='hip',
        type=mujoco.mjtJoint.mjJNT_HINGE,
        axis=[0, 1, 0],
        range=[-1, 1],
    )
    leg.add_geom(
        name='leg',
        type=mujoco.mjtGeom.mjGEOM_CAPSULE,
        size=[0.03, 0, 0],
        fromto=[0, 0, 0, 0, 0, -0.2],
    )
    self.foot = leg.add_site(name='foot', pos=[0, 0, -0.2])
    self.motor = spec.add_actuator(
        name='motor', target='hip', trntype=mujoco.mjtTrn.mjTRN_JOINT
    )
    self.motor.gear[0] = 5
    site = mujoco.mjtObj.mjOBJ_SITE
    self.sensors = [
        spec.add_sensor(
            name='acc',
            type=mujoco.mjtSensor.mjSENS_ACCELEROMETER,
            objtype=site,
            objname='imu',
        ),
        spec.add_sensor(
            name='touch',
            type=mujoco.mjtSensor.mjSENS_TOUCH,
            objtype=site,
            objname='pad',
        ),
        spec.add_sensor(
            name='vel',
            type=mujoco.mjtSensor.mjSENS_VELOCIMETER,
            objtype=site,
            objname='imu',
        ),
        spec.add_sensor(
            name='zaxis',
            type=mujoco.mjtSensor.mjSENS_FRAMEZAXIS,
            objtype=site,
            objname='imu',
        ),
    ]

  @property
  def actuators(self):
    return (self.motor,)


class _HopTask(composer.Task):
  """Observes the hopper's sensors, its foot's position, its torso's
  `subtree_linvel` (composer's walkers' `torso_xvel` reads it) and the
  last row of the torso's `xmat`, as dm_control binds them."""

  def __init__(self):
    self.arena = composer.Arena()
    self.arena.mjcf_model.worldbody.add_geom(
        name='floor', type=mujoco.mjtGeom.mjGEOM_PLANE, size=[2, 2, 0.1]
    )
    self.hopper = _Hopper()
    self.arena.add_free_entity(self.hopper)
    self.set_timesteps(control_timestep=0.01, physics_timestep=0.005)

  @property
  def root_entity(self):
    return self.arena

  @property
  def task_observables(self):
    hopper = self.hopper
    found = {
        'sensors': observable.MJCFFeature('sensordata', hopper.sensors),
        'foot': observable.MJCFFeature('xpos', hopper.foot),
        'torso_xvel': observable.MJCFFeature('subtree_linvel', hopper.torso),
        'upright': observable.MJCFFeature('xmat', hopper.torso)[6:],
    }
    for obs in found.values():
      obs.enabled = True
    return found

  def get_reward(self, physics):
    return physics.bind(self.hopper.foot).xpos[2]


def _read(physics, names):
  """The reference's values of the task's observables, by compiled name.

  MuJoCo computes `subtree_linvel` only where a sensor needs it: what a
  binding reads is `mj_subtreeVel`'s on the stepped state.
  """
  mujoco.mj_subtreeVel(physics.model.ptr, physics.data.ptr)
  data = physics.data
  return {
      'sensors': np.array(data.sensordata),
      'foot': np.array(physics.named.data.site_xpos[names['foot']]),
      'torso_xvel': np.array(physics.named.data.subtree_linvel[names['torso']]),
      'upright': np.array(physics.named.data.xmat[names['torso']][6:]),
  }


@pytest.fixture(scope='module')
def episode():
  """`_N_STEPS` control steps of one world with scripted actions: the states
  and actions."""
  task = _HopTask()
  env = composer.Environment(task)
  reset, step = jax.jit(env.reset), jax.jit(env.step)
  state = reset(jax.random.key(0))
  states, actions = [state], []
  for i in range(_N_STEPS):
    action = jnp.array([np.sin(0.7 * i)], jnp.float32)
    state = step(state, action)
    states.append(state)
    actions.append(np.asarray(action))
  return env, states, actions


def test_step_recomputes_what_its_readers_read(episode):
  env, _, _ = episode
  assert env._transitions.step_forward.stage == 'velocity'  # pylint: disable=protected-access


def test_observations_are_composers_after_each_step(episode):
  """Each observation against dm_control's physics stepped from the same
  state with the same action: poses, velocities and their sensors of the
  new state, acceleration and touch of the state the step started from."""
  from dm_control import mujoco as dm_mujoco  # pylint: disable=g-import-not-at-top

  env, states, actions = episode
  mjb = np.zeros(mujoco.mj_sizeModel(env.mj_model), np.uint8)
  mujoco.mj_saveModel(env.mj_model, None, mjb)
  physics = dm_mujoco.Physics.from_byte_string(mjb.tobytes())
  names = {'foot': 'hopper/foot', 'torso': 'hopper/torso'}
  touched = 0
  for before, action, after in zip(states, actions, states[1:]):
    with physics.reset_context():
      for field in ('qpos', 'qvel', 'act', 'qacc_warmstart'):
        getattr(physics.data, field)[:] = np.asarray(
            getattr(before.data, field)
        )
      physics.data.time = float(before.data.time)
    physics.set_control(action)
    for _ in range(env.n_sub_steps):
      physics.step()
    expected = _read(physics, names)
    touched += expected['sensors'][3] > 0
    for key, value in expected.items():
      np.testing.assert_allclose(
          np.asarray(after.observation[key]).reshape(value.shape),
          value,
          rtol=2e-3,
          atol=2e-3 * max(1.0, float(np.max(np.abs(value)))),
          err_msg=f'{key} at t={float(after.data.time):.3f}',
      )
    np.testing.assert_allclose(
        after.reward, expected['foot'][2], rtol=1e-4, atol=1e-5
    )
  assert touched, 'the scripted episode never touches the floor'


class _BindingHopTask(_HopTask):
  """`_HopTask` applying its action as dm_control's walkers do: `ctrl`
  written through a binding in `before_step`."""

  def before_step(self, physics, action, key):
    del key
    return physics.bind(self.hopper.motor).set(ctrl=action[0])


def test_a_ctrl_written_through_a_binding_makes_composers_next_read_forward(
    episode,
):
  """Every dm_control walker writes `ctrl` through a binding in
  `apply_action`. That marks dm_control's physics dirty, `Physics.step`
  leaves the mark, and the first binding read after the step runs
  `mj_forward`: composer's accelerometer and touch after such a control
  step are of the new state, not of the state its last sub-step started
  from (what `set_control` gives). Ours end such a step with the forward
  pass (`runtime/dirty_forward.py`): the same values, with no forward pass
  in the task."""
  from dm_control import mjcf  # pylint: disable=g-import-not-at-top

  env, _, actions = episode
  # PyMJCF takes no '/' in a name: the same model, its prefix spelt '_'.
  mjcf_model = mjcf.from_xml_string(
      env.spec.to_xml().replace('hopper/', 'hopper_')
  )
  physics = mjcf.Physics.from_mjcf_model(mjcf_model)
  motor = mjcf_model.find('actuator', 'hopper_motor')
  sensors = [
      mjcf_model.find('sensor', f'hopper_{name}')
      for name in ('acc', 'touch', 'vel', 'zaxis')
  ]
  binding = composer.Environment(_BindingHopTask())
  assert binding.step_forward_stage == 'full'
  reset, step = jax.jit(binding.reset), jax.jit(binding.step)
  state = reset(jax.random.key(0))
  moved = 0.0
  for action in actions:
    with physics.reset_context():
      for field in ('qpos', 'qvel', 'act', 'qacc_warmstart'):
        getattr(physics.data, field)[:] = np.asarray(getattr(state.data, field))
      physics.data.time = float(state.data.time)
    physics.bind([motor]).ctrl = action  # A walker's apply_action.
    for _ in range(env.n_sub_steps):
      physics.step()
    stepped = np.array(physics.data.sensordata)  # What set_control leaves.
    composers = np.array(physics.bind(sensors).sensordata)
    state = step(state, jnp.asarray(action))
    scale = max(1.0, float(np.max(np.abs(composers))))
    np.testing.assert_allclose(
        np.asarray(state.observation['sensors']).reshape(-1),
        composers,
        rtol=2e-3,
        atol=2e-3 * scale,
        err_msg=f't={float(state.data.time):.3f}',
    )
    moved = max(moved, float(np.max(np.abs(composers - stepped))) / scale)
  # The read's forward pass changed the sensors: the test tells the two
  # timings apart. Through `set_control`, ours are the stepped values
  # (`test_observations_are_composers_after_each_step`).
  assert moved > 0.05
