"""MJCFVariator in an Environment: bind, apply, schedules, state, errors.

Field-by-field compile-equivalence of every attribute is tested in
test_compiler.py; here the variator's plumbing is tested on one small
environment (compiled once), plus a recompile check of what the environment
carries per world.
"""

import functools

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer import variation
from mjx_composer.compiler import attributes
from mjx_composer.variation import deterministic
from mjx_composer.variation import distributions
from mjx_composer.variation import noises
from mjx_composer.variation import variator_base
from tests import conftest

_J = mujoco.mjtJoint
_G = mujoco.mjtGeom
_COLORS = [[1, 0, 0, 1], [0, 1, 0, 1], [0, 0, 1, 1]]
_K = 2  # the every-k schedule's interval


def _hinge():
  """A damped, limited hinge with friction loss, a motor limited by
  autolimits (its ctrlrange) and a second, unlimited hinge (`unlimited`);
  no tip site."""
  return conftest.Pendulum(
      name='hinge',
      damping=0.5,
      tip=False,
      ctrllimited=mujoco.mjtLimited.mjLIMITED_AUTO,
      free_spin=True,
      range=[-90, 90],
      frictionloss=0.01,
  )


def _ball(name='ball'):
  return conftest.Ball(name=name, density=400)


class VariedTask(composer.Task):
  """Four MJCF variators, one per schedule, on a hinge and a free ball."""

  def __init__(self):
    # No floor and one sub-step per control step: contacts and extra
    # sub-steps would only add compile time to these tests. (Pyramidal
    # cones: MJX 3.17's elliptic-cone solver fails to trace a model with
    # no contacts.)
    self.arena = composer.Arena()
    self.arena.mjcf_model.option.cone = mujoco.mjtCone.mjCONE_PYRAMIDAL
    self.hinge = _hinge()
    self.arena.attach(self.hinge)
    self.ball = _ball()
    self.arena.add_free_entity(self.ball)
    self.set_timesteps(control_timestep=0.01, physics_timestep=0.01)
    # Per episode: a stateful Sequence of colours and a derived size.
    self.per_episode = variation.MJCFVariator()
    self.per_episode.bind_attributes(
        self.ball.geom,
        rgba=deterministic.Sequence(_COLORS),
        size=distributions.Uniform([0.03, 0, 0], [0.08, 0, 0]),
    )
    # Once per world: friction.
    self.once = variation.MJCFVariator(
        schedule=variation.Schedule.once_per_world()
    )
    self.once.bind_attributes(
        self.ball.geom,
        friction=distributions.Uniform([0.5, 0.001, 1e-4], [1.5, 0.01, 1e-3]),
    )
    # Every k steps: cumulative damping, doubled at each draw.
    self.every = variation.MJCFVariator(
        schedule=variation.Schedule.every_steps(_K)
    )
    self.every.bind_attributes(
        self.hinge.joint, damping=noises.Multiplicative(2.0, cumulative=True)
    )

  @property
  def root_entity(self):
    return self.arena

  def initialize_episode(self, physics, key):
    keys = jax.random.split(key, 3)
    physics = self.per_episode.apply_variations(physics, keys[0])
    physics = self.once.apply_variations(physics, keys[1])
    return self.every.apply_variations(physics, keys[2])

  def get_reward(self, physics):
    return 0.0


_N_WORLDS = 2
_STEPS = 8
_EPISODE_STEPS = 3


@pytest.fixture(scope='module')
def rollout():
  """Two worlds, 3-step episodes with same-step auto-reset, 8 steps."""
  task = VariedTask()
  env = composer.Environment(
      task,
      time_limit=_EPISODE_STEPS * 0.01,
      options=composer.ExecutionOptions(auto_reset='same_step'),
  )
  keys = jax.random.split(jax.random.key(0), _N_WORLDS)

  @jax.jit
  def run(keys):
    states = jax.vmap(env.reset)(keys)
    actions = jnp.zeros((_N_WORLDS, 1))

    def body(states, _):
      states = jax.vmap(env.step)(states, actions)
      return states, states

    _, trajectory = jax.lax.scan(body, states, None, length=_STEPS)
    return states, trajectory

  first, trajectory = run(keys)
  return dict(task=task, env=env, first=first, trajectory=trajectory)


def _field(state, name, index):
  return np.asarray(state.model_fields[name])[..., index, :]


