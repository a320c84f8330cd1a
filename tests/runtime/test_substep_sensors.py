"""Tests for `substep_sensors`: sensors computed once per control step.

`sensors_of` is held to `mjx.step` and to MuJoCo's `mj_step` on a model
with sensors of every stage (some read `qpos`, `qvel` and `time`, which the
integrator advances); `Transitions.sensors_once_per_step` to what runs
between the sub-steps; and environments that compute the sensors once to
the same environments with `substep_sensors='all'`.
"""

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.runtime import data_reads
from mjx_composer.runtime import reset_forward
from mjx_composer.runtime import substep_sensors
from tests import conftest
from tests.runtime import test_reset_forward

# `test_reset_forward`'s model (a hinge and a ball joint, a tendon, a free
# ball on a floor, every position and velocity sensor type), its ball low
# enough to touch the floor (contacts: constraint rows), and sensors of the
# acceleration stage.
_ACCELERATION_SENSORS = """
    <accelerometer site="sa"/>
    <force site="sb"/>
    <torque site="sb"/>
    <framelinacc objtype="site" objname="sa"/>
    <touch site="sball"/>
    <actuatorfrc actuator="m"/>
  </sensor>"""
_XML = test_reset_forward._SENSORS_XML.replace(
    '<geom type="sphere" size="0.1" mass="0.2"/>',
    '<geom type="sphere" size="0.1" mass="0.2"/><site name="sball" size="0.11"/>',
).replace('  </sensor>', _ACCELERATION_SENSORS)


@pytest.fixture(scope='module')
def sensed():
  """The host model, its device model and data away from rest."""
  m = mujoco.MjModel.from_xml_string(_XML)
  d = test_reset_forward._moving_state(m)
  free = m.jnt_qposadr[m.body('free').jntadr[0]]
  d.qpos[free + 2] = 0.09  # the ball touches the floor
  return m, mjx.put_model(m), d


def _step_without_sensors(model, data):
  started = substep_sensors.IntegrationState.of(data)
  stepped = mjx.step(substep_sensors.without_sensors(model), data)
  return substep_sensors.sensors_of(model, stepped, started)


def test_sensors_of_a_step_are_mjx_steps_and_mujocos(sensed):
  m, model, d = sensed
  data = mjx.put_data(m, d)
  once = jax.jit(lambda x: _step_without_sensors(model, x))(data)
  every = jax.jit(lambda x: mjx.step(model, x))(data)
  assert int(np.asarray(data._impl.efc_J).shape[0])  # contacts: rows
  for name, a, b in zip(
      data_reads.leaf_names(data), jax.tree.leaves(once), jax.tree.leaves(every)
  ):
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5, err_msg=name)
  # MuJoCo's own step, in double precision.
  host = mujoco.MjData(m)
  host.qpos[:], host.qvel[:], host.ctrl[:] = d.qpos, d.qvel, d.ctrl
  host.time = d.time
  mujoco.mj_step(m, host)
  # float32 against float64 on this fixed state: 2.0e-6 at most (the
  # frame's linear acceleration, of 4.9; the accelerometer 1.7e-6 of 5.3,
  # the touch sensor 1.1e-6 of 22.9; 2.8e-6 fully optimized), every
  # position and velocity sensor within 4e-7. atol=1e-5 allows 3.5 times
  # the largest.
  np.testing.assert_allclose(
      once.sensordata, host.sensordata, rtol=1e-6, atol=1e-5
  )
  np.testing.assert_allclose(once.qpos, host.qpos, rtol=1e-4, atol=1e-5)
  # The sensors that read the integration state see it before the step.
  clock = m.sensor_adr[list(m.sensor_type).index(mujoco.mjtSensor.mjSENS_CLOCK)]
  assert float(once.sensordata[clock]) == pytest.approx(0.25)
  assert float(once.time) == pytest.approx(0.25 + m.opt.timestep)


@pytest.mark.parametrize('stage', ['position', 'velocity', 'full'])
def test_sensor_stages_the_step_forward_recomputes_are_skipped(sensed, stage):
  m, model, d = sensed
  data = mjx.put_data(m, d)
  step_forward = reset_forward.StepForward(stage, sensors=True)
  recomputed = step_forward.sensor_stages
  assert recomputed == {'position': 1, 'velocity': 2, 'full': 3}[stage]

  def control_step_end(x, recomputed):
    started = substep_sensors.IntegrationState.of(x)
    stepped = mjx.step(substep_sensors.without_sensors(model), x)
    sensed = substep_sensors.sensors_of(model, stepped, started, recomputed)
    return stepped, sensed, step_forward(model, sensed)

  end = jax.jit(control_step_end, static_argnums=1)
  (stepped, all_sensed, full), (_, skipped, lean) = (
      end(data, 0),
      end(data, recomputed),
  )
  # What the step's forward stage leaves is the same either way ...
  for name, a, b in zip(
      data_reads.leaf_names(data), jax.tree.leaves(full), jax.tree.leaves(lean)
  ):
    np.testing.assert_array_equal(a, b, err_msg=name)
  # ... and the skipped stages' sensors really were not computed before it.
  stages = np.asarray(m.sensor_needstage)
  rows = np.concatenate(
      [
          np.arange(m.sensor_adr[i], m.sensor_adr[i] + m.sensor_dim[i])
          for i in range(m.nsensor)
          if stages[i] <= recomputed
      ]
  )
  before = np.asarray(stepped.sensordata)[rows]
  np.testing.assert_array_equal(np.asarray(skipped.sensordata)[rows], before)
  assert np.any(np.asarray(all_sensed.sensordata)[rows] != before)


