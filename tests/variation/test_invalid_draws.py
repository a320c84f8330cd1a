"""Variations that draw invalid model values (negative masses, NaNs, ...).

At reset an invalid draw fails the episode's initialization (the
environment resamples it); in-step it is dropped. One tiny environment is
compiled for the whole file: its task holds an MJCFVariator and a
PhysicsVariator whose callables draw an invalid value for the attribute that
`_MODE` names when reset is traced, so each environment-level case only
retraces reset. Most cases apply variators directly to
`env.initial_physics()`.
"""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer import variation
from mjx_composer.compiler import attributes
from mjx_composer.variation import deterministic
from mjx_composer.variation import distributions
from mjx_composer.variation import noises
from mjx_composer.variation import physics_variator
from mjx_composer.variation import variator_base

_J = mujoco.mjtJoint
_G = mujoco.mjtGeom
KEY = jax.random.key(0)
_ATTEMPTS = 3

# Which switch draws an invalid value (read when reset is traced).
_MODE = {'invalid': None}


class Rig(composer.Robot):
  """A hinged box (inertia from its geom) carrying an explicit-inertia body."""

  def _build(self):
    spec = mujoco.MjSpec()
    spec.modelname = 'rig'
    self.link = spec.worldbody.add_body(name='link', pos=[0, 0, 0.5])
    self.joint = self.link.add_joint(
        name='hinge', type=_J.mjJNT_HINGE, axis=[0, 1, 0], damping=0.5
    )
    self.geom = self.link.add_geom(
        name='box',
        type=_G.mjGEOM_BOX,
        size=[0.1, 0.02, 0.02],
        pos=[0.1, 0, 0],
        contype=0,
        conaffinity=0,
    )
    self.weight = self.link.add_body(name='weight', pos=[0.2, 0, 0])
    self.weight.mass = 1.0
    self.weight.ipos = [0, 0, 0]
    self.weight.inertia = [0.01, 0.01, 0.01]
    self.weight.iquat = [1, 0, 0, 0]
    self.weight.explicitinertial = True
    self.motor = spec.add_actuator(
        name='motor', target='hinge', trntype=mujoco.mjtTrn.mjTRN_JOINT
    )
    self._spec = spec

  @property
  def mjcf_model(self):
    return self._spec

  @property
  def actuators(self):
    return (self.motor,)


def _switch(name, invalid):
  """Keeps the current value, or draws `invalid(key)` when `_MODE` says so."""

  def draw(initial, current, key):
    del initial
    if _MODE['invalid'] == name:
      return invalid(key)
    return current

  return draw


class _Task(composer.Task):

  def __init__(self):
    self.arena = composer.Arena()
    self.arena.mjcf_model.option.cone = mujoco.mjtCone.mjCONE_PYRAMIDAL
    self.rig = Rig()
    self.arena.attach(self.rig)
    self.set_timesteps(control_timestep=0.01, physics_timestep=0.01)
    self.mjcf = variation.MJCFVariator()
    self.mjcf.bind_attributes(
        self.rig.geom,
        size=_switch('mjcf_size', lambda key: jnp.asarray([-0.1, 0.02, 0.02])),
    )
    self.mjcf.bind_attributes(
        self.rig.joint, damping=_switch('mjcf_nan', lambda key: jnp.nan)
    )
    self.physics = variation.PhysicsVariator()
    self.physics.bind_attributes(
        self.rig.weight,
        mass=_switch(
            'physics_mass',
            lambda key: jax.random.uniform(key, (), minval=-2.0, maxval=-1.0),
        ),
    )

  @property
  def root_entity(self):
    return self.arena

  def initialize_episode(self, physics, key):
    keys = jax.random.split(key)
    physics = self.mjcf.apply_variations(physics, keys[0])
    return self.physics.apply_variations(physics, keys[1])

  def get_reward(self, physics):
    return 0.0


@pytest.fixture(scope='module')
def env():
  return composer.Environment(_Task(), max_reset_attempts=_ATTEMPTS)


