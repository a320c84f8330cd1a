"""A walker whose task writes `ctrl` through a binding, against dm_control's
composer: the acceleration stage read after a control step (accelerometer,
touch, force and torque sensors) is composer's.

dm_control's bindings mark the physics dirty when they write `ctrl`;
`Physics.step` leaves the mark, so the observables' binding reads after the
step run `mj_forward` on the new state. The reference is dm_control's own
`composer.Environment` on the same MJCF, its physics set at each control
step to the state ours started the step from, stepped with the same action:
the comparison is of which state each value belongs to, free of drift
between float32 and float64 trajectories.

Tolerance: from the same state, ours steps in float32 (MJX) and dm_control
in float64 (MuJoCo), and both constraint solvers stop on their own
tolerances, so contact forces (touch, force and torque sensors, and through
them the accelerometer) agree to about 1e-4 of their scale (the hip's torque,
a small difference of large contact moments, to about 2e-3), not to
float32's epsilon. We allow 5e-3 of each sensor's largest magnitude over the
episode: the two timings differ by far more (the test asserts it, with
`ExecutionOptions(dirty_forward='never')`), and every touch flag must agree.
The walker's contacts use elliptic friction cones: with pyramidal ones MJX's
and MuJoCo's forward passes of the very same state already differ by up to
a fifth of a foot's touch value (friction pyramids in float32), which would
hide the timing under the solver.
"""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.observation import observable

_N_STEPS = 30

# A box torso on four hinged legs, free to fall on the floor; an
# accelerometer on the torso, a touch sensor on each foot, a force and a
# torque sensor at one hip.
_WALKER = """
<mujoco model="walker">
  <option timestep="0.005" cone="elliptic"/>
  <worldbody>
    <geom name="floor" type="plane" size="3 3 0.1"/>
    <body name="torso" pos="0 0 0.3">
      <freejoint name="root"/>
      <geom name="torso" type="box" size="0.15 0.1 0.04"/>
      <site name="imu" pos="0 0 0" size="0.01"/>
      <body name="leg_fl" pos="0.15 0.1 0">
        <joint name="hip_fl" type="hinge" axis="0 1 0" range="-1 1"/>
        <site name="hip_fl" size="0.01"/>
        <geom name="leg_fl" type="capsule" size="0.025" fromto="0 0 0 0 0 -0.18"/>
        <site name="foot_fl" type="sphere" pos="0 0 -0.18" size="0.04"/>
      </body>
      <body name="leg_fr" pos="0.15 -0.1 0">
        <joint name="hip_fr" type="hinge" axis="0 1 0" range="-1 1"/>
        <geom name="leg_fr" type="capsule" size="0.025" fromto="0 0 0 0 0 -0.18"/>
        <site name="foot_fr" type="sphere" pos="0 0 -0.18" size="0.04"/>
      </body>
      <body name="leg_bl" pos="-0.15 0.1 0">
        <joint name="hip_bl" type="hinge" axis="0 1 0" range="-1 1"/>
        <geom name="leg_bl" type="capsule" size="0.025" fromto="0 0 0 0 0 -0.18"/>
        <site name="foot_bl" type="sphere" pos="0 0 -0.18" size="0.04"/>
      </body>
      <body name="leg_br" pos="-0.15 -0.1 0">
        <joint name="hip_br" type="hinge" axis="0 1 0" range="-1 1"/>
        <geom name="leg_br" type="capsule" size="0.025" fromto="0 0 0 0 0 -0.18"/>
        <site name="foot_br" type="sphere" pos="0 0 -0.18" size="0.04"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="hip_fl" joint="hip_fl" gear="4" ctrlrange="-1 1"/>
    <motor name="hip_fr" joint="hip_fr" gear="4" ctrlrange="-1 1"/>
    <motor name="hip_bl" joint="hip_bl" gear="4" ctrlrange="-1 1"/>
    <motor name="hip_br" joint="hip_br" gear="4" ctrlrange="-1 1"/>
  </actuator>
  <sensor>
    <accelerometer name="accel" site="imu"/>
    <touch name="touch_fl" site="foot_fl"/>
    <touch name="touch_fr" site="foot_fr"/>
    <touch name="touch_bl" site="foot_bl"/>
    <touch name="touch_br" site="foot_br"/>
    <force name="hip_force" site="hip_fl"/>
    <torque name="hip_torque" site="hip_fl"/>
  </sensor>
</mujoco>
"""
_ACTUATORS = ('hip_fl', 'hip_fr', 'hip_bl', 'hip_br')
_SENSORS = (
    'accel',
    'touch_fl',
    'touch_fr',
    'touch_bl',
    'touch_br',
    'hip_force',
    'hip_torque',
)
# `sensordata` rows of each sensor, in `_SENSORS` order.
_ROWS = {
    'accel': slice(0, 3),
    'touch': slice(3, 7),
    'hip_force': slice(7, 10),
    'hip_torque': slice(10, 13),
}
_CONTROL_TIMESTEP = 0.02
_PHYSICS_TIMESTEP = 0.005


