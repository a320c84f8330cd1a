"""Tests for `reset_forward`: the stage of the forward pass a reset runs.

The reduced stages are held to MJX's forward pass and MuJoCo's (sensors),
the readers' analysis to what tasks read, and environments that reset with
a reduced stage to the same environments with `reset_forward='full'`.
"""

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.platform import internals_jax
from mjx_composer.runtime import data_reads
from mjx_composer.runtime import reset_forward
from tests import conftest
from tests import test_environment

# Every sensor type the reduced stages compute (POSITION_SENSORS and
# VELOCITY_SENSORS), on a hinge, a ball joint, a tendon and a free body.
_SENSORS_XML = """
<mujoco>
  <worldbody>
    <geom type="plane" size="2 2 0.1"/>
    <body name="a" pos="0 0 1">
      <joint name="hinge" axis="0 1 0" damping="0.1"/>
      <geom type="capsule" size="0.05" fromto="0 0 0 0.3 0 0" mass="1"/>
      <site name="sa" pos="0.3 0 0" euler="0.2 0.4 0"/>
      <body name="b" pos="0.3 0 0">
        <joint name="ball" type="ball" damping="0.1"/>
        <geom type="box" size="0.05 0.1 0.05" mass="0.5"/>
        <site name="sb" pos="0.1 0.02 0"/>
      </body>
    </body>
    <body name="free" pos="0.5 0.5 0.3">
      <freejoint/>
      <geom type="sphere" size="0.1" mass="0.2"/>
    </body>
  </worldbody>
  <tendon><fixed name="t"><joint joint="hinge" coef="1.5"/></fixed></tendon>
  <actuator>
    <motor name="m" joint="hinge" gear="2"/>
    <position name="p" tendon="t" kp="5"/>
  </actuator>
  <sensor>
    <jointpos joint="hinge"/>
    <tendonpos tendon="t"/>
    <actuatorpos actuator="m"/>
    <ballquat joint="ball"/>
    <framepos objtype="site" objname="sb"/>
    <framequat objtype="body" objname="b"/>
    <framexaxis objtype="site" objname="sa"/>
    <frameyaxis objtype="site" objname="sa"/>
    <framezaxis objtype="body" objname="free"/>
    <subtreecom body="a"/>
    <clock/>
    <velocimeter site="sb"/>
    <gyro site="sb"/>
    <jointvel joint="hinge"/>
    <tendonvel tendon="t"/>
    <actuatorvel actuator="p"/>
    <ballangvel joint="ball"/>
    <framelinvel objtype="body" objname="free"/>
    <frameangvel objtype="site" objname="sb"/>
    <subtreelinvel body="a"/>
    <subtreeangmom body="a"/>
  </sensor>
</mujoco>
"""


def _moving_state(m):
  """A model and data away from rest: random joint positions, velocities."""
  rng = np.random.default_rng(0)
  d = mujoco.MjData(m)
  d.qpos[:] = m.qpos0 + rng.uniform(-0.5, 0.5, m.nq)
  mujoco.mj_normalizeQuat(m, d.qpos)
  d.qvel[:] = rng.uniform(-2, 2, m.nv)
  d.ctrl[:] = rng.uniform(-1, 1, m.nu)
  d.time = 0.25
  return d


@pytest.fixture(scope='module')
def sensor_model():
  m = mujoco.MjModel.from_xml_string(_SENSORS_XML)
  return m, mjx.put_model(m), _moving_state(m)


def test_the_test_model_has_every_sensor_the_stages_compute(sensor_model):
  m, _, _ = sensor_model
  types = {mujoco.mjtSensor(int(t)) for t in m.sensor_type}
  assert types == reset_forward.POSITION_SENSORS | (
      reset_forward.VELOCITY_SENSORS
  )


def test_what_a_stage_writes_is_traced_once_per_model_structure(
    sensor_model, monkeypatch
):
  m, model, d = sensor_model
  data = mjx.put_data(m, d)
  traced = []
  trace = reset_forward._trace_written  # pylint: disable=protected-access
  monkeypatch.setattr(reset_forward, '_WRITTEN', data_reads.PerStructure())
  monkeypatch.setattr(
      reset_forward,
      '_trace_written',
      lambda *args: traced.append(args[0]) or trace(*args),
  )
  full = reset_forward.written('full', model, data)
  # Abstract data of the same shapes, and another put_model of the same
  # model: the same answer, without a second trace.
  assert (
      reset_forward.written('full', model, jax.eval_shape(lambda: data)) == full
  )
  assert reset_forward.written('full', mjx.put_model(m), data) == full
  assert traced == ['full']
  assert full == trace('full', model, data, True)
  # A model that differs in a static field MJX branches on (its sensors
  # disabled) is traced anew, and its forward pass writes no sensordata.
  m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_SENSOR
  try:
    no_sensors = mjx.put_model(m)
  finally:
    m.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
  without = reset_forward.written('full', no_sensors, data)
  assert traced == ['full', 'full']
  assert 'sensordata' in full and 'sensordata' not in without