def _check_only_varied_fields_are_per_world(rollout):
  fields = set(rollout['first'].model_fields)
  # rgba, friction, damping, and what a sphere's size derives.
  assert {
      'geom_rgba',
      'geom_friction',
      'dof_damping',
      'geom_size',
      'geom_rbound',
      'geom_aabb',
      'body_mass',
      'body_inertia',
      'body_subtreemass',
      'dof_invweight0',
  } <= fields
  assert not fields & {
      'geom_pos',
      'geom_solref',
      'jnt_range',
      'body_pos',
      'actuator_gear',
      'opt',
      'cam_pos0',
  }


def _check_per_episode_sequence_advances_at_every_auto_reset(rollout):
  env, first = rollout['env'], rollout['first']
  trajectory = rollout['trajectory']
  geom = env.mj_model.geom('ball/geom').id
  # Episode e of every world shows colour e (mod 3): the Sequence state
  # lives in the world's persistent entry, so auto-resets advance it.
  np.testing.assert_array_equal(
      _field(first, 'geom_rgba', geom), [_COLORS[0]] * _N_WORLDS
  )
  episodes = (np.arange(1, _STEPS + 1)) // _EPISODE_STEPS
  rgba = _field(trajectory, 'geom_rgba', geom)  # (T, worlds, 4)
  for t, episode in enumerate(episodes):
    np.testing.assert_array_equal(rgba[t], [_COLORS[episode % 3]] * _N_WORLDS)
  # Sizes are fresh each episode and stay within the distribution.
  size = _field(trajectory, 'geom_size', geom)[:, :, 0]
  assert np.all((size >= 0.03) & (size <= 0.08))
  assert len(np.unique(np.round(size[:, 0], 6))) == episodes.max() + 1


def _check_derived_fields_follow_the_size_and_match_a_recompile(rollout):
  env, task, first = rollout['env'], rollout['task'], rollout['first']
  geom = env.mj_model.geom('ball/geom').id
  body = env.mj_model.body('ball/body').id
  radius = _field(first, 'geom_size', geom)[:, 0]
  np.testing.assert_allclose(
      np.asarray(first.model_fields['geom_rbound'])[:, geom], radius, rtol=1e-6
  )
  mass = np.asarray(first.model_fields['body_mass'])[:, body]
  np.testing.assert_allclose(mass, 400 * 4 / 3 * np.pi * radius**3, rtol=1e-5)
  # World 0 against the spec recompiled with its sampled attribute values
  # (the fields they set). No draw of this variator reads the current
  # values, so its persistent entry keeps none; the cumulative and the
  # once-per-world variators' entries do.
  entry = first.persistent[task.per_episode.persistent_name]
  assert 'values' not in entry
  for kept in (task.every, task.once):
    assert 'values' in first.persistent[kept.persistent_name]
  rgba = _field(first, 'geom_rgba', geom)[0]
  size = _field(first, 'geom_size', geom)[0]
  geom_handle = task.ball.geom
  saved = (np.array(geom_handle.rgba), np.array(geom_handle.size))
  try:
    geom_handle.rgba, geom_handle.size = rgba, size.astype(np.float64)
    spec, _ = task.root_entity.compose()
    reference = mjx.put_model(spec.compile())
  finally:
    geom_handle.rgba, geom_handle.size = saved
  for name, value in first.model_fields.items():
    if name in ('geom_friction', 'dof_damping'):
      continue  # varied by the other variators
    for mine, theirs in zip(
        jax.tree.leaves(value), jax.tree.leaves(getattr(reference, name))
    ):
      np.testing.assert_allclose(
          np.asarray(mine)[0], theirs, rtol=1e-5, atol=1e-6, err_msg=name
      )


def _check_once_per_world_keeps_values_across_auto_resets(rollout):
  env, first = rollout['env'], rollout['first']
  trajectory = rollout['trajectory']
  geom = env.mj_model.geom('ball/geom').id
  friction0 = _field(first, 'geom_friction', geom)  # (worlds, 3)
  friction = _field(trajectory, 'geom_friction', geom)  # (T, worlds, 3)
  np.testing.assert_array_equal(
      friction, np.broadcast_to(friction0, friction.shape)
  )
  assert not np.allclose(friction0[0], friction0[1])  # per world
  assert not np.allclose(friction0[0], [1, 0.005, 1e-4])  # really drawn


