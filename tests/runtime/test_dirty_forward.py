"""Tests for `dirty_forward`: when a control step ends with composer's
forward pass of a dirty physics.

`replay` and `forwarding_read` follow dm_control's dirty flag over recorded
events; the environments below (a hinged arm with a motor, an
accelerometer and a position sensor) vary one thing each from a task that
writes `ctrl` through a binding in `before_step` and observes the
accelerometer through a binding, and `Environment.step_forward_stage`
says whether the step ends with the full forward pass.
"""

import jax
import jax.numpy as jnp
import pytest

import mjx_composer as composer
from mjx_composer.observation import observable
from mjx_composer.physics import bindings
from mjx_composer.runtime import dirty_forward
from mjx_composer.runtime import reset_forward

_W, _R, _F = bindings.DIRTYING_WRITE, bindings.FORWARDING_READ, bindings.FORWARD

_ARM = """
<mujoco model="arm">
  <option timestep="0.01"/>
  <worldbody>
    <body name="link" pos="0 0 1">
      <joint name="hinge" type="hinge" axis="0 1 0"/>
      <geom name="link" type="capsule" size="0.03" fromto="0 0 0 0.3 0 0"/>
      <site name="tip" pos="0.3 0 0" size="0.01"/>
    </body>
  </worldbody>
  <actuator>
    <motor name="motor" joint="hinge" gear="2"/>
  </actuator>
  <sensor>
    <accelerometer name="accel" site="tip"/>
    <framepos name="tip_pos" objtype="site" objname="tip"/>
  </sensor>
</mujoco>
"""


def test_replay_follows_dm_controls_dirty_flag():
  assert not dirty_forward.replay([])
  assert dirty_forward.replay([(_W, 'ctrl')])
  assert not dirty_forward.replay([(_W, 'ctrl'), (_R, 'xpos')])
  assert not dirty_forward.replay([(_W, 'ctrl'), (_F, '')])
  assert dirty_forward.replay([(_R, 'xpos'), (_W, 'qvel')])
  assert dirty_forward.replay([(_R, 'xpos')], dirty=False) is False
  assert dirty_forward.replay([], dirty=True)


def test_forwarding_read_is_a_binding_read_before_any_forward_pass():
  assert dirty_forward.forwarding_read([(_W, 'ctrl'), (_R, 'sensordata')])
  assert not dirty_forward.forwarding_read([(_F, ''), (_R, 'sensordata')])
  assert not dirty_forward.forwarding_read([(_W, 'ctrl')])


def test_bindings_record_what_marks_and_what_forwards():
  """Writes of the forward pass's inputs mark, reads of anything else
  forward; `named`, `set_control` and visual fields record nothing."""
  env = composer.Environment(_ArmTask())
  task = env.task
  recorded = []

  def accesses(key):
    physics = env.physics(env.reset(key))
    with bindings.recording_dirty_events() as events:
      physics.bind(task.motor).set(ctrl=1.0)
      physics.bind(task.hinge).qpos  # pylint: disable=pointless-statement
      physics.bind(task.tip).xpos  # pylint: disable=pointless-statement
      physics.bind(task.link).set(rgba=jnp.ones(4))
      physics.bind(task.link).set(friction=jnp.ones(3))
      physics.named.data.set('ctrl', 'motor', 1.0)
      physics.named.data.sensordata['accel']  # pylint: disable=pointless-statement
      physics.set_control(jnp.ones(1))
      physics.forward()
    recorded.extend(events)
    return physics.data.qpos

  jax.eval_shape(accesses, jax.random.key(0))
  events = recorded
  assert events == [
      (_W, 'ctrl'),
      (_R, 'site_xpos'),
      (_W, 'geom_friction'),
      (_F, ''),
  ]