def _action(i):
  return np.sin(0.6 * i + np.arange(4)).astype(np.float32)


class _BindingWalk(composer.Task):
  """Observes the walker's sensors through a binding; writes the action
  as dm_control's walkers do (`ctrl` through a binding, in
  `before_step`), or through `set_control` (`set_control=True`)."""

  def __init__(self, set_control=False):
    self._walker = composer.ModelWrapperEntity(_WALKER)
    spec = self._walker.mjcf_model
    self._actuators = [spec.actuator(name) for name in _ACTUATORS]
    self._sensors = [spec.sensor(name) for name in _SENSORS]
    self._set_control = set_control
    self.set_timesteps(
        control_timestep=_CONTROL_TIMESTEP, physics_timestep=_PHYSICS_TIMESTEP
    )

  @property
  def root_entity(self):
    return self._walker

  @property
  def task_observables(self):
    sensors = observable.MJCFFeature('sensordata', self._sensors)
    sensors.enabled = True
    return {'sensors': sensors}

  def before_step(self, physics, action, key):
    del key
    if self._set_control:
      return physics.set_control(action)
    return physics.bind(self._actuators).set(ctrl=action)

  def get_reward(self, physics):
    return physics.bind(self._sensors[0]).sensordata[2]


def _dm_control_env(set_control=False):
  """dm_control's composer environment of the same walker and task."""
  from dm_control import composer as dm_composer  # pylint: disable=g-import-not-at-top
  from dm_control import mjcf  # pylint: disable=g-import-not-at-top
  from dm_control.composer.observation import observable as dm_observable  # pylint: disable=g-import-not-at-top

  class Walker(dm_composer.Entity):

    def _build(self):
      self._model = mjcf.from_xml_string(_WALKER)

    @property
    def mjcf_model(self):
      return self._model

  class Walk(dm_composer.Task):

    def __init__(self):
      self._walker = Walker()
      model = self._walker.mjcf_model
      self._actuators = [model.find('actuator', n) for n in _ACTUATORS]
      self._sensors = [model.find('sensor', n) for n in _SENSORS]
      self._observable = dm_observable.MJCFFeature('sensordata', self._sensors)
      self._observable.enabled = True
      self.set_timesteps(
          control_timestep=_CONTROL_TIMESTEP,
          physics_timestep=_PHYSICS_TIMESTEP,
      )

    @property
    def root_entity(self):
      return self._walker

    @property
    def task_observables(self):
      return {'sensors': self._observable}

    def before_step(self, physics, action, random_state):
      del random_state
      if set_control:
        physics.set_control(action)
      else:
        physics.bind(self._actuators).ctrl = action  # A walker's apply_action.

    def get_reward(self, physics):
      return 0.0

  return dm_composer.Environment(Walk(), random_state=0)


def _episode(env):
  """`_N_STEPS` control steps of one world: the states and actions."""
  reset, step = jax.jit(env.reset), jax.jit(env.step)
  state = reset(jax.random.key(0))
  states, actions = [state], []
  for i in range(_N_STEPS):
    action = _action(i)
    state = step(state, jnp.asarray(action))
    states.append(state)
    actions.append(action)
  return states, actions