def _reset(env, mode):
  _MODE['invalid'] = mode
  try:
    # A fresh function: reset is traced again with this mode.
    return jax.jit(lambda key: env.reset(key))(KEY)
  finally:
    _MODE['invalid'] = None


def _rig(env):
  return env.task.rig


# -- through the environment --------------------------------------------------


def test_valid_draws_are_not_flagged(env):
  state = _reset(env, None)
  assert state.metrics['init_failed'] == 0
  assert state.metrics['init_failures'] == 0


@pytest.mark.parametrize('mode', ['mjcf_size', 'mjcf_nan', 'physics_mass'])
def test_always_invalid_draw_fails_every_attempt(env, mode):
  state = _reset(env, mode)
  assert state.metrics['init_failed'] == 1
  assert state.metrics['init_failures'] == _ATTEMPTS


# -- at reset, on one world ---------------------------------------------------


def _negative(shape=()):
  return distributions.Uniform(-2.0 * np.ones(shape), -1.0 * np.ones(shape))


def _constant(value):
  return lambda initial, current, key: jnp.asarray(value, jnp.float32)


def _failed(env, variator):
  physics = jax.jit(variator.apply_variations)(env.initial_physics(), KEY)
  return bool(physics.initialization_failed), physics


_MJCF_INVALID = {
    'geom mass': ('geom', 'mass', _negative()),
    'geom density': ('geom', 'density', _constant(-5.0)),
    'geom size': ('geom', 'size', _constant([-0.1, 0.02, 0.02])),
    'geom size nan': ('geom', 'size', _constant([np.nan, 0.02, 0.02])),
    'geom friction': ('geom', 'friction', _negative((3,))),
    'geom rgba': ('geom', 'rgba', _constant([2.0, 0, 0, 1])),
    'joint damping': ('joint', 'damping', noises.Additive(-10.0)),
    'body mass': ('weight', 'mass', _negative()),
    'body inertia': ('weight', 'inertia', _constant([-1.0, 0.01, 0.01])),
    'body mass nan': ('weight', 'mass', _constant(np.nan)),
}


@pytest.mark.parametrize('case', sorted(_MJCF_INVALID))
def test_mjcf_invalid_draw_fails_initialization(env, case):
  element, attr, draw = _MJCF_INVALID[case]
  variator = variation.MJCFVariator()
  variator.bind_attributes(getattr(_rig(env), element), **{attr: draw})
  failed, _ = _failed(env, variator)
  assert failed


def test_mjcf_valid_draws_are_not_flagged_and_invalid_ones_written(env):
  rig = _rig(env)
  variator = variation.MJCFVariator()
  variator.bind_attributes(
      rig.geom,
      mass=distributions.Uniform(1.0, 2.0),
      size=noises.Multiplicative(distributions.Uniform(0.9, 1.1)),
      rgba=distributions.Uniform(0.0, 1.0),
  )
  variator.bind_attributes(rig.joint, damping=distributions.Uniform(0, 1))
  variator.bind_attributes(rig.weight, inertia=[0.02, 0.02, 0.02])
  failed, _ = _failed(env, variator)
  assert not failed
  # The invalid value is still written: the environment resamples.
  variator.bind_attributes(rig.joint, damping=_constant(np.nan))
  failed, physics = _failed(env, variator)
  assert failed
  dof = env.mj_model.joint('rig/hinge').dofadr[0]
  assert np.isnan(physics.model.dof_damping[dof])


_PHYSICS_INVALID = {
    'body_mass': ('weight', 'mass', _negative()),
    'body_inertia': ('weight', 'body_inertia', _constant([-1.0, 1.0, 1.0])),
    'geom_size': ('geom', 'size', _constant([-0.1, 0.02, 0.02])),
    'geom_friction': ('geom', 'friction', _negative((3,))),
    'geom_rgba nan': ('geom', 'rgba', _constant([np.nan, 0, 0, 1])),
    'dof_damping': ('joint', 'damping', noises.Additive(-10.0)),
    'actuator_gear nan': ('motor', 'gear', _constant([np.nan, 0, 0, 0, 0, 0])),
}