@pytest.mark.parametrize('stage', ['position', 'velocity'])
def test_reduced_stages_compute_what_the_forward_pass_does(sensor_model, stage):
  m, model, d = sensor_model
  data = mjx.put_data(m, d)
  reduced = jax.jit(lambda x: reset_forward.forward(stage, model, x))(data)
  full = jax.jit(lambda x: reset_forward.forward('full', model, x))(data)
  writes = reset_forward.written(stage, model, data)
  assert {'xpos', 'site_xpos', 'subtree_com', 'sensordata'} <= writes
  assert ('cvel' in writes) == (stage == 'velocity')
  assert not writes & {'qacc', 'qfrc_bias', 'qfrc_constraint'}
  names = data_reads.leaf_names(data)
  for name, a, b in zip(names, jax.tree.leaves(reduced), jax.tree.leaves(full)):
    if name in writes and name != 'sensordata':
      np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6, err_msg=name)
  # Sensors against MuJoCo's forward pass with actuation disabled: all of
  # them on the velocity stage, the position sensors on the position stage.
  m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_ACTUATION
  try:
    host = mujoco.MjData(m)
    host.qpos[:], host.qvel[:], host.ctrl[:] = d.qpos, d.qvel, d.ctrl
    host.time = d.time
    mujoco.mj_forward(m, host)
  finally:
    m.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_ACTUATION)
  computed = (
      reset_forward.POSITION_SENSORS
      if stage == 'position'
      else reset_forward.POSITION_SENSORS | reset_forward.VELOCITY_SENSORS
  )
  checked = 0
  for i in range(m.nsensor):
    rows = slice(m.sensor_adr[i], m.sensor_adr[i] + m.sensor_dim[i])
    kind = mujoco.mjtSensor(int(m.sensor_type[i]))
    if kind not in computed:
      continue
    got = np.asarray(reduced.sensordata)[rows]
    # As MJX's forward pass, which the reduced stage replaces.
    np.testing.assert_allclose(
        got, np.asarray(full.sensordata)[rows], rtol=1e-5, atol=1e-6
    )
    # As MuJoCo's, but for actuator velocities: with actuation disabled,
    # MuJoCo zeroes them and MJX 3.17's forward pass does not.
    if kind != mujoco.mjtSensor.mjSENS_ACTUATORVEL:
      np.testing.assert_allclose(
          got, host.sensordata[rows], rtol=1e-4, atol=1e-5, err_msg=str(kind)
      )
    checked += 1
  assert checked == len(computed)
  # With actuation disabled, as composer's reset.
  np.testing.assert_array_equal(reduced.qfrc_actuator, 0.0)
  np.testing.assert_array_equal(reduced.act_dot, 0.0)


def test_sensor_stage():
  def stage(sensors):
    xml = _SENSORS_XML.split('<sensor>')[0] + f'<sensor>{sensors}</sensor>'
    return reset_forward.sensor_stage(
        mujoco.MjModel.from_xml_string(xml + '</mujoco>')
    )

  assert stage('') == 'none'
  assert stage('<framepos objtype="site" objname="sb"/>') == 'position'
  assert stage('<jointpos joint="hinge"/><gyro site="sb"/>') == 'velocity'
  assert stage('<gyro site="sb"/><accelerometer site="sb"/>') == 'full'
  assert stage('<touch site="sb"/>') == 'full'


