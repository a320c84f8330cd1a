"""The end-of-step stage carried between physics steps
(`runtime.carried_stage`), against `mjx.step` and the recomputed stage."""

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.runtime import carried_stage
from mjx_composer.runtime import data_reads
from mjx_composer.runtime import reset_forward
from tests import conftest
from tests.runtime import test_reset_forward
from tests.runtime import test_substep_sensors
from tests.runtime import test_transitions


@pytest.fixture(scope='module')
def moving():
  """A model with contacts, a ball joint and sensors, its data moving."""
  m = mujoco.MjModel.from_xml_string(test_substep_sensors._XML)
  d = test_reset_forward._moving_state(m)
  free = m.jnt_qposadr[m.body('free').jntadr[0]]
  d.qpos[free + 2] = 0.09  # the ball touches the floor
  return mjx.put_model(m), mjx.put_data(m, d)


@pytest.mark.parametrize('stage', carried_stage.STAGES)
def test_a_physics_step_from_the_carried_stage_is_mjx_step(moving, stage):
  model, data = moving
  data = jax.jit(lambda d: carried_stage.stage(model, d, stage))(data)
  assert np.asarray(data._impl.efc_J).shape[0]  # contacts: constraint rows
  want = jax.jit(lambda d: mjx.step(model, d))(data)
  got = jax.jit(lambda d: carried_stage.physics_step(model, d, stage))(data)
  for name, a, b in zip(
      data_reads.leaf_names(data), jax.tree.leaves(got), jax.tree.leaves(want)
  ):
    np.testing.assert_array_equal(a, b, err_msg=name)


@pytest.mark.parametrize('stage', carried_stage.STAGES)
def test_what_a_stage_reads_and_writes_is_traced_once_per_model_structure(
    moving, stage, monkeypatch
):
  model, data = moving
  monkeypatch.setattr(carried_stage, '_STAGE_IO', data_reads.PerStructure())
  traced = []
  trace = carried_stage.stage
  monkeypatch.setattr(
      carried_stage,
      'stage',
      lambda *args: traced.append(args[2]) or trace(*args),
  )
  reads, writes = carried_stage._stage_io(model, data, stage)
  # The writes are those `reset_forward.written` finds for the stage a
  # control step runs after its physics, sensors skipped.
  assert writes == reset_forward.written(
      stage, model, data, False, after_step=True
  )
  assert 'qpos' in reads and 'xpos' in writes
  assert ('qvel' in reads) == ('cvel' in writes) == (stage == 'velocity')
  # Abstract data of the same shapes, another put of the same model: the
  # same answers, without a second trace.
  again = carried_stage._stage_io(
      jax.tree.map(jnp.asarray, model), jax.eval_shape(lambda: data), stage
  )
  assert again == (reads, writes)
  assert traced == [stage]


class _Disturbing(test_substep_sensors._SensingTask):
  """The sensing swing task observing its gyro, with a step hook that
  `disturbs` the carried stage: None; 'qpos' (`before_step` writes a joint
  position); 'qvel' (`before_step` writes a joint velocity); 'mass' (a step
  hook writes a model field); 'read' (`before_substep` reads a pose)."""

  def __init__(self, disturbs=None):
    super().__init__(observed='velocity')
    self.disturbs = disturbs

  def before_step(self, physics, action, key):
    physics = super().before_step(physics, action, key)
    data = physics.data
    if self.disturbs == 'qpos':
      return physics.replace(data=data.replace(qpos=data.qpos.at[0].add(1e-3)))
    if self.disturbs == 'qvel':
      return physics.replace(data=data.replace(qvel=0.99 * data.qvel))
    if self.disturbs == 'mass':
      mass = physics.model.body_mass.at[-1].multiply(1.01)
      return physics.replace(model=physics.model.replace(body_mass=mass))
    return physics

  def before_substep(self, physics, action, key):
    physics = super().before_substep(physics, action, key)
    if self.disturbs != 'read':
      return physics
    height = physics.bind(self.pendulum.tip).xpos[2]
    applied = physics.data.qfrc_applied.at[0].set(1e-3 * height)
    return physics.replace(data=physics.data.replace(qfrc_applied=applied))


def _env(disturbs=None, carry_stage='auto', share_reset_forward=False):
  return composer.Environment(
      _Disturbing(disturbs),
      time_limit=0.1,
      options=composer.ExecutionOptions(
          share_reset_forward=share_reset_forward, carry_stage=carry_stage
      ),
  )