@pytest.mark.parametrize('case', sorted(_PHYSICS_INVALID))
def test_physics_invalid_draw_fails_initialization(env, case):
  element, attr, draw = _PHYSICS_INVALID[case]
  variator = variation.PhysicsVariator()
  variator.bind_attributes(getattr(_rig(env), element), **{attr: draw})
  failed, _ = _failed(env, variator)
  assert failed


def test_physics_valid_draws_are_not_flagged(env):
  rig = _rig(env)
  variator = variation.PhysicsVariator()
  variator.bind_attributes(rig.weight, mass=distributions.Uniform(1.0, 2.0))
  variator.bind_attributes(
      rig.geom,
      friction=distributions.Uniform([0.5, 0, 0], [1.5, 0.01, 0.01]),
      size=noises.Multiplicative(distributions.Uniform(0.9, 1.1)),
  )
  variator.bind_attributes(rig.joint, damping=0.0)
  # Negative gains are valid (gear: finite only).
  variator.bind_attributes(rig.motor, gear=[-2.0, 0, 0, 0, 0, 0])
  failed, _ = _failed(env, variator)
  assert not failed


def test_skipped_draws_are_never_invalid(env):
  """Once per world: the second reset keeps the values, draws nothing."""
  variator = variation.PhysicsVariator(
      schedule=variation.Schedule.once_per_world()
  )
  variator.bind_attributes(
      _rig(env).weight, mass=deterministic.Sequence([1.0, -1.0])
  )

  @jax.jit
  def two_resets(physics):
    first = variator.apply_variations(physics, KEY)
    second = variator.apply_variations(
        first.replace(initialization_failed=jnp.zeros((), bool)), KEY
    )
    return first.initialization_failed, second.initialization_failed

  first, second = two_resets(env.initial_physics())
  assert not first and not second


# -- in step ------------------------------------------------------------------


def _steps(variator, physics, n, read):
  """Reset, then `n` in-step calls; `read(physics)` after each call."""

  @jax.jit
  def run(physics):
    physics = variator.apply_variations(physics, KEY)
    out = [read(physics)]
    for i in range(n):
      physics = variator.apply_variations(
          physics, jax.random.fold_in(KEY, i + 1), in_step=True
      )
      out.append(read(physics))
    return jnp.stack(out), physics.initialization_failed

  return run(physics)


def test_physics_in_step_invalid_draw_keeps_current_values(env):
  variator = variation.PhysicsVariator(
      schedule=variation.Schedule.every_steps(1)
  )
  variator.bind_attributes(
      _rig(env).joint, damping=deterministic.Sequence([1.0, 2.0, -1.0, 3.0])
  )
  dof = env.mj_model.joint('rig/hinge').dofadr[0]
  values, failed = _steps(
      variator, env.initial_physics(), 4, lambda p: p.model.dof_damping[dof]
  )
  # Reset: 1; in-step call 1 (no step done yet): no draw; call 2: 2; calls
  # 3 and 4 draw -1 (the state does not advance past a dropped draw).
  np.testing.assert_array_equal(values, [1.0, 1.0, 2.0, 2.0, 2.0])
  assert not failed


def test_mjcf_in_step_invalid_draw_keeps_current_values(env):
  variator = variation.MJCFVariator(schedule=variation.Schedule.every_steps(1))
  variator.bind_attributes(
      _rig(env).geom,
      size=deterministic.Sequence(
          [[0.1, 0.02, 0.02], [0.2, 0.02, 0.02], [np.nan, 0.02, 0.02]]
      ),
  )
  link = env.mj_model.body('rig/link').id
  geom = env.mj_model.geom('rig/box').id

  def read(physics):
    return jnp.concatenate(
        [
            physics.model.geom_size[geom],
            physics.model.body_mass[link][None],
        ]
    )

  values, failed = _steps(variator, env.initial_physics(), 3, read)
  values = np.asarray(values)
  assert np.all(np.isfinite(values))
  np.testing.assert_allclose(values[2, :3], [0.2, 0.02, 0.02], rtol=1e-6)
  # The derived mass follows the last valid size and stays there.
  np.testing.assert_array_equal(values[3], values[2])
  assert values[2, 3] > values[0, 3]
  assert not failed


