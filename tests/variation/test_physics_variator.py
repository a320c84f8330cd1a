"""PhysicsVariator: compiled model fields varied per world (composer names)."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer import variation
from mjx_composer.variation import deterministic
from mjx_composer.variation import distributions
from mjx_composer.variation import noises
from tests import conftest

_J = mujoco.mjtJoint
_G = mujoco.mjtGeom


class Arm(conftest.SpecEntity, composer.Robot):

  def _build(self):
    spec = self._new_spec('arm')
    self.body = spec.worldbody.add_body(name='link', pos=[0, 0, 0.5])
    self.joint = self.body.add_joint(
        name='hinge', type=_J.mjJNT_HINGE, axis=[0, 1, 0], damping=0.5
    )
    self.geom = self.body.add_geom(
        name='link', type=_G.mjGEOM_BOX, size=[0.1, 0.02, 0.02], pos=[0.1, 0, 0]
    )
    self.motor = spec.add_actuator(
        name='motor',
        target='hinge',
        trntype=mujoco.mjtTrn.mjTRN_JOINT,
        gear=[3, 0, 0, 0, 0, 0],
    )

  @property
  def actuators(self):
    return (self.motor,)


class _Task(composer.Task):

  def __init__(self, fluid=True):
    self.arena = composer.Arena()
    if fluid:
      self.arena.mjcf_model.option.density = 1.2
    self.arm = Arm()
    self.arena.attach(self.arm)
    self.variator = None

  @property
  def root_entity(self):
    return self.arena

  def initialize_episode(self, physics, key):
    if self.variator is None:
      return physics
    return self.variator.apply_variations(physics, key)

  def get_reward(self, physics):
    return 0.0


@pytest.fixture(scope='module')
def env():
  return composer.Environment(_Task())


def _physics(env):
  """A fresh world's Physics (no reset needed to test the variator)."""
  return env.initial_physics()


KEY = jax.random.key(0)


def test_composer_binding_names_map_to_model_fields(env):
  arm = env.task.arm
  option = env.task.arena.mjcf_model.option
  variator = variation.PhysicsVariator()
  variator.bind_attributes(
      arm.geom, friction=[0.5, 0.01, 0.001], geom_rgba=[1, 0, 0, 1]
  )
  variator.bind_attributes(arm.joint, damping=2.0, dof_armature=0.1)
  variator.bind_attributes(arm.body, mass=3.0)
  variator.bind_attributes(arm.motor, gear=[5, 0, 0, 0, 0, 0])
  variator.bind_attributes(option, gravity=[0, 0, -1], density=2.0)
  physics = jax.jit(variator.apply_variations)(_physics(env), KEY)
  m = env.mj_model
  g, j, b = (
      m.geom('arm/link').id,
      m.joint('arm/hinge').dofadr[0],
      m.body('arm/link').id,
  )
  np.testing.assert_allclose(physics.model.geom_friction[g], [0.5, 0.01, 0.001])
  np.testing.assert_allclose(physics.model.geom_rgba[g], [1, 0, 0, 1])
  assert physics.model.dof_damping[j] == 2.0
  np.testing.assert_allclose(physics.model.dof_armature[j], 0.1, rtol=1e-6)
  assert physics.model.body_mass[b] == 3.0
  assert physics.model.actuator_gear[0, 0] == 5.0
  np.testing.assert_allclose(physics.model.opt.gravity, [0, 0, -1])
  assert physics.model.opt.density == 2.0
  # Like composer: no derived quantity is recomputed.
  np.testing.assert_array_equal(
      physics.model.body_subtreemass, env.mjx_model.body_subtreemass
  )
  np.testing.assert_array_equal(
      physics.model.dof_invweight0, env.mjx_model.dof_invweight0
  )


def test_initial_value_is_compiled_current_value_is_the_worlds(env):
  """Non-cumulative noise acts on the compiled value every time;
  cumulative noise compounds on the world's current value."""
  arm = env.task.arm
  fixed = variation.PhysicsVariator()
  fixed.bind_attributes(
      arm.joint,
      damping=noises.Multiplicative(deterministic.Sequence([2.0, 3.0])),
  )
  growing = variation.PhysicsVariator()
  growing.bind_attributes(
      arm.body,
      mass=noises.Multiplicative(
          deterministic.Sequence([2.0, 3.0]), cumulative=True
      ),
  )

  @jax.jit
  def two_episodes(physics):
    out = []
    for i in range(2):
      physics = fixed.apply_variations(physics, jax.random.fold_in(KEY, i))
      physics = growing.apply_variations(physics, jax.random.fold_in(KEY, i))
      out.append(physics.model)
    return out

  first, second = two_episodes(_physics(env))
  m = env.mj_model
  dof, body = m.joint('arm/hinge').dofadr[0], m.body('arm/link').id
  damping0, mass0 = m.dof_damping[dof], m.body_mass[body]
  np.testing.assert_allclose(first.dof_damping[dof], 2 * damping0, rtol=1e-6)
  np.testing.assert_allclose(second.dof_damping[dof], 3 * damping0, rtol=1e-6)
  np.testing.assert_allclose(first.body_mass[body], 2 * mass0, rtol=1e-6)
  np.testing.assert_allclose(second.body_mass[body], 6 * mass0, rtol=1e-6)