class _ArmTask(composer.Task):
  """The arm, its accelerometer observed through a binding, its action
  written as `write` says: 'binding' (`ctrl` through a binding in
  `before_step`), 'set_control' or 'named'. `substep` is an optional
  `before_substep(task, physics)`, `after_substep` likewise; `observe`
  'binding', 'raw' (`physics.data.sensordata` in a `Generic` observable,
  no binding read after the step) or 'position' (the position sensor
  only)."""

  def __init__(
      self,
      write='binding',
      substep=None,
      after_substep=None,
      observe='binding',
      physics_timestep=0.01,
  ):
    self._arm = composer.ModelWrapperEntity(_ARM)
    spec = self._arm.mjcf_model
    self.motor = spec.actuator('motor')
    self.hinge = spec.joint('hinge')
    self.tip = spec.site('tip')
    self.link = spec.geom('link')
    self.accel = spec.sensor('accel')
    self.tip_pos = spec.sensor('tip_pos')
    self._write = write
    self._substep = substep
    self._after_substep = after_substep
    self._observe = observe
    self.set_timesteps(control_timestep=0.02, physics_timestep=physics_timestep)

  @property
  def root_entity(self):
    return self._arm

  @property
  def task_observables(self):
    if self._observe == 'binding':
      found = observable.MJCFFeature('sensordata', self.accel)
    elif self._observe == 'raw':
      found = observable.Generic(lambda physics: physics.data.sensordata[:3])
    else:
      found = observable.MJCFFeature('sensordata', self.tip_pos)
    found.enabled = True
    return {'sensor': found}

  def before_step(self, physics, action, key):
    del key
    if self._write == 'set_control':
      return physics.set_control(action)
    if self._write == 'named':
      return physics.named.data.set('ctrl', 'motor', action[0])
    return physics.bind(self.motor).set(ctrl=action[0])

  def before_substep(self, physics, action, key):
    del action, key
    if self._substep is None:
      return physics
    return self._substep(self, physics)

  def after_substep(self, physics, key):
    del key
    if self._after_substep is None:
      return physics
    return self._after_substep(self, physics)

  def get_reward(self, physics):
    del physics
    return 0.0


def _stage(**kwargs):
  options = kwargs.pop('options', None)
  return composer.Environment(
      _ArmTask(**kwargs), options=options
  ).step_forward_stage


def test_a_binding_write_of_ctrl_read_through_a_binding_forwards():
  assert _stage() == 'full'


def test_dirty_forward_never_keeps_the_steps_values():
  never = composer.ExecutionOptions(dirty_forward='never')
  assert _stage(options=never) != 'full'


@pytest.mark.parametrize('write', ['set_control', 'named'])
def test_writes_that_mark_nothing_in_dm_control_do_not_forward(write):
  assert _stage(write=write) != 'full'


def _read_tip(task, physics):
  """Reads the tip's position through a binding (composer's forward pass
  runs here where the physics is dirty)."""
  tip = physics.bind(task.tip).xpos
  del tip
  return physics


def _push(task, physics):
  """Writes `qfrc_applied` through a binding (marks the physics dirty)."""
  return physics.bind(task.hinge).set(qfrc_applied=0.1)


def test_a_binding_read_before_the_physics_clears_the_mark():
  """Composer's read of the tip's position in `before_substep` runs the
  forward pass before the physics: the step leaves a clean physics."""
  assert _stage(substep=_read_tip) != 'full'


def test_a_forward_pass_before_the_physics_clears_the_mark():
  assert _stage(substep=lambda task, physics: physics.forward()) != 'full'


@pytest.mark.parametrize('physics_timestep', [0.01, 0.02])
def test_a_write_in_after_substep_marks_the_physics(physics_timestep):
  """`after_substep` (of two sub-steps, or of the one) writes through a
  binding after the physics, and nothing reads before the step's end."""
  assert (
      _stage(
          write='set_control',
          after_substep=_push,
          physics_timestep=physics_timestep,
      )
      == 'full'
  )


def test_a_read_after_the_write_in_after_substep_clears_the_mark():
  assert (
      _stage(
          write='set_control',
          after_substep=lambda task, physics: _read_tip(
              task, _push(task, physics)
          ),
      )
      != 'full'
  )


def test_no_forwarding_read_after_the_step_keeps_the_steps_values():
  assert _stage(observe='raw') != 'full'


def test_no_acceleration_stage_reader_keeps_the_steps_values():
  assert _stage(observe='position') == 'position'


def test_dirty_forward_must_be_composer_or_never():
  with pytest.raises(ValueError, match="dirty_forward must be 'composer'"):
    composer.ExecutionOptions(dirty_forward='always')


def test_the_forward_pass_after_the_step_leaves_the_trajectory_alone():
  """It writes derived quantities only: not the velocities, activations,
  time, controls or the solver's warm start that the next step reads.
  `qpos` it writes back with its quaternions normalized, as the next
  step's own forward pass does first."""
  env = composer.Environment(_ArmTask())
  state = jax.eval_shape(env.reset, jax.random.key(0))
  written = reset_forward.written(
      'full', env.mjx_model, state.data, after_step=True
  )
  assert {'sensordata', 'qacc', 'actuator_force'} <= written
  assert not written & {'qvel', 'act', 'time', 'qacc_warmstart', 'ctrl'}