# -- bind time and bounds -----------------------------------------------------


@pytest.mark.parametrize(
    'kind, element, attrs, match',
    [
        ('mjcf', 'geom', {'mass': -1.0}, r'mass must be finite and >= 0'),
        ('mjcf', 'geom', {'size': [0.0, 0.1, 0.1]}, 'size must be'),
        ('mjcf', 'geom', {'rgba': [0, 0, 0, 2]}, r'in \[0, 1\]'),
        ('mjcf', 'joint', {'damping': np.nan}, 'damping must be finite'),
        ('mjcf', 'weight', {'inertia': [-1, 1, 1]}, 'inertia must be'),
        ('physics', 'weight', {'mass': -1.0}, r'mass must be finite and >= 0'),
        ('physics', 'geom', {'friction': [-1, 0, 0]}, 'friction must be'),
        ('physics', 'joint', {'dof_damping': -1.0}, 'dof_damping must be'),
        ('physics', 'motor', {'gear': [np.inf, 0, 0, 0, 0, 0]}, 'finite'),
    ],
)
def test_invalid_constant_is_refused_at_bind_time(
    env, kind, element, attrs, match
):
  variator = (
      variation.MJCFVariator()
      if kind == 'mjcf'
      else variation.PhysicsVariator()
  )
  with pytest.raises(ValueError, match=match):
    variator.bind_attributes(getattr(_rig(env), element), **attrs)


def test_bounds():
  assert attributes.BY_KIND['geom']['mass'].bound is attributes.NONNEGATIVE
  assert attributes.BY_KIND['geom']['size'].bound is attributes.SIZE
  assert attributes.BY_KIND['actuator']['gear'].bound is attributes.FINITE
  timestep = physics_variator.FIELD_BOUNDS['opt.timestep']
  assert not timestep.valid(np.float64(0.0))
  assert timestep.valid(np.float64(0.002))
  size = attributes.SIZE
  assert size.valid(np.array([0.1, 0.0, 0.0]))
  assert not size.valid(np.array([0.0, 0.1, 0.1]))
  assert not size.valid(np.array([0.1, -0.1, 0.1]))
  assert not bool(size.valid(jnp.array([[0.1, 0, 0], [0, 0.1, 0]])))
  # A compiled value that breaks its bound (an infinite plane) relaxes it.
  assert attributes.bound_for(size, [0, 0, 0.1]) is attributes.NONNEGATIVE
  assert attributes.bound_for(attributes.POSITIVE, -1.0) is attributes.FINITE


def _draws(rng, breaks):
  """Values and bounds as a variator checks them: scalars, sizes and gears
  sharing bounds, with the one at index `breaks` out of its bound."""
  bounds = [attributes.NONNEGATIVE] * 5 + [attributes.SIZE] * 3
  bounds += [attributes.FINITE] * 2 + [attributes.POSITIVE]
  values = [rng.uniform(0.5, 1.5) for _ in range(5)]
  values += [rng.uniform(0.1, 0.2, 3) for _ in range(3)]
  values += [rng.uniform(-1.0, 1.0, 6) for _ in range(2)] + [rng.uniform(1, 2)]
  bad = {
      attributes.NONNEGATIVE: -0.1,
      attributes.SIZE: np.array([0.0, 0.1, 0.1]),
      attributes.FINITE: np.array([0, 0, np.nan, 0, 0, 0]),
      attributes.POSITIVE: 0.0,
  }
  if breaks is not None:
    values[breaks] = bad[bounds[breaks]]
  return [np.asarray(v, np.float32) for v in values], bounds