def test_choose_stage(sensor_model):
  m, model, d = sensor_model
  data = mjx.put_data(m, d)

  def choose(*needed):
    chosen = reset_forward.choose_stage(needed, model, data, m)
    return chosen.stage, chosen.sensors

  assert choose() == ('none', False)
  assert choose('qvel', 'ctrl') == ('none', False)  # not derived
  # MJX's kinematics writes qpos (its quaternions normalized).
  assert choose('qpos') == ('position', False)
  assert choose('xpos', 'site_xmat') == ('position', False)
  assert choose('subtree_com', 'cvel') == ('velocity', False)
  assert choose('xpos', 'qacc') == ('full', True)
  assert choose('qfrc_bias') == ('full', True)
  # Every sensor here is a velocity-stage sensor or less.
  assert choose('sensordata') == ('velocity', True)
  with_accelerometer = mujoco.MjModel.from_xml_string(
      _SENSORS_XML.replace('<clock/>', '<clock/><accelerometer site="sb"/>')
  )
  chosen = reset_forward.choose_stage(
      ['sensordata'],
      mjx.put_model(with_accelerometer),
      mjx.make_data(with_accelerometer),
      with_accelerometer,
  )
  assert (chosen.stage, chosen.sensors) == ('full', True)
  assert chosen.writes == chosen.derived


def _with_accelerometer():
  """The sensor model with an accelerometer after its other sensors."""
  m = mujoco.MjModel.from_xml_string(
      _SENSORS_XML.replace('</sensor>', '<accelerometer site="sb"/></sensor>')
  )
  return m, mjx.put_model(m), mjx.make_data(m)


def _gyro_elements(m):
  gyro = int(np.flatnonzero(m.sensor_type == mujoco.mjtSensor.mjSENS_GYRO)[0])
  return frozenset(range(m.sensor_adr[gyro], m.sensor_adr[gyro] + 3))


def test_choose_stage_from_the_sensors_read(sensor_model):
  m, model, data = _with_accelerometer()
  adr = int(m.sensor_adr[m.nsensor - 1])  # the accelerometer's

  def choose(elements):
    return reset_forward.choose_stage(
        ['sensordata'], model, data, m, sensordata=elements
    )

  # Only the gyro read: the velocity stage, which leaves the accelerometer.
  chosen = choose(_gyro_elements(m))
  assert (chosen.stage, chosen.sensors) == ('velocity', True)
  expected = np.ones(m.nsensordata, bool)
  expected[adr : adr + 3] = False
  np.testing.assert_array_equal(chosen.sensor_rows, expected)
  # One element of the accelerometer read, or not known which: full.
  assert choose(_gyro_elements(m) | {adr + 1}).stage == 'full'
  assert choose(None).stage == 'full'
  # Where the stage computes every sensor, nothing is masked.
  m, model, _ = sensor_model
  chosen = reset_forward.choose_stage(
      ['sensordata'],
      model,
      mjx.make_data(m),
      m,
      sensordata=_gyro_elements(m),
  )
  assert chosen.stage == 'velocity' and chosen.sensor_rows is None


def test_a_reduced_stage_keeps_the_sensors_it_does_not_compute():
  m, model, _ = _with_accelerometer()
  d = _moving_state(m)
  data = mjx.put_data(m, d)
  before = data.replace(sensordata=jnp.full_like(data.sensordata, 7.0))
  adr = int(m.sensor_adr[m.nsensor - 1])  # the accelerometer's
  chosen = reset_forward.choose_stage(
      ['sensordata'], model, data, m, sensordata=_gyro_elements(m)
  )
  reduced = jax.jit(lambda x: chosen(model, x))(before)
  full = jax.jit(lambda x: reset_forward.forward('full', model, x))(before)
  got, want = np.asarray(reduced.sensordata), np.asarray(full.sensordata)
  np.testing.assert_array_equal(got[adr : adr + 3], 7.0)
  assert np.abs(want[adr : adr + 3] - 7.0).max() > 1.0
  np.testing.assert_allclose(got[:adr], want[:adr], rtol=1e-5, atol=1e-6)
  # A fused restart's full pass, restricted, leaves the same.
  restricted = chosen.restrict(full, before)
  np.testing.assert_array_equal(restricted.sensordata[adr : adr + 3], 7.0)
  np.testing.assert_array_equal(restricted.sensordata[:adr], want[:adr])


def test_without_dead_code_elimination_everything_counts_as_read(
    sensor_model, monkeypatch
):
  m, model, _ = sensor_model
  data = mjx.make_data(model)
  monkeypatch.setattr(internals_jax, 'dce_jaxpr', None)
  read = data_reads.reads(lambda d: (d.qvel, d.xpos), data)
  assert read.fields == set(data_reads.leaf_names(data))
  assert read.sensordata is None
  chosen = reset_forward.choose_stage(
      read.fields, model, data, m, sensordata=read.sensordata
  )
  assert chosen.stage == 'full'