def test_once_per_world_and_every_steps_schedules(env):
  arm = env.task.arm
  once = variation.PhysicsVariator(schedule=variation.Schedule.once_per_world())
  once.bind_attributes(arm.geom, friction=distributions.Uniform(0.5, 1.5))
  every = variation.PhysicsVariator(schedule=variation.Schedule.every_steps(2))
  every.bind_attributes(
      arm.joint, damping=noises.Additive(1.0, cumulative=True)
  )

  @jax.jit
  def run(physics):
    frictions, dampings = [], []
    for episode in range(2):
      key = jax.random.fold_in(KEY, episode)
      physics = once.apply_variations(physics, key)
      physics = every.apply_variations(physics, key)
      for step in range(5):
        physics = every.apply_variations(
            physics, jax.random.fold_in(key, step), in_step=True
        )
        dampings.append(physics.model.dof_damping[0])
      frictions.append(physics.model.geom_friction)
    return jnp.stack(frictions), jnp.stack(dampings)

  frictions, dampings = run(_physics(env))
  np.testing.assert_array_equal(frictions[0], frictions[1])
  assert not np.allclose(frictions[0], env.mj_model.geom_friction)
  # 0.5 compiled; +1 at each reset and before control steps 3 and 5.
  np.testing.assert_allclose(
      dampings, [1.5, 1.5, 2.5, 2.5, 3.5, 4.5, 4.5, 5.5, 5.5, 6.5]
  )


def test_environment_carries_only_the_varied_fields(env):
  arm = env.task.arm
  env.task.variator = variator = variation.PhysicsVariator()
  variator.bind_attributes(
      arm.geom,
      friction=distributions.Uniform([0.5, 0.001, 1e-4], [1.5, 0.01, 1e-3]),
  )
  variator.bind_attributes(
      env.task.arena.mjcf_model.option,
      wind=distributions.Normal([0, 0, 0], 1.0),
  )
  try:
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(KEY, 3))
  finally:
    env.task.variator = None
  assert set(states.model_fields) == {'geom_friction', 'opt'}
  wind = np.asarray(states.model_fields['opt'].wind)
  assert wind.shape == (3, 3) and len(np.unique(wind[:, 0])) == 3
  assert variator.persistent_name in states.persistent


def test_bind_errors_list_valid_attributes():
  arm = Arm()
  variator = variation.PhysicsVariator()
  with pytest.raises(
      ValueError, match=r"no compiled model attribute 'qpos'" r".*'damping'"
  ):
    variator.bind_attributes(arm.joint, qpos=0.1)
  with pytest.raises(ValueError, match="'contype'.*'friction'"):
    variator.bind_attributes(arm.geom, contype=0)
  with pytest.raises(ValueError, match='option attribute'):
    variator.bind_attributes(composer.Arena().mjcf_model.option, timestep=0.1)
  with pytest.raises(TypeError, match='expected an MjSpec element'):
    variator.bind_attributes('arm/link', friction=1.0)


def test_trace_time_errors():
  task = _Task(fluid=False)
  environment = composer.Environment(task)
  physics = _physics(environment)

  def trace(variator):
    return jax.eval_shape(variator.apply_variations, physics, KEY)

  stray = Arm()
  variator = variation.PhysicsVariator()
  variator.bind_attributes(stray.geom, friction=1.0)
  with pytest.raises(
      ValueError,
      match=r"MjsGeom\('link'\).*not part of the "
      'compiled model.*attach its entity',
  ):
    trace(variator)

  variator = variation.PhysicsVariator()
  variator.bind_attributes(task.arm.geom, friction=jnp.ones(2))
  with pytest.raises(
      ValueError,
      match=r'friction gives values of shape '
      r'\(2,\), but the attribute has shape \(3,\)',
  ):
    trace(variator)

  variator = variation.PhysicsVariator()
  variator.bind_attributes(task.arena.mjcf_model.option, density=1.0)
  with pytest.raises(ValueError, match='no fluid forces'):
    trace(variator)


def test_persistent_names_do_not_depend_on_construction_order(env):
  arm = env.task.arm
  physics = env.initial_physics()

  def named(order):
    variators = {}
    for which in order:
      variator = variation.PhysicsVariator()
      if which == 'friction':
        variator.bind_attributes(arm.geom, friction=distributions.Uniform())
      else:
        variator.bind_attributes(arm.joint, damping=distributions.Uniform())
      jax.eval_shape(variator.apply_variations, physics, KEY)
      variators[which] = variator.persistent_name
    return variators

  assert named(['friction', 'damping']) == named(['damping', 'friction'])
  names = named(['friction', 'damping'])
  assert names['friction'] != names['damping']
  assert 'arm/link' in names['friction'] and 'arm/hinge' in names['damping']
  # An explicit name wins; an unapplied variator says how to get one.
  assert variation.PhysicsVariator(name='mine').persistent_name == 'mine'
  with pytest.raises(ValueError, match='not been applied yet'):
    _ = variation.PhysicsVariator().persistent_name