def _check_every_k_steps_draws_and_reset_restarts_the_count(rollout):
  env, first = rollout['env'], rollout['first']
  trajectory = rollout['trajectory']
  dof = env.mj_model.joint('hinge/hinge').dofadr[0]
  damping = np.asarray(trajectory.model_fields['dof_damping'])[:, 0, dof]
  # The reset draw doubles the compiled 0.5 (cumulative on the world's
  # current value, which a fresh reset takes from the compiled model).
  assert np.asarray(first.model_fields['dof_damping'])[0, dof] == 1.0
  # Draws at the start of control steps k, 2k, ... of each episode, and at
  # each reset; cumulative values persist across auto-resets.
  expected, value, in_episode = [], 1.0, 0
  for t in range(_STEPS):
    if in_episode > 0 and in_episode % _K == 0:
      value *= 2
    in_episode += 1
    if in_episode == _EPISODE_STEPS:  # same-step auto-reset draws
      value *= 2
      in_episode = 0
    expected.append(value)
  np.testing.assert_allclose(damping, expected)
  counts = np.asarray(
      trajectory.persistent[rollout['task'].every.persistent_name]['count']
  )[:, 0]
  assert counts.tolist() == [
      0 if (t + 1) % _EPISODE_STEPS == 0 else (t + 1) % _EPISODE_STEPS
      for t in range(_STEPS)
  ]


def test_schedules_state_and_derived_fields_across_auto_resets(rollout):
  """All checks on the one rollout (compiled once even under xdist)."""
  _check_only_varied_fields_are_per_world(rollout)
  _check_per_episode_sequence_advances_at_every_auto_reset(rollout)
  _check_derived_fields_follow_the_size_and_match_a_recompile(rollout)
  _check_once_per_world_keeps_values_across_auto_resets(rollout)
  _check_every_k_steps_draws_and_reset_restarts_the_count(rollout)


def _binding(variation_, slot=0):
  return variator_base.Binding(None, 'attr', variation_, slot)


@pytest.mark.parametrize(
    'make, reads',
    [
        (lambda: distributions.Uniform(0.9, 1.1), False),
        (lambda: noises.Multiplicative(distributions.Uniform(0.9, 1.1)), False),
        (lambda: noises.Additive(0.1, cumulative=True), True),
        (lambda: deterministic.Sequence([1.0, 2.0]), False),
        (lambda: (lambda initial, current, key: initial * 2.0), False),
        (lambda: (lambda initial, current, key: current + 1.0), True),
    ],
)
def test_draws_read_current_finds_what_builds_on_the_current_value(make, reads):
  # With a distribution drawn beside it, as a variator binds several.
  bindings = [_binding(distributions.Uniform(0.0, 1.0)), _binding(make(), 1)]
  initial = [np.float32(0.5), np.float32(1.0)]
  assert variator_base.draws_read_current(bindings, initial) is reads


# -- bind-time errors ----------------------------------------------------------


class ComposersCallTask(composer.Task):
  """dm_control's idiom: the MJCF variator applied in
  `initialize_episode_mjcf` with composer's `apply_variations(random_state)`;
  `initialize_episode` records the ball's mass and radius it then sees."""

  def __init__(self):
    self.arena = composer.Arena()
    self.arena.mjcf_model.option.cone = mujoco.mjtCone.mjCONE_PYRAMIDAL
    self.ball = _ball()
    self.arena.add_free_entity(self.ball)
    self.set_timesteps(control_timestep=0.01, physics_timestep=0.01)
    self.variator = variation.MJCFVariator()
    self.variator.bind_attributes(
        self.ball.geom, size=distributions.Uniform([0.03, 0, 0], [0.08, 0, 0])
    )

  @property
  def root_entity(self):
    return self.arena

  def initial_task_state(self):
    return {'mass': jnp.zeros(()), 'radius': jnp.zeros(())}

  def initialize_episode_mjcf(self, random_state):
    self.variator.apply_variations(random_state)

  def initialize_episode(self, physics, key):
    return physics.update_task_state(
        mass=physics.bind(self.ball.body).mass,
        radius=physics.bind(self.ball.geom).size[0],
    )

  def get_reward(self, physics):
    return 0.0