# -- environments ------------------------------------------------------------


class _ReadsInBeforeStep(conftest.SwingTask):
  """The swing task whose `before_step` reads a derived field of the state
  it starts from (a force from the rod's velocity, or from `qacc`)."""

  def __init__(self, field):
    super().__init__()
    self.field = field

  def before_step(self, physics, action, key):
    read = jnp.sum(getattr(physics.data, self.field))
    applied = physics.data.qfrc_applied.at[0].set(1e-3 * read)
    return physics.replace(data=physics.data.replace(qfrc_applied=applied))


def rollout(env, steps):
  """The states of 3 worlds over `steps` steps of random one-dim actions."""
  states = [
      jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(1), 3))
  ]
  step = jax.jit(jax.vmap(env.step))
  actions = jax.random.uniform(jax.random.key(2), (steps, 3, 1), minval=-1)
  for action in actions:
    states.append(step(states[-1], action))
  return states


def _rollouts(make_env, steps=7):
  """States of `steps` steps of 3 worlds (episodes of 5) in both modes."""
  out = {}
  for mode in ('observed', 'full'):
    env = make_env(mode)
    out[mode] = (env, rollout(env, steps))
  return out


def _assert_same_episodes(observed, full):
  """Observations, rewards, metrics and the integration state, bit for bit."""
  for a, b in zip(observed, full):
    for name in ('observation', 'reward', 'discount', 'step_type', 'metrics'):
      test_environment.assert_trees_equal(getattr(a, name), getattr(b, name))
    for name in ('qpos', 'qvel', 'act', 'qacc_warmstart', 'time'):
      np.testing.assert_array_equal(
          getattr(a.data, name), getattr(b.data, name), err_msg=name
      )


@pytest.mark.parametrize('auto_reset', ['same_step', 'next_step'])
@pytest.mark.parametrize('share_reset_forward', [True, False])
def test_observed_resets_make_the_same_episodes(
    auto_reset, share_reset_forward
):
  runs = _rollouts(
      lambda mode: conftest.make_swing_env(
          time_limit=0.05,
          options=composer.ExecutionOptions(
              auto_reset=auto_reset,
              share_reset_forward=share_reset_forward,
              reset_forward=mode,
          ),
      )
  )
  env, observed = runs['observed']
  full_env, full = runs['full']
  # The task observes the tip's position: kinematics suffices.
  assert env.reset_forward_stage == 'position'
  assert full_env.reset_forward_stage == 'full'
  _assert_same_episodes(observed, full)
  # The fields the stage computes are the forward pass's; the others keep
  # their values from before it (the initial data's here).
  first, first_full = observed[0], full[0]
  np.testing.assert_array_equal(first.data.site_xpos, first_full.data.site_xpos)
  initial = env.initial_physics().data
  np.testing.assert_array_equal(
      first.data.qacc, np.broadcast_to(initial.qacc, first.data.qacc.shape)
  )
  assert np.abs(np.asarray(first_full.data.qacc)).max() > 1.0  # gravity


class _ReadsAVelocitySensor(conftest.SwingTask):
  """The swing task whose `before_step` reads the model's centre-of-mass
  velocity sensor, in a model that also has an accelerometer."""

  def __init__(self):
    super().__init__()
    spec = self.arena.mjcf_model
    self.com_velocity = spec.add_sensor(
        name='com_velocity',
        type=mujoco.mjtSensor.mjSENS_SUBTREELINVEL,
        objtype=mujoco.mjtObj.mjOBJ_BODY,
        objname='world',
    )
    spec.worldbody.add_site(name='imu', pos=[0.1, 0, 0.5])
    self.accelerometer = spec.add_sensor(
        name='accelerometer',
        type=mujoco.mjtSensor.mjSENS_ACCELEROMETER,
        objtype=mujoco.mjtObj.mjOBJ_SITE,
        objname='imu',
    )

  def before_step(self, physics, action, key):
    read = jnp.sum(physics.bind(self.com_velocity).sensordata)
    applied = physics.data.qfrc_applied.at[0].set(1e-2 * read)
    return physics.replace(data=physics.data.replace(qfrc_applied=applied))