@pytest.mark.parametrize(
    'disturbs, carried',
    [
        (None, 'velocity'),
        ('qvel', 'position'),  # a write of qvel leaves the positions' stage
        ('qpos', None),
        ('mass', None),
        ('read', None),  # it would read the stage of the new state
    ],
)
def test_the_stage_is_carried_where_nothing_disturbs_it(disturbs, carried):
  env = _env(disturbs)
  assert env.step_forward_stage == 'velocity'
  assert env.carried_stage == carried
  assert _env(disturbs, carry_stage='never').carried_stage is None


@pytest.mark.parametrize('disturbs', [None, 'qvel'])
def test_carried_stages_make_the_same_episodes(disturbs):
  carried, recomputed = _env(disturbs), _env(disturbs, carry_stage='never')
  assert carried.carried_stage is not None
  # 12 steps of 10-step episodes: each world restarts once (same step).
  a_states = test_reset_forward.rollout(carried, 12)
  b_states = test_reset_forward.rollout(recomputed, 12)
  assert np.asarray(a_states[10].last()).all()
  test_substep_sensors.assert_close_episodes(a_states, b_states)
  # The gyro, read after the step, moves: the test sees the stage's values.
  gyro = [np.asarray(s.observation['gyro']) for s in a_states[1:10]]
  assert np.abs(gyro[-1] - gyro[0]).max() > 0.1


# The restart runs separately, or in the sub-step loop, whose reset then
# uses the sub-steps' copy of the stage.
@pytest.mark.parametrize('share_reset_forward', [False, True])
def test_the_step_program_holds_one_copy_of_the_stage(share_reset_forward):
  carried = _env(share_reset_forward=share_reset_forward)
  recomputed = _env(
      carry_stage='never', share_reset_forward=share_reset_forward
  )
  states = jax.eval_shape(
      jax.vmap(carried.reset), jax.random.split(jax.random.key(0), 2)
  )
  actions = jnp.zeros((2, 1))
  size = lambda f, *args: test_transitions._flat_eqn_count(
      jax.make_jaxpr(f)(*args).jaxpr
  )
  physics = carried.initial_physics()
  stage = size(
      lambda d: carried_stage.stage(physics.model, d, 'velocity'), physics.data
  )
  saved = size(jax.vmap(recomputed.step), states, actions) - size(
      jax.vmap(carried.step), states, actions
  )
  assert saved > 0.8 * stage


class _ObservesTime(conftest.SwingTask):
  """The swing task observing only the time: its reset reads no pose."""

  @property
  def task_observables(self):
    time = composer.observation.observable.Generic(
        lambda physics: physics.data.time[None]
    )
    time.enabled = True
    return {'time': time}


def test_a_reset_computes_the_stage_its_state_carries():
  def env(carry_stage):
    return composer.Environment(
        _ObservesTime(),
        time_limit=0.1,
        options=composer.ExecutionOptions(
            share_reset_forward=False, carry_stage=carry_stage
        ),
    )

  recomputed, carried = env('never'), env('auto')
  assert recomputed.reset_forward_stage == 'none'
  # The reward reads the tip's height after every step.
  assert carried.step_forward_stage == 'position'
  assert carried.carried_stage == 'position'
  assert carried.reset_forward_stage == 'position'
  state = jax.jit(carried.reset)(jax.random.key(0))
  want = jax.jit(lambda d: mjx.kinematics(carried.mjx_model, d))(state.data)
  np.testing.assert_allclose(state.data.xpos, want.xpos, atol=1e-6)


def test_a_state_edited_by_hand_steps_from_its_forwarded_data():
  carried, recomputed = _env(), _env(carry_stage='never')
  state = jax.jit(carried.reset)(jax.random.key(0))
  edited = state.replace(data=state.data.replace(qpos=state.data.qpos + 0.5))
  forwarded = edited.replace(
      data=jax.jit(lambda s: carried.physics(s).forward().data)(edited)
  )
  action = jnp.full((1,), 0.3)
  want = jax.jit(recomputed.step)(edited, action)
  got = jax.jit(carried.step)(forwarded, action)
  for name in ('qpos', 'qvel'):
    np.testing.assert_allclose(
        getattr(got.data, name), getattr(want.data, name), rtol=1e-5, atol=1e-5
    )
  np.testing.assert_allclose(
      got.observation['gyro'], want.observation['gyro'], rtol=1e-5, atol=1e-5
  )
  # Unforwarded, its physics starts from the stage of the state it was
  # edited from.
  stale = jax.jit(carried.step)(edited, action)
  assert np.abs(stale.data.qvel - want.data.qvel).max() > 1e-3