def _composers(dm_env, states, actions):
  """dm_control composer's observed sensors after each control step, each
  step started from ours' state before it."""
  dm_env.reset()
  physics = dm_env.physics
  observed = []
  for before, action in zip(states, actions):
    with physics.reset_context():
      for field in ('qpos', 'qvel', 'act', 'qacc_warmstart'):
        getattr(physics.data, field)[:] = np.asarray(
            getattr(before.data, field)
        )
      physics.data.time = float(before.data.time)
    timestep = dm_env.step(action)
    observed.append(np.array(timestep.observation['sensors']).reshape(-1))
  return np.stack(observed)


@pytest.fixture(scope='module')
def binding_walk():
  """Ours and dm_control's sensors after each step of the binding-writing
  walker, and ours with `dirty_forward='never'` from the same states."""
  env = composer.Environment(_BindingWalk())
  states, actions = _episode(env)
  ours = np.stack(
      [np.asarray(s.observation['sensors']).reshape(-1) for s in states[1:]]
  )
  never = composer.Environment(
      _BindingWalk(),
      options=composer.ExecutionOptions(dirty_forward='never'),
  )
  step = jax.jit(never.step)
  raw = np.stack(
      [
          np.asarray(step(s, jnp.asarray(a)).observation['sensors']).reshape(-1)
          for s, a in zip(states, actions)
      ]
  )
  return env, ours, raw, _composers(_dm_control_env(), states, actions)


def _assert_sensors_match(ours, expected):
  for name, rows in _ROWS.items():
    scale = max(1.0, float(np.max(np.abs(expected[:, rows]))))
    np.testing.assert_allclose(
        ours[:, rows], expected[:, rows], rtol=0, atol=5e-3 * scale,
        err_msg=name,
    )  # fmt: skip
  touch = _ROWS['touch']
  np.testing.assert_array_equal(ours[:, touch] > 0, expected[:, touch] > 0)


def test_a_binding_write_of_ctrl_ends_the_step_with_a_forward_pass(
    binding_walk,
):
  env = binding_walk[0]
  assert env.step_forward_stage == 'full'


def test_sensors_after_a_step_are_composers(binding_walk):
  _, ours, _, expected = binding_walk
  touch = expected[:, _ROWS['touch']]
  assert np.any(touch > 0), 'the scripted episode never touches the floor'
  _assert_sensors_match(ours, expected)


def test_the_step_starts_values_differ_from_composers(binding_walk):
  """`dirty_forward='never'` keeps the values of the state the last
  sub-step started from: far from composer's after a binding write, so the
  comparison above tells the two timings apart."""
  _, _, raw, expected = binding_walk
  rows = _ROWS['accel']
  scale = float(np.max(np.abs(expected[:, rows])))
  assert np.max(np.abs(raw[:, rows] - expected[:, rows])) > 0.05 * scale


def test_set_control_keeps_the_step_starts_values_and_composers():
  """Through `set_control` composer's physics is never dirty: the
  acceleration stage after a step is that of the state the last sub-step
  started from, ours as composer's, and the step program is the one
  `dirty_forward='never'` compiles."""
  env = composer.Environment(_BindingWalk(set_control=True))
  assert env.step_forward_stage != 'full'
  states, actions = _episode(env)
  ours = np.stack(
      [np.asarray(s.observation['sensors']).reshape(-1) for s in states[1:]]
  )
  expected = _composers(_dm_control_env(set_control=True), states, actions)
  assert np.any(expected[:, _ROWS['touch']] > 0)
  _assert_sensors_match(ours, expected)

  never = composer.Environment(
      _BindingWalk(set_control=True),
      options=composer.ExecutionOptions(dirty_forward='never'),
  )
  action = jnp.zeros(len(_ACTUATORS), jnp.float32)
  assert (
      jax.jit(env.step).lower(states[0], action).as_text()
      == jax.jit(never.step).lower(states[0], action).as_text()
  )