def test_resets_reading_one_sensor_skip_the_others():
  # The separate restart (`ResetForward.__call__`); the fused one's
  # `restrict` keeps the same sensors (unit test above).
  runs = _rollouts(
      lambda mode: composer.Environment(
          _ReadsAVelocitySensor(),
          time_limit=0.05,
          options=composer.ExecutionOptions(
              auto_reset='same_step',
              share_reset_forward=False,
              reset_forward=mode,
          ),
      )
  )
  env, observed = runs['observed']
  # Not 'full' for the accelerometer that nothing reads.
  assert env.reset_forward_stage == 'velocity'
  _assert_same_episodes(observed, runs['full'][1])
  accelerometer = env.mj_model.sensor('accelerometer')
  rows = slice(accelerometer.adr[0], accelerometer.adr[0] + 3)
  com = env.mj_model.sensor('com_velocity')
  com_rows = slice(com.adr[0], com.adr[0] + 3)
  # The sensor read is the full pass's; the accelerometer keeps its value
  # from before (the initial data's), which the full pass would change.
  for state, full in zip(observed[:1], runs['full'][1][:1]):
    np.testing.assert_array_equal(
        state.data.sensordata[:, com_rows], full.data.sensordata[:, com_rows]
    )
    initial = np.asarray(env.initial_physics().data.sensordata)[rows]
    np.testing.assert_array_equal(
        state.data.sensordata[:, rows],
        np.broadcast_to(initial, state.data.sensordata[:, rows].shape),
    )
    assert np.abs(full.data.sensordata[:, rows] - initial).max() > 1.0


@pytest.mark.parametrize(
    'field, stage', [('cvel', 'velocity'), ('qacc', 'full')]
)
def test_step_hooks_reading_the_reset_state_are_served(field, stage):
  runs = _rollouts(
      lambda mode: composer.Environment(
          _ReadsInBeforeStep(field),
          time_limit=0.05,
          options=composer.ExecutionOptions(
              auto_reset='same_step', reset_forward=mode
          ),
      )
  )
  assert runs['observed'][0].reset_forward_stage == stage
  _assert_same_episodes(runs['observed'][1], runs['full'][1])


def test_bundled_tasks_stages():
  from mjx_composer.suite.tasks import reach  # pylint: disable=g-import-not-at-top

  env = composer.Environment(reach.Reach(), time_limit=1.0)
  # Ball pose and velocity sensors, a delayed hand position: velocities.
  assert env.reset_forward_stage == 'velocity'


def test_walk_stages_follow_the_sensors_read():
  from mjx_composer.suite.tasks import walk  # pylint: disable=g-import-not-at-top

  # The critic group reads the torso's accelerometer: the full pass.
  assert (
      composer.Environment(walk.Walk(), time_limit=1.0).reset_forward_stage
      == 'full'
  )
  # HumanoidWalk's observation reads the centre-of-mass velocity sensor
  # alone of the humanoid's 16: velocities suffice.
  task = walk.Walk(**walk.PLAYGROUND_EQUIVALENT)
  policy = task.observation_groups()['policy']
  task.observation_groups = lambda: {'policy': policy}
  env = composer.Environment(task, time_limit=1.0)
  assert env.reset_forward_stage == 'velocity'


def test_reset_forward_must_be_observed_or_full():
  with pytest.raises(ValueError, match="'observed' or 'full'"):
    conftest.make_swing_env(
        options=composer.ExecutionOptions(reset_forward='partial')
    )


def test_physics_of_a_reset_state_is_complete():
  runs = _rollouts(
      lambda mode: conftest.make_swing_env(
          time_limit=0.05,
          options=composer.ExecutionOptions(
              auto_reset='same_step', reset_forward=mode
          ),
      ),
      steps=5,
  )
  env, observed = runs['observed']
  _, full = runs['full']
  assert env.reset_forward_stage == 'position'
  # FIRST, a step within the episode, and LAST (holding the restart).
  assert np.asarray(observed[0].first()).all()
  assert np.asarray(observed[5].last()).all()
  for i in (0, 1, 5):
    got = env.physics(observed[i]).data
    test_environment.assert_trees_close(got, full[i].data)
  # The reset state itself keeps the skipped fields; the accessor, not the
  # state, is completed.
  assert not np.allclose(observed[0].data.qacc, full[0].data.qacc)
  # One world (unbatched) too.
  world = jax.tree.map(lambda x: x[1], observed[0])
  test_environment.assert_trees_close(
      env.physics(world).data, jax.tree.map(lambda x: x[1], full[0].data)
  )