def test_outputs_are_what_the_sensor_stages_write(sensed):
  m, model, d = sensed
  data = mjx.put_data(m, d)
  with_sensors = jax.jit(lambda x: mjx.step(model, x))(data)
  without = jax.jit(
      lambda x: mjx.step(substep_sensors.without_sensors(model), x)
  )(data)
  differ = {
      name
      for name, a, b in zip(
          data_reads.leaf_names(data),
          jax.tree.leaves(with_sensors),
          jax.tree.leaves(without),
      )
      if not np.array_equal(a, b)
  }
  assert differ == substep_sensors.OUTPUTS


def test_a_model_without_constraints_keeps_its_acceleration_sensors():
  # `mjx.forward` skips the acceleration stage's sensors without
  # constraint rows; so does `sensors_of`.
  m = mujoco.MjModel.from_xml_string(
      _XML.replace(
          '<mujoco>', '<mujoco><option><flag contact="disable"/></option>'
      )
  )
  model = mjx.put_model(m)
  data = mjx.put_data(m, mujoco.MjData(m))
  assert not np.asarray(data._impl.efc_J).size
  once = jax.jit(lambda x: _step_without_sensors(model, x))(data)
  every = jax.jit(lambda x: mjx.step(model, x))(data)
  np.testing.assert_allclose(once.sensordata, every.sensordata, atol=1e-6)


class _SensingTask(conftest.SwingTask):
  """The swing task with sensors on the rod, observed at the control step:
  an accelerometer in the model's acceleration stage (or, with
  `observed='velocity'`, a gyro in its velocity stage instead), a clock.

  `between`: what also runs between sub-steps: None; 'buffered' (the
  accelerometer also observed with a buffer of every sub-step's sample);
  'before_substep' (a hook that reads the accelerometer into a force);
  'after_substep' (a hook that writes a force on the ball);
  'after_substep_qvel' (a hook that damps the hinge's velocity); 'rk4'
  (nothing, but the Runge-Kutta integrator).
  """

  def __init__(self, between=None, observed='acceleration'):
    super().__init__()
    self.between = between
    self.observed = observed
    spec = self.pendulum.mjcf_model
    spec.body('rod').add_site(name='imu', pos=[0, 0, -0.25])
    self.accelerometer = spec.add_sensor(
        name='accelerometer',
        type=mujoco.mjtSensor.mjSENS_ACCELEROMETER,
        objtype=mujoco.mjtObj.mjOBJ_SITE,
        objname='imu',
    )
    self.gyro = spec.add_sensor(
        name='gyro',
        type=mujoco.mjtSensor.mjSENS_GYRO,
        objtype=mujoco.mjtObj.mjOBJ_SITE,
        objname='imu',
    )
    self.clock = spec.add_sensor(
        name='clock', type=mujoco.mjtSensor.mjSENS_CLOCK
    )
    if between == 'rk4':
      self.arena.mjcf_model.option.integrator = mujoco.mjtIntegrator.mjINT_RK4

  @property
  def task_observables(self):
    observables = dict(super().task_observables)
    rate = (
        ('accelerometer', self.accelerometer)
        if self.observed == 'acceleration'
        else ('gyro', self.gyro)
    )
    for name, sensor, buffered in (
        (*rate, False),
        ('clock', self.clock, False),
        ('accelerometer_buffered', self.accelerometer, True),
    ):
      if buffered and self.between != 'buffered':
        continue
      observable = composer.observation.observable.Generic(
          lambda physics, sensor=sensor: physics.bind(sensor).sensordata
      )
      observable.enabled = True
      if buffered:
        observable.buffer_size = 2
      observables[name] = observable
    return observables

  def initialize_episode(self, physics, key):
    physics = super().initialize_episode(physics, key)
    if self.observed != 'velocity':
      return physics
    # A gyro at rest reads zero before and after any forward pass.
    qvel = jax.random.uniform(
        jax.random.fold_in(key, 1), physics.data.qvel.shape, minval=-2
    )
    return physics.replace(data=physics.data.replace(qvel=qvel))

  def before_substep(self, physics, action, key):
    physics = super().before_substep(physics, action, key)
    if self.between != 'before_substep':
      return physics
    read = jnp.sum(physics.bind(self.accelerometer).sensordata)
    applied = physics.data.qfrc_applied.at[0].set(1e-3 * read)
    return physics.replace(data=physics.data.replace(qfrc_applied=applied))

  def after_substep(self, physics, key):
    physics = super().after_substep(physics, key)
    if self.between == 'after_substep':
      applied = physics.data.xfrc_applied.at[-1, 0].set(0.01)
      return physics.replace(data=physics.data.replace(xfrc_applied=applied))
    if self.between == 'after_substep_qvel':
      return physics.replace(
          data=physics.data.replace(qvel=0.99 * physics.data.qvel)
      )
    return physics