def test_composers_call_in_initialize_episode_mjcf_varies_every_episode():
  """Each world's episode gets its own draw, applied before
  `initialize_episode`, equal to the model recompiled with it."""
  task = ComposersCallTask()
  env = composer.Environment(task)
  assert 'ComposersCallTask.initialize_episode_mjcf' in (
      env.per_world_model_fields['geom_size']
  )
  states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), 4))
  geom = env.mj_model.geom('ball/geom').id
  radius = _field(states, 'geom_size', geom)[:, 0]
  assert np.all((radius >= 0.03) & (radius <= 0.08))
  assert len(np.unique(radius)) == 4
  np.testing.assert_array_equal(states.task_state['radius'], radius)
  body = env.mj_model.body('ball/body').id
  np.testing.assert_array_equal(
      states.task_state['mass'],
      np.asarray(states.model_fields['body_mass'])[:, body],
  )
  # World 1 against the spec recompiled with its radius.
  handle = task.ball.geom
  saved = np.array(handle.size)
  try:
    handle.size = [float(radius[1]), 0.0, 0.0]
    spec, _ = task.root_entity.compose()
    reference = mjx.put_model(spec.compile())
  finally:
    handle.size = saved
  for name, value in states.model_fields.items():
    for mine, theirs in zip(
        jax.tree.leaves(value), jax.tree.leaves(getattr(reference, name))
    ):
      np.testing.assert_allclose(
          np.asarray(mine)[1], theirs, rtol=1e-5, atol=1e-6, err_msg=name
      )


def test_composers_call_outside_initialize_episode_mjcf_says_where():
  variator = variation.MJCFVariator()
  with pytest.raises(TypeError, match='initialize_episode_mjcf'):
    variator.apply_variations(np.random.RandomState(0))


def test_unsupported_attribute_lists_what_is_supported():
  ball = _ball()
  variator = variation.MJCFVariator()
  with pytest.raises(ValueError, match=r"geom attribute 'margin'.*'friction'"):
    variator.bind_attributes(ball.geom, margin=0.1)
  camera = ball.body.add_camera(name='cam')
  with pytest.raises(ValueError, match='cannot vary a camera.*geom: size'):
    variator.bind_attributes(camera, pos=[0, 0, 1])
  with pytest.raises(TypeError, match='MjSpec element'):
    variator.bind_attributes('ball/geom', rgba=[1, 0, 0, 1])


def test_structural_attributes_are_refused_with_reasons():
  hinge, ball = _hinge(), _ball()
  variator = variation.MJCFVariator()
  with pytest.raises(ValueError, match='fromto'):
    variator.bind_attributes(hinge.geom, pos=[0, 0, 0])
  with pytest.raises(ValueError, match='not limited'):
    variator.bind_attributes(hinge.unlimited, range=[-1, 1])
  hinge.joint.frictionloss = 0
  with pytest.raises(ValueError, match='no friction loss'):
    variator.bind_attributes(hinge.joint, frictionloss=0.1)
  with pytest.raises(ValueError, match='infers its mass'):
    variator.bind_attributes(ball.body, mass=1.0)
  with pytest.raises(ValueError, match='position actuators'):
    variator.bind_attributes(hinge.motor, kp=10.0)
  with pytest.raises(ValueError, match='no fluid forces'):
    variator.bind_attributes(composer.Arena().mjcf_model.option, density=1.0)
  mesh_spec = mujoco.MjSpec()
  mesh_spec.add_mesh(name='m', uservert=[0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1])
  mesh_geom = mesh_spec.worldbody.add_body().add_geom(
      type=_G.mjGEOM_MESH, meshname='m'
  )
  with pytest.raises(ValueError, match='re-meshing'):
    variator.bind_attributes(mesh_geom, size=[1, 1, 1])
  assert not variator.bindings


def test_shape_mismatch_at_bind_time():
  ball = _ball()
  variator = variation.MJCFVariator()
  with pytest.raises(ValueError, match=r'shape \(2,\).*shape \(3,\)'):
    variator.bind_attributes(ball.geom, size=[0.1, 0.2])
  with pytest.raises(
      ValueError,
      match=r'rgba cannot give a value for an ' r'attribute of shape \(4,\)',
  ):
    variator.bind_attributes(
        ball.geom, rgba=distributions.Uniform(np.zeros(5), 1)
    )
  with pytest.raises(ValueError, match=r'rgba gives values of shape \(3,\)'):
    variator.bind_attributes(
        ball.geom, rgba=lambda initial, current, key: jnp.ones(3)
    )
  # Scalars broadcast, like composer's attribute assignment.
  variator.bind_attributes(ball.geom, friction=distributions.Uniform(0.5, 1.0))
  # `None` unbinds.
  variator.bind_attributes(ball.geom, friction=None)
  assert not variator.bindings