@pytest.mark.parametrize('breaks', [None, 0, 3, 6, 7, 8, 9, 10])
def test_invalid_draw_flags_exactly_the_value_that_breaks_its_bound(breaks):
  # Every value is checked in one array against its bound's limits; the
  # flag is still each value's own check (NumPy's, one value at a time)
  # or-ed together.
  values, bounds = _draws(np.random.default_rng(7), breaks)
  expected = not all(bool(b.valid(v)) for v, b in zip(values, bounds))
  assert expected == (breaks is not None)
  flag = jax.jit(variator_base.invalid_draw, static_argnums=1)
  assert bool(flag(values, tuple(bounds))) == expected
  batched = jax.vmap(lambda v: variator_base.invalid_draw(v, bounds))
  stacked = [np.stack([v, v]) for v in values]
  np.testing.assert_array_equal(batched(stacked), [expected, expected])


# -- a world whose every attempt fails ------------------------------------------


class _MassTask(_Task):
  """The rig with the weight's mass drawn from [-1, 1] at every reset: about
  half the attempts are invalid (a negative mass)."""

  def __init__(self):
    super().__init__()
    self.mass = variation.PhysicsVariator()
    self.mass.bind_attributes(
        self.rig.weight, mass=distributions.Uniform(-1.0, 1.0)
    )

  def initialize_episode(self, physics, key):
    return self.mass.apply_variations(physics, key)


_MASS_ATTEMPTS = 2
_MASS_STEPS = 4


@pytest.fixture(scope='module', params=['next_step', 'same_step'])
def mass_env(request):
  return composer.Environment(
      _MassTask(),
      max_reset_attempts=_MASS_ATTEMPTS,
      options=composer.ExecutionOptions(auto_reset=request.param),
  )


def _numbers(leaf):
  """A state's leaf as a NumPy array (a PRNG key as its key data)."""
  if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
    leaf = jax.random.key_data(leaf)
  return np.asarray(leaf)


def _rollout(env, keys):
  """The reset of `keys`' worlds and `_MASS_STEPS` steps, every state."""

  @jax.jit
  def run(keys):
    state = jax.vmap(env.reset)(keys)
    states = [state]
    action = jnp.full((keys.shape[0], 1), 0.3)
    for _ in range(_MASS_STEPS):
      state = jax.vmap(env.step)(state, action)
      states.append(state)
    return states

  return jax.device_get(run(keys))


def test_a_world_whose_every_attempt_fails_never_runs_its_draw(mass_env):
  """It keeps the compiled mass, is flagged, and its first step ends the
  episode; the other worlds run bit for bit as in a batch without it."""
  env = mass_env
  weight = env.mj_model.body('rig/weight').id
  nominal = env.mj_model.body_mass[weight]
  candidates = jax.random.split(jax.random.key(7), 32)
  first = jax.device_get(jax.jit(jax.vmap(env.reset))(candidates))
  failed = np.flatnonzero(first.metrics['init_failed'] == 1)
  passed = np.flatnonzero(first.metrics['init_failed'] == 0)
  assert failed.size and passed.size >= 2, 'no failing or valid world drawn'
  bad, good = failed[0], passed[:2]
  assert first.metrics['init_failures'][bad] == _MASS_ATTEMPTS

  with_bad = _rollout(env, candidates[np.array([good[0], bad, good[1]])])
  without = _rollout(env, candidates[good])
  mass = lambda state: state.model_fields['body_mass'][:, weight]

  # The failing world: the compiled mass at reset, never a negative one.
  start = with_bad[0]
  assert mass(start)[1] == nominal
  assert start.metrics['init_failed'][1] == 1
  for state in with_bad + without:
    assert np.all(mass(state) >= 0), mass(state)
    assert np.all(np.isfinite(state.data.qpos))
  # Its first step ends the episode, with nothing learned from it.
  after = with_bad[1]
  assert after.metrics['diverged'][1] == 0
  assert after.step_type[1] == composer.StepType.LAST
  assert after.reward[1] == 0 and after.discount[1] == 0
  assert bool(after.terminated[1])

  # The valid worlds run as in a batch without the failing one.
  for state_with, state_without in zip(with_bad, without, strict=True):
    for a, b in zip(
        jax.tree.leaves(state_with), jax.tree.leaves(state_without), strict=True
    ):
      a, b = _numbers(a), _numbers(b)
      if a.ndim and a.shape[0] == 3:
        np.testing.assert_array_equal(a[np.array([0, 2])], b)