def assert_close_episodes(a_states, b_states):
  """Two rollouts' observations, rewards, discounts, metrics and data agree
  to float32 rounding (1e-5), their step types exactly."""
  for a, b in zip(a_states, b_states, strict=True):
    for name in ('observation', 'reward', 'discount', 'metrics'):
      jax.tree.map(
          lambda x, y: np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-5),
          getattr(a, name),
          getattr(b, name),
      )
    for name, x, y in zip(
        data_reads.leaf_names(a.data),
        jax.tree.leaves(a.data),
        jax.tree.leaves(b.data),
    ):
      np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-5, err_msg=name)
    np.testing.assert_array_equal(a.step_type, b.step_type)


def _make_env(mode, between=None, observed='acceleration', **options):
  options.setdefault('share_reset_forward', False)
  return composer.Environment(
      _SensingTask(between, observed),
      time_limit=0.1,
      options=composer.ExecutionOptions(substep_sensors=mode, **options),
  )


@pytest.mark.parametrize(
    'between, observed, share_reset_forward',
    [
        (None, 'acceleration', False),
        ('after_substep_qvel', 'acceleration', False),
        # The fused restart: its forward pass, the sub-steps' too, skips the
        # sensors; the reset's stage ('full' for the accelerometer,
        # 'velocity' for the gyro) computes its own once.
        (None, 'acceleration', True),
        (None, 'velocity', True),
    ],
)
def test_sensors_once_per_step_make_the_same_episodes(
    between, observed, share_reset_forward
):
  kwargs = dict(share_reset_forward=share_reset_forward)
  once_env = _make_env('read', between, observed, **kwargs)
  every_env = _make_env('all', between, observed, **kwargs)
  # Stepped first: the step decides from its own state, then reports it.
  # 12 steps of 10-step episodes: each world restarts once (same step).
  once, every = test_reset_forward.rollout(
      once_env, 12
  ), test_reset_forward.rollout(every_env, 12)
  assert np.asarray(once[10].last()).all()
  # The fused restart as asked for (the task's Euler model can fuse it).
  assert once_env.share_reset_forward == share_reset_forward
  assert once_env.options.share_reset_forward == share_reset_forward
  assert once_env.reset_forward_stage == (
      'full' if observed == 'acceleration' else 'velocity'
  )
  assert once_env.sensors_once_per_step
  assert not every_env.sensors_once_per_step
  assert_close_episodes(once, every)
  # The observed sensors change over the episode: the test sees them.
  rate = 'accelerometer' if observed == 'acceleration' else 'gyro'
  final = np.asarray(once[9].observation[rate])
  assert np.abs(final - np.asarray(once[1].observation[rate])).max() > 0.1
  # The restarted worlds' first observation is the reset's, not the ended
  # episode's (nor zero: the gyro's worlds start moving).
  restarted = np.asarray(once[10].observation[rate]).reshape(3, -1)
  final = final.reshape(3, -1)
  assert np.abs(restarted - final).max(axis=1).min() > 1e-3
  assert np.abs(restarted).max(axis=1).min() > 1e-3
  # The clock, a position sensor, reads the time after the control step's
  # last sub-step, as after composer's `Physics.step` (whose `mj_step1`
  # computes the position sensors at the new state).
  np.testing.assert_allclose(
      once[2].observation['clock'][:, 0], 2 * 0.01, atol=1e-6
  )


@pytest.mark.parametrize(
    'between', ['buffered', 'before_substep', 'after_substep', 'rk4']
)
def test_sensors_read_or_disturbed_between_substeps_stay_in_every_substep(
    between,
):
  assert not _make_env('read', between).sensors_once_per_step


def test_a_single_substep_keeps_mjx_step():
  task = _SensingTask()
  task.set_timesteps(control_timestep=0.005, physics_timestep=0.005)
  env = composer.Environment(
      task,
      time_limit=0.1,
      options=composer.ExecutionOptions(share_reset_forward=False),
  )
  assert not env.sensors_once_per_step


def test_the_locomotion_tasks_compute_their_sensors_once_per_step():
  # pylint: disable=g-import-not-at-top
  from mjx_composer.suite.tasks import joystick
  from mjx_composer.suite.tasks import walk

  # pylint: enable=g-import-not-at-top
  # Walk shipped (pushes, falls, noise, delay, history, the critic's
  # accelerometer) and like Playground's HumanoidWalk; the quadruped's
  # joystick (foot contacts, feet air time).
  for task in (
      walk.Walk(),
      walk.Walk(**walk.PLAYGROUND_EQUIVALENT),
      joystick.Joystick(),
  ):
    env = composer.Environment(
        task,
        time_limit=1.0,
        options=composer.ExecutionOptions(share_reset_forward=False),
    )
    assert env.sensors_once_per_step


def test_substep_sensors_must_be_read_or_all():
  with pytest.raises(ValueError, match="'read' or 'all'"):
    _make_env('some')