# -- trace-time errors ---------------------------------------------------------


class _OneVariatorTask(composer.Task):
  """A hinge and a ball, and one variator that `bind` sets up."""

  def __init__(self, bind, schedule=None):
    self.arena = composer.Arena()
    self.arena.mjcf_model.worldbody.add_geom(
        name='floor', type=_G.mjGEOM_PLANE, size=[2, 2, 0.1]
    )
    self.hinge = _hinge()
    self.arena.attach(self.hinge)
    self.ball = _ball()
    self.arena.add_free_entity(self.ball)
    self.variator = variation.MJCFVariator(schedule=schedule)
    bind(self, self.variator)

  @property
  def root_entity(self):
    return self.arena

  def initialize_episode(self, physics, key):
    return self.variator.apply_variations(physics, key)

  def get_reward(self, physics):
    return 0.0


def _trace_reset(task, in_step=False):
  """Traces the task's variator on a fresh world of the compiled task.

  (Tracing apply_variations alone: Environment.reset would add its forward
  passes to every trace.)
  """
  env = composer.Environment(task)
  physics = env.initial_physics()
  apply = functools.partial(task.variator.apply_variations, in_step=in_step)
  return jax.eval_shape(apply, physics, jax.random.key(0))


def test_element_not_in_the_composed_model_names_it_and_says_attach():
  stray = _ball(name='stray')
  task = _OneVariatorTask(
      lambda t, v: v.bind_attributes(stray.geom, rgba=[1, 0, 0, 1])
  )
  with pytest.raises(
      ValueError,
      match=r"MjsGeom\('geom'\).*not part of the "
      r'compiled model.*attach its entity',
  ):
    _trace_reset(task)


def test_simple_body_refuses_moving_its_inertial_frame():
  # A lone slide body with one centred geom is "simple": MJX's mass matrix
  # omits couplings that an off-centre geom would create.
  def bind(task, variator):
    body = task.arena.mjcf_model.worldbody.add_body(name='cart')
    body.add_joint(name='x', type=_J.mjJNT_SLIDE, axis=[1, 0, 0])
    task.cart_geom = body.add_geom(
        name='cart', type=_G.mjGEOM_BOX, size=[0.1, 0.1, 0.1]
    )
    variator.bind_attributes(task.cart_geom, pos=[0.1, 0, 0])

  task = _OneVariatorTask(bind)
  with pytest.raises(ValueError, match='simple.*`simple = 0`'):
    _trace_reset(task)
  # As the message says: with simple = 0 the variation is allowed.
  task = _OneVariatorTask(bind)
  task.arena.mjcf_model.body('cart').simple = 0
  _trace_reset(task)


def test_option_not_of_the_root_spec_is_refused():
  # Options of attached entities are not compiled; here: a stray spec's.
  stray = mujoco.MjSpec()
  stray.option.gravity = [0, 0, -1]

  def bind(task, variator):
    del task
    variator.bind_attributes(stray.option, gravity=[0, 0, -5])

  with pytest.raises(ValueError, match="root entity's `mjcf_model.option`"):
    _trace_reset(_OneVariatorTask(bind))


def test_in_step_call_needs_the_every_steps_schedule():
  task = _OneVariatorTask(
      lambda t, v: v.bind_attributes(t.ball.geom, rgba=[1, 0, 0, 1])
  )
  with pytest.raises(ValueError, match='only applies to Schedule.every_steps'):
    _trace_reset(task, in_step=True)
  # The in-step call of an every-k variator needs the reset call's counter.
  task = _OneVariatorTask(
      lambda t, v: v.bind_attributes(t.ball.geom, rgba=[1, 0, 0, 1]),
      schedule=variation.Schedule.every_steps(2),
  )
  with pytest.raises(ValueError, match='from initialize_episode as well'):
    _trace_reset(task, in_step=True)


def test_schedule_validation():
  with pytest.raises(ValueError, match='positive integer'):
    variation.Schedule.every_steps(0)
  with pytest.raises(TypeError, match='Schedule'):
    variation.MJCFVariator(schedule='episode')
  assert str(variation.Schedule.every_steps(4)) == 'Schedule.every_steps(4)'


def test_supported_attributes_table_is_documented():
  text = attributes.supported_text()
  for kind in ('geom', 'body', 'site', 'joint', 'actuator', 'option'):
    assert kind in text
