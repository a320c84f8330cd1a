"""Bad input is rejected early, with a message that says what to fix."""

import functools
import math
import re
import subprocess
import sys
import warnings

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.model import model_checks
from mjx_composer import task as task_lib
from tests import conftest

_OBJ = mujoco.mjtObj

# -- 1. composition never drops an element ------------------------------------


class _Arm(conftest.SpecEntity):
  """A one-joint arm; `edit(spec)` may add a faulty element."""

  def _build(self, edit=None, name='arm'):
    spec = self._new_spec(name)
    body = spec.worldbody.add_body(name='link')
    body.add_joint(name='shoulder', type=mujoco.mjtJoint.mjJNT_HINGE)
    body.add_geom(name='geom', size=[0.1, 0, 0])
    body.add_site(name='tip')
    spec.add_actuator(
        name='motor', target='shoulder', trntype=mujoco.mjtTrn.mjTRN_JOINT
    )
    if edit is not None:
      edit(spec)


def _typo_actuator(spec):
  spec.actuators[0].target = 'shoulderr'


def _typo_sensor(spec):
  spec.add_sensor(
      name='touch',
      type=mujoco.mjtSensor.mjSENS_TOUCH,
      objtype=_OBJ.mjOBJ_SITE,
      objname='tipp',
  )


def _in_arena(arm):
  arena = composer.Arena()
  arena.attach(arm)
  return arena


def test_valid_composition_keeps_every_element():
  arena = _in_arena(_Arm(edit=_typo_sensor_fixed))
  model = arena.compose()[0].compile()
  assert (model.nu, model.nsensor) == (1, 1)


def _typo_sensor_fixed(spec):
  spec.add_sensor(
      name='touch',
      type=mujoco.mjtSensor.mjSENS_TOUCH,
      objtype=_OBJ.mjOBJ_SITE,
      objname='tip',
  )


def test_root_actuator_typo_raises():
  with pytest.raises(
      ValueError,
      match=(
          r"Actuator 'motor' targets joint 'shoulderr', which does not exist "
          r"in the composed model: fix the target name in entity 'arm'.*did "
          r"you mean 'shoulder'"
      ),
  ):
    _Arm(edit=_typo_actuator).compose()


def test_child_actuator_typo_raises():
  with pytest.raises(
      ValueError,
      match=(
          r"Actuator 'arm/motor' targets joint 'arm/shoulderr', which does not"
          r" exist in the composed model: fix the target name in entity 'arm'"
      ),
  ):
    _in_arena(_Arm(edit=_typo_actuator)).compose()


def test_root_sensor_typo_raises():
  with pytest.raises(
      ValueError,
      match=r"Sensor 'touch' is attached to site 'tipp'.*fix the sensor's "
      r"objname in entity 'arm'.*did you mean 'tip'",
  ):
    _Arm(edit=_typo_sensor).compose()


def test_child_sensor_typo_raises():
  with pytest.raises(
      ValueError,
      match=r"Sensor 'arm/touch' is attached to site 'arm/tipp'.*fix the "
      r"sensor's objname in entity 'arm'",
  ):
    _in_arena(_Arm(edit=_typo_sensor)).compose()


def test_grandchild_typo_names_the_full_path():
  hand = _Arm(edit=_typo_actuator, name='hand')
  arm = _Arm()
  arm.attach(hand)
  with pytest.raises(
      ValueError,
      match=r"Actuator 'arm/hand/motor' targets joint 'arm/hand/shoulderr'.*"
      r"fix the target name in entity 'hand'",
  ):
    _in_arena(arm).compose()


def test_every_dropped_element_is_reported():
  def two_typos(spec):
    _typo_actuator(spec)
    _typo_sensor(spec)

  with pytest.raises(ValueError, match=r'would drop 2 elements') as error:
    _in_arena(_Arm(edit=two_typos)).compose()
  assert "'arm/motor'" in str(error.value)
  assert "'arm/touch'" in str(error.value)


@pytest.mark.parametrize(
    'edit, match',
    [
        (
            lambda s: s.add_tendon(name='t').wrap_joint('elbow', 1.0),
            r"Tendon 'arm/t' wraps \(path element 0\) a joint that does not "
            r"exist in entity 'arm'.*fix the joint name of path element 0",
        ),
        (
            lambda s: s.add_equality(
                name='weld',
                type=mujoco.mjtEq.mjEQ_WELD,
                objtype=_OBJ.mjOBJ_BODY,
                name1='link',
                name2='lnk',
            ),
            r"Equality 'arm/weld' constrains body 'arm/lnk'.*fix the "
            r"equality's name2 in entity 'arm'",
        ),
        (
            lambda s: s.add_exclude(bodyname1='link', bodyname2='base'),
            r"Exclude #0 \(unnamed\) excludes body 'arm/base'.*fix the "
            r"exclude's bodyname2 in entity 'arm'",
        ),
        (
            lambda s: s.add_pair(geomname1='geom', geomname2='gem'),
            r"Contact pair #0 \(unnamed\) pairs geom 'arm/gem'.*fix the "
            r"pair's geomname2 in entity 'arm'",
        ),
        (
            lambda s: s.add_actuator(
                name='site_motor',
                target='tip',
                refsite='ref',
                trntype=mujoco.mjtTrn.mjTRN_SITE,
            ),
            r"Actuator 'arm/site_motor' refers to site 'arm/ref'.*fix the "
            r"refsite name in entity 'arm'",
        ),
    ],
)
def test_other_dangling_references_raise(edit, match):
  with pytest.raises(ValueError, match=match):
    _in_arena(_Arm(edit=edit)).compose()


def test_reference_into_a_child_entity_is_kept():
  # Composer lets an entity refer to the elements of entities attached below
  # it by full name; composition adds such elements after the attach.
  arena = _in_arena(_Arm())
  reach = arena.mjcf_model.add_actuator(
      name='reach', target='arm/shoulder', trntype=mujoco.mjtTrn.mjTRN_JOINT
  )
  weld = arena.mjcf_model.add_equality(
      type=mujoco.mjtEq.mjEQ_CONNECT,
      name1='arm/link',
      objtype=_OBJ.mjOBJ_BODY,
      active=False,
  )
  spec, handles = arena.compose()
  model = spec.compile()
  assert model.nu == 2 and model.neq == 1
  shoulder = model.joint('arm/shoulder').id
  assert model.actuator('reach').trnid[0] == shoulder
  assert model.actuator('arm/motor').trnid[0] == shoulder
  assert model.eq_obj1id[0] == model.body('arm/link').id
  # The arena's own handles bind to the composed elements.
  assert handles[id(reach)][2].name == 'reach'
  assert handles[id(weld)][1] == 'equality'


def test_reference_to_an_entity_not_attached_below_raises():
  arena = _in_arena(_Arm())
  arena.mjcf_model.add_actuator(
      name='reach', target='leg/knee', trntype=mujoco.mjtTrn.mjTRN_JOINT
  )
  with pytest.raises(
      ValueError,
      match=r"Actuator 'reach' targets joint 'leg/knee', which is not an "
      r"element of the own spec of entity 'arena'.*by full name to those of "
      r'entities attached below it',
  ):
    arena.compose()


def test_typo_in_a_reference_into_a_child_fails_to_compile():
  arena = _in_arena(_Arm())
  arena.mjcf_model.add_actuator(
      name='reach', target='arm/shoulderr', trntype=mujoco.mjtTrn.mjTRN_JOINT
  )
  with pytest.raises(ValueError, match=r'failed to compile.*arm/shoulderr'):
    composer.Environment(composer.NullTask(arena))


def test_child_sensor_on_its_worldbody_raises():
  def world_sensor(spec):
    spec.add_sensor(
        name='frame',
        type=mujoco.mjtSensor.mjSENS_FRAMEPOS,
        objtype=_OBJ.mjOBJ_BODY,
        objname='world',
    )

  # As the root entity, 'world' is the world: nothing is dropped.
  assert _Arm(edit=world_sensor).compose()[0].compile().nsensor == 1
  with pytest.raises(
      ValueError,
      match=r"Sensor 'arm/frame' is attached to the worldbody of entity "
      r"'arm'.*make it refer to a body inside entity 'arm'",
  ):
    _in_arena(_Arm(edit=world_sensor)).compose()


def test_environment_build_raises_on_a_dropped_element():
  task = composer.NullTask(_in_arena(_Arm(edit=_typo_actuator)))
  with pytest.raises(ValueError, match=r"fix the target name in entity 'arm'"):
    composer.Environment(task)


# -- 2. timesteps and model options -------------------------------------------

_BAD_SECONDS = [0, 0.0, -0.01, math.nan, math.inf]


@pytest.mark.parametrize('bad', _BAD_SECONDS)
def test_check_timesteps_divisible_rejects_non_positive(bad):
  with pytest.raises(
      ValueError, match=r'physics_timestep must be a positive, finite number'
  ):
    task_lib.check_timesteps_divisible(0.01, bad)
  with pytest.raises(
      ValueError, match=r'control_timestep must be a positive, finite number'
  ):
    task_lib.check_timesteps_divisible(bad, 0.01)


@pytest.mark.parametrize('bad', _BAD_SECONDS)
def test_set_timesteps_rejects_non_positive(bad):
  task = composer.NullTask(composer.Arena())
  with pytest.raises(
      ValueError, match=r'positive, finite number of seconds.*set_timesteps'
  ):
    task.set_timesteps(control_timestep=0.01, physics_timestep=bad)
  with pytest.raises(ValueError, match=r'control_timestep must be a positive'):
    task.set_timesteps(control_timestep=bad, physics_timestep=0.01)


@pytest.mark.parametrize('bad', _BAD_SECONDS)
def test_timestep_setters_reject_non_positive(bad):
  task = composer.NullTask(composer.Arena())
  with pytest.raises(ValueError, match=r'physics_timestep must be a positive'):
    task.physics_timestep = bad
  with pytest.raises(ValueError, match=r'control_timestep must be a positive'):
    task.control_timestep = bad
  task.set_timesteps(control_timestep=0.02, physics_timestep=0.01)
  with pytest.raises(ValueError, match=r'physics_timestep must be a positive'):
    task.physics_timestep = bad
  assert task.physics_timestep == 0.01  # Unchanged.


def test_timesteps_must_be_numbers():
  task = composer.NullTask(composer.Arena())
  with pytest.raises(TypeError, match=r'must be a number of seconds'):
    task.set_timesteps(control_timestep='0.02', physics_timestep=0.01)


_BODY = '<worldbody><body><joint/><geom size=".1"/></body></worldbody>'


def _model(option='', body=_BODY):
  return mujoco.MjModel.from_xml_string(f'<mujoco>{option}{body}</mujoco>')


@pytest.mark.parametrize('timestep', ['0', '-0.01', 'nan', 'inf'])
def test_check_compiled_model_rejects_bad_timestep(timestep):
  with pytest.raises(
      ValueError,
      match=r'option.timestep is .*positive, finite number of seconds.*'
      r'task.set_timesteps',
  ):
    model_checks.check_compiled_model(
        _model(f'<option timestep="{timestep}"/>')
    )


def test_check_compiled_model_rejects_zero_dofs():
  with pytest.raises(
      ValueError,
      match=r'no degrees of freedom \(nv == 0\).*Give a body a joint.*'
      r'add_free_entity',
  ):
    model_checks.check_compiled_model(
        _model(body='<worldbody><body><geom size=".1"/></body></worldbody>')
    )


def test_check_compiled_model_accepts_a_default_model_quietly():
  with warnings.catch_warnings():
    warnings.simplefilter('error')
    model_checks.check_compiled_model(_model())


@pytest.mark.parametrize(
    'option, named',
    [
        ('<option noslip_iterations="3"/>', 'option.noslip_iterations=3'),
        ('<option ccd_iterations="7"/>', 'option.ccd_iterations=7'),
        ('<option sdf_iterations="3"/>', 'option.sdf_iterations=3'),
        ('<option actuatorgroupdisable="1"/>', 'option.disableactuator'),
        (
            '<option><flag nativeccd="disable"/></option>',
            'mjDSBL_NATIVECCD',
        ),
        ('<option><flag sleep="enable"/></option>', 'mjENBL_SLEEP'),
    ],
)
def test_check_compiled_model_warns_about_ignored_options(option, named):
  with pytest.warns(
      model_checks.MjxIgnoredOptionWarning, match=r'MJX ignores.*' + named
  ):
    model_checks.check_compiled_model(_model(option))


def test_ignored_options_are_named_in_one_warning():
  option = (
      '<option noslip_iterations="2" ccd_tolerance="1e-3">'
      '<flag multiccd="disable"/></option>'
  )
  with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter('always')
    model_checks.check_compiled_model(_model(option))
  assert len(caught) == 1
  message = str(caught[0].message)
  for name in ('noslip_iterations', 'ccd_tolerance', 'mjDSBL_MULTICCD'):
    assert name in message


@pytest.mark.parametrize(
    'option, match',
    [
        (
            '<option integrator="implicit"/>',
            r'integrator mjINT_IMPLICIT.*implicitfast',
        ),
        ('<option solver="PGS"/>', r'solver mjSOL_PGS.*Newton'),
        (
            '<option><flag override="enable"/></option>',
            r'enable flags \[.mjENBL_OVERRIDE.\].*clear them',
        ),
    ],
)
def test_check_compiled_model_explains_what_mjx_rejects(option, match):
  with pytest.raises(NotImplementedError, match=match):
    model_checks.check_compiled_model(_model(option))


# These need `model_checks.check_compiled_model(self._mj_model)` in
# `Environment.__init__`, right after the composed spec compiles.


def test_environment_rejects_a_timestep_set_on_the_spec():
  arena = _in_arena(_Arm())
  arena.mjcf_model.option.timestep = -0.01
  with pytest.raises(
      ValueError, match=r"compiled model's option.timestep is -0.01"
  ):
    composer.Environment(composer.NullTask(arena))


def test_environment_rejects_a_model_without_dofs():
  arena = composer.Arena()
  arena.mjcf_model.worldbody.add_geom(size=[0.1, 0, 0])
  with pytest.raises(ValueError, match=r'no degrees of freedom'):
    composer.Environment(composer.NullTask(arena))


def test_environment_warns_about_ignored_options():
  arena = _in_arena(_Arm())
  arena.mjcf_model.option.noslip_iterations = 5
  with pytest.warns(
      model_checks.MjxIgnoredOptionWarning, match=r'noslip_iterations=5'
  ):
    composer.Environment(composer.NullTask(arena))


# -- 3. HostEnvironment arguments and action shapes ----------------------------


@functools.lru_cache(maxsize=None)
def _pendulum_environment():
  arena = composer.Arena()
  arena.attach(conftest.Pendulum())
  return composer.Environment(composer.NullTask(arena), time_limit=0.1)


@pytest.mark.parametrize('num_worlds', [0, -2, 2.5, True, '3'])
def test_host_environment_rejects_bad_num_worlds(num_worlds):
  with pytest.raises(
      ValueError, match=r'num_worlds must be a positive int.*num_worlds=None'
  ):
    composer.HostEnvironment(_pendulum_environment(), num_worlds=num_worlds)


def test_batched_host_environment_explains_a_single_world_action():
  env = composer.HostEnvironment(_pendulum_environment(), num_worlds=3)
  env.reset()
  single = np.zeros(env.action_spec().shape, np.float32)  # (1,)
  with pytest.raises(
      ValueError,
      match=r'steps 3 worlds at once: expected actions of shape \(3, 1\).*got '
      r"\(1,\), the shape of one world's action.*np.broadcast_to\(action, "
      r'\(3, 1\)\)',
  ):
    env.step(single)
  timestep = env.step(np.broadcast_to(single, (3, 1)))
  assert timestep.step_type.shape == (3,)


def test_single_world_host_environment_explains_a_batched_action():
  env = composer.HostEnvironment(_pendulum_environment())
  env.reset()
  with pytest.raises(
      ValueError,
      match=r'steps one world: expected an action of shape \(1,\).*got '
      r'\(4, 1\).*HostEnvironment\(environment, num_worlds=4\)',
  ):
    env.step(np.zeros((4, 1), np.float32))


# -- 5. importing the package prints nothing ----------------------------------


def test_import_prints_nothing():
  result = subprocess.run(
      [sys.executable, '-c', 'import mjx_composer'],
      capture_output=True,
      text=True,
      check=True,
  )
  assert result.stdout == ''
  assert result.stderr == ''


# -- the Brax adapter -----------------------------------------------------------


@pytest.mark.parametrize('length', [0, -5, 2.5, True])
def test_brax_env_rejects_a_bad_episode_length(length):
  from mjx_composer.adapters import brax as brax_adapter  # pylint: disable=g-import-not-at-top

  env = composer.Environment(
      composer.NullTask(_Arm()),
      time_limit=1.0,
      options=composer.ExecutionOptions(auto_reset='same_step'),
  )
  with pytest.raises(ValueError, match='positive number of control steps'):
    brax_adapter.BraxEnv(env, episode_length=length)


def test_a_batched_state_in_the_single_world_step_says_use_vmap():
  env = composer.Environment(composer.NullTask(_Arm()))
  states = jax.eval_shape(
      jax.vmap(env.reset), jax.random.split(jax.random.key(0), 3)
  )
  with pytest.raises(ValueError, match=r'holds 3 worlds.*jax.vmap\(env.step\)'):
    jax.eval_shape(env.step, states, jnp.zeros((1,)))


# -- distributions: numpy's parameter checks, at construction ----------------

_NAN, _INF = float('nan'), float('inf')
_GEN = np.random.default_rng(0)

# (distribution, the argument named, the numpy call that refuses the same
# parameters, or None where numpy returns NaN/inf samples instead).
_BAD_DISTRIBUTIONS = [
    (lambda d: d.Exponential(scale=-1), 'scale', lambda: _GEN.exponential(-1)),
    (lambda d: d.Poisson(lam=-1), 'lam', lambda: _GEN.poisson(-1)),
    (lambda d: d.Poisson(lam=_NAN), 'lam', lambda: _GEN.poisson(_NAN)),
    (lambda d: d.Poisson(lam=1e20), 'lam', lambda: _GEN.poisson(1e20)),
    (lambda d: d.Bernoulli(prob=1.5), 'prob', lambda: _GEN.binomial(1, 1.5)),
    (lambda d: d.Bernoulli(prob=-0.1), 'prob', lambda: _GEN.binomial(1, -0.1)),
    (lambda d: d.Bernoulli(prob=_NAN), 'prob', lambda: _GEN.binomial(1, _NAN)),
    (lambda d: d.UniformInteger(5, 2), 'high', lambda: _GEN.integers(5, 2)),
    (lambda d: d.UniformInteger(2, 2), 'high', lambda: _GEN.integers(2, 2)),
    (lambda d: d.UniformInteger(0), 'low', lambda: _GEN.integers(0)),
    (lambda d: d.UniformInteger([0, 5], [3, 4]), 'high', None),
    (lambda d: d.UniformInteger(_NAN), 'low', lambda: _GEN.integers(_NAN)),
    (lambda d: d.UniformInteger(2.5), 'low', None),
    (lambda d: d.Normal(0, scale=-1), 'scale', lambda: _GEN.normal(0, -1)),
    (lambda d: d.Normal(0, scale=_NAN), 'scale', None),
    (lambda d: d.Normal(loc=_INF), 'loc', None),
    (
        lambda d: d.LogNormal(0, sigma=-1),
        'sigma',
        lambda: _GEN.lognormal(0, -1),
    ),
    (lambda d: d.LogNormal(mean=_NAN), 'mean', None),
    (lambda d: d.Uniform(0, _INF), 'high', lambda: _GEN.uniform(0, _INF)),
    (lambda d: d.Uniform(_NAN, 1), 'low', lambda: _GEN.uniform(_NAN, 1)),
    # Variation parameters whose static bounds leave the domain.
    (lambda d: d.Exponential(scale=d.Uniform(-1, 1)), 'scale', None),
    (lambda d: d.Bernoulli(prob=d.Uniform(0.5, 2)), 'prob', None),
    (lambda d: d.UniformInteger(d.UniformInteger(0, 5), 3), 'high', None),
]


@pytest.mark.parametrize(
    'make, name, numpy_call',
    _BAD_DISTRIBUTIONS,
    ids=[str(i) for i in range(len(_BAD_DISTRIBUTIONS))],
)
def test_distribution_refuses_parameters_numpy_refuses(make, name, numpy_call):
  from mjx_composer.variation import distributions  # pylint: disable=g-import-not-at-top

  if numpy_call is not None:  # The reference: numpy refuses them too.
    with pytest.raises((ValueError, OverflowError)):
      numpy_call()
  with pytest.raises(ValueError, match=rf'`{name}`.*Pass'):
    make(distributions)


def test_distribution_refuses_non_numeric_parameters():
  from mjx_composer.variation import distributions  # pylint: disable=g-import-not-at-top

  with pytest.raises(TypeError, match=r"Normal: `loc` must be a number.*'a'"):
    distributions.Normal('a')


def test_distribution_boundary_parameters_numpy_accepts_are_kept():
  from mjx_composer.variation import distributions  # pylint: disable=g-import-not-at-top

  key = jax.random.key(0)
  assert float(distributions.Exponential(0.0)(key=key)) == _GEN.exponential(0)
  assert int(distributions.Bernoulli(1.0)(key=key)) == 1
  assert int(distributions.Bernoulli(0)(key=key)) == 0
  assert int(distributions.UniformInteger(1)(key=key)) == 0
  assert int(distributions.Poisson(0.0)(key=key)) == 0
  assert float(distributions.Normal(2.0, 0.0)(key=key)) == 2.0
  # composer's RandomState.uniform allows low > high: so do we.
  assert 1.0 < float(distributions.Uniform(2.0, 1.0)(key=key)) <= 2.0
  # Unbounded variation parameters cannot be checked at construction.
  distributions.Normal(0.0, distributions.Normal())


class _GroupedSwing(conftest.SwingTask):
  """The swing task with a flattened and a dict-valued observation group."""

  def observation_groups(self):
    group = composer.ObservationGroup
    return {
        'policy': group(keys=['tip'], flatten=True),
        'raw': group(keys=['tip']),
    }


@functools.lru_cache(maxsize=None)
def _brax_envs():
  """(ungrouped, grouped) swing environments that Brax can wrap."""
  options = composer.ExecutionOptions(auto_reset='same_step')
  return (
      conftest.make_swing_env(time_limit=0.05, options=options),
      composer.Environment(_GroupedSwing(), time_limit=0.05, options=options),
  )


@pytest.mark.parametrize(
    'obs_key, error, match',
    [
        ([], ValueError, r'obs_key=\[\] selects no observation.*Pass None'),
        (('tip', 'tip'), ValueError, r"obs_key=.*names \['tip'\] more than"),
        (3, TypeError, r'obs_key must be None, a string.*got 3'),
        (['tip', 4], TypeError, r'obs_key must be None, a string'),
        ('nope', ValueError, r"obs_key: no observation \['nope'\].*'tip'"),
    ],
)
def test_brax_env_refuses_a_bad_obs_key(obs_key, error, match):
  from mjx_composer.adapters import brax as brax_adapter  # pylint: disable=g-import-not-at-top

  with pytest.raises(error, match=match):
    brax_adapter.BraxEnv(_brax_envs()[0], obs_key=obs_key)


def test_brax_env_refuses_a_group_that_is_not_flattened():
  from mjx_composer.adapters import brax as brax_adapter  # pylint: disable=g-import-not-at-top

  grouped = _brax_envs()[1]
  for obs_key in (None, 'raw', ['policy', 'raw']):
    with pytest.raises(
        ValueError, match=r"\['raw'\] are not flattened.*flatten=True"
    ):
      brax_adapter.BraxEnv(grouped, obs_key=obs_key)
  assert brax_adapter.BraxEnv(grouped, obs_key='policy').observation_size == 3


def test_brax_env_default_obs_key_works_with_brax_networks():
  """Without groups, Brax's default networks (policy_obs_key='state') fit.

  Before, obs_key=None gave Brax a dict without 'state' and Brax's network
  factory failed with KeyError: 'state'.
  """
  from brax.training.agents.ppo import networks as ppo_networks  # pylint: disable=g-import-not-at-top
  from mjx_composer.adapters import brax as brax_adapter  # pylint: disable=g-import-not-at-top

  brax_env = brax_adapter.BraxEnv(_brax_envs()[0])
  assert brax_env.observation_size == 3
  with pytest.raises(KeyError, match='state'):  # The reference: Brax.
    ppo_networks.make_ppo_networks({'tip': (3,)}, brax_env.action_size)
  networks = ppo_networks.make_ppo_networks(
      brax_env.observation_size, brax_env.action_size
  )
  params = networks.policy_network.init(jax.random.key(0))
  obs = brax_env.reset(jax.random.key(1)).obs
  assert obs.shape == (3,)
  logits = networks.policy_network.apply(None, params, obs[None])
  assert logits.shape == (1, 2 * brax_env.action_size)


# -- HostEnvironment: seeds and failed initializations -----------------------


@pytest.mark.parametrize(
    'seed, error, match',
    [
        ('abc', TypeError, r"seed must be an int, got 'abc' \(str\).*seed=0"),
        (1.5, TypeError, r'seed must be an int, got 1.5 \(float\)'),
        (None, TypeError, r'seed must be an int, got None'),
        (True, TypeError, r'seed must be an int, got True'),
        (2**70, ValueError, r'seed must be in \[0, 2\*\*63\).*got 1180591'),
        (-1, ValueError, r'seed must be in \[0, 2\*\*63\).*got -1'),
    ],
)
@pytest.mark.parametrize('num_worlds', [None, 2])
def test_host_environment_refuses_a_bad_seed(seed, error, match, num_worlds):
  with pytest.raises(error, match=match):
    composer.HostEnvironment(
        _pendulum_environment(), num_worlds=num_worlds, seed=seed
    )


def test_host_environment_accepts_the_largest_seed():
  env = composer.HostEnvironment(_pendulum_environment(), seed=2**63 - 1)
  assert env.reset().first()


class _FlakyInitialization(composer.NullTask):
  """Fails an episode's initialization with probability `p` per attempt."""

  def __init__(self, p):
    arena = composer.Arena()
    arena.attach(conftest.Pendulum())
    super().__init__(arena)
    self.p = p

  def initialize_episode(self, physics, key):
    return physics.fail_initialization(jax.random.uniform(key) < self.p)


@functools.lru_cache(maxsize=None)
def _flaky_environment(p, attempts):
  return composer.Environment(
      _FlakyInitialization(p), time_limit=0.1, max_reset_attempts=attempts
  )


@pytest.mark.parametrize('num_worlds', [None, 3])
def test_host_reset_raises_when_every_attempt_fails(num_worlds):
  """composer's reset raises EpisodeInitializationError after its retries."""
  env = composer.HostEnvironment(
      _flaky_environment(1.0, 3), num_worlds=num_worlds
  )
  where = r' in world\(s\) \[0, 1, 2\]' if num_worlds else ''
  with pytest.raises(
      composer.EpisodeInitializationError,
      match=rf'all 3 attempt\(s\).*failed{where}.*max_reset_attempts',
  ):
    env.reset()


def test_host_reset_succeeds_when_a_retry_succeeds():
  env = composer.HostEnvironment(_flaky_environment(0.9, 200), num_worlds=3)
  env.reset()  # Each world fails all 200 attempts with probability 7e-10.
  failures = np.asarray(env.state.metrics['init_failures'])
  assert not np.any(np.asarray(env.state.metrics['init_failed']))
  assert failures.sum() > 0  # Retries happened, and one succeeded.


# -- sharding: arrays on other devices than the program's mesh ---------------

_SHARDING_SCRIPT = r"""
import json
import jax
import numpy as np
from mjx_composer.platform import sharding

d = jax.devices()
a, b = sharding.world_mesh(d[:2]), sharding.world_mesh(d[2:])
program = sharding.per_device(lambda states, actions: states + actions, a)
x = np.arange(12, dtype=np.float32).reshape(4, 3)
on = lambda mesh: sharding.put_worlds(x, mesh)
cases = {
    'states_of_another_mesh': (on(b), on(a)),
    'both_of_another_mesh': (on(b), on(b)),
    'actions_on_one_device': (on(a), jax.device_put(x, d[0])),
    'actions_on_every_device': (on(a), on(sharding.world_mesh(d))),
    'numpy_actions': (on(a), x),
    'placed': (on(a), on(a)),
}
out = {}
for name, args in cases.items():
  try:
    out[name] = np.asarray(program(*args)).tolist()
  except ValueError as error:
    out[name] = str(error)
try:
  program.lower(on(b), on(a))
  out['lower'] = 'lowered'
except ValueError as error:
  out['lower'] = str(error)
print(json.dumps(out))
"""


def test_a_program_refuses_arrays_of_another_mesh(tmp_path):
  """jax.jit said "Received incompatible devices", naming no fix."""
  out = conftest.run_script(
      _SHARDING_SCRIPT,
      None,
      tmp_path,
      env={'XLA_FLAGS': '--xla_force_host_platform_device_count=4'},
  )
  expected = (np.arange(12).reshape(4, 3) * 2).tolist()
  assert out['placed'] == expected
  assert out['numpy_actions'] == expected  # jax.jit moves numpy arrays.
  for name, where, devices in [
      ('states_of_another_mesh', r'args\[0\]', r'\[2, 3\]'),
      ('both_of_another_mesh', r'args\[0\]', r'\[2, 3\]'),
      ('actions_on_one_device', r'args\[1\]', r'\[0\]'),
      ('actions_on_every_device', r'args\[1\]', r'\[0, 1, 2, 3\]'),
      ('lower', r'args\[0\]', r'\[2, 3\]'),
  ]:
    assert re.search(
        rf'{where} is on devices {devices}, but this program runs on the '
        r'devices \[0, 1\] of its mesh: .*sharding.put_worlds',
        out[name],
    ), (name, out[name])


# -- the persistent compilation cache ----------------------------------------

_CACHE_SCRIPT = r"""
import json, sys, warnings
import jax
import jax.numpy as jnp

hits = []
jax.monitoring.register_event_listener(
    lambda event, **kwargs: hits.append(event)
    if event == '/jax/compilation_cache/cache_hits' else None)

from mjx_composer.platform import compilation_cache

with warnings.catch_warnings(record=True) as caught:
  warnings.simplefilter('always')
  path = compilation_cache.enable(sys.argv[1] and json.loads(sys.argv[1]),
                                  min_compile_time_secs=0.0)
  f = jax.jit(lambda x: jnp.sin(x) * 3.0 + jnp.cos(x) ** 2)
  f(jnp.arange(7.0)).block_until_ready()
print(json.dumps({'path': path, 'hits': len(hits),
                  'warnings': [str(w.message) for w in caught]}))
"""


def _cache_run(tmp_path, folder):
  return conftest.run_script(
      _CACHE_SCRIPT,
      str(folder),
      tmp_path,
      drop=('MJX_COMPOSER_CACHE_DIR', 'JAX_COMPILATION_CACHE_DIR'),
  )


@pytest.mark.parametrize(
    'mode, reason',
    [
        (0o777, 'can be written by everyone (mode 777)'),
        (0o1777, 'can be written by everyone (mode 1777)'),
        (0o770, 'can be written by its group (mode 770)'),
        (0o700, None),
        (0o755, None),
    ],
)
def test_unsafe_cache_folders_are_recognised(tmp_path, mode, reason):
  from mjx_composer.platform import compilation_cache  # pylint: disable=g-import-not-at-top

  tmp_path.chmod(mode)
  assert compilation_cache.unsafe_folder_reason(str(tmp_path)) == reason


def test_a_cache_folder_others_can_write_is_refused(tmp_path):
  folder = tmp_path / 'shared_cache'
  folder.mkdir()
  folder.chmod(0o777)
  out = _cache_run(tmp_path, folder)
  assert out['path'] is None
  assert not list(folder.iterdir())
  (message,) = [w for w in out['warnings'] if 'compilation cache' in w]
  assert re.search(
      rf'No persistent compilation cache: {re.escape(str(folder))} can be '
      r'written by everyone \(mode 777\), and JAX runs whatever a cache '
      r'entry holds.*chmod 700',
      message,
  ), message


def test_a_corrupted_cache_entry_is_removed_and_written_afresh(tmp_path):
  folder = tmp_path / 'cache'
  first = _cache_run(tmp_path, folder)
  assert first['path'] == str(folder) and first['hits'] == 0
  entries = sorted(folder.glob('*-cache'))
  assert entries
  for entry in entries:  # Writes cut short.
    entry.write_bytes(entry.read_bytes()[:100])
  repaired = _cache_run(tmp_path, folder)
  assert repaired['hits'] == 0
  removed = [
      w
      for w in repaired['warnings']
      if 'Removed the unreadable compilation' in w
  ]
  assert len(removed) == len(entries), repaired['warnings']
  assert all(any(e.name in w for w in removed) for e in entries)
  # Written afresh by the compilations, and loaded by the next process.
  assert all(e.stat().st_size > 100 for e in entries)
  again = _cache_run(tmp_path, folder)
  assert again['hits'] == len(entries) and not again['warnings']


# -- first use: composer's elliptic cones on models MJX cannot run them on ---


class _LimitedPole(conftest.SpecEntity):
  """A hinge with a range and a motor; `condim` adds a free box that can
  touch the world's floor with that contact dimension (None: no contacts)."""

  def _build(self, condim=None, name='pole'):
    spec = self._new_spec(name)
    body = spec.worldbody.add_body(name='link')
    body.add_joint(
        name='hinge',
        type=mujoco.mjtJoint.mjJNT_HINGE,
        range=[-0.3, 0.3],
        limited=mujoco.mjtLimited.mjLIMITED_TRUE,
    )
    body.add_geom(
        name='rod',
        size=[0.05, 0, 0],
        pos=[0, 0, 0.5],
        contype=0,
        conaffinity=0,
    )
    spec.add_actuator(
        name='motor',
        target='hinge',
        trntype=mujoco.mjtTrn.mjTRN_JOINT,
        gear=[20, 0, 0, 0, 0, 0],
    )
    if condim is not None:
      spec.worldbody.add_geom(
          name='floor',
          type=mujoco.mjtGeom.mjGEOM_PLANE,
          size=[1, 1, 0.1],
          condim=condim,
      )
      box = spec.worldbody.add_body(name='box', pos=[0.5, 0, 0.2])
      box.add_joint(name='drop', type=mujoco.mjtJoint.mjJNT_SLIDE)
      box.add_geom(
          name='box',
          type=mujoco.mjtGeom.mjGEOM_BOX,
          size=[0.05] * 3,
          condim=condim,
      )


def test_a_contact_free_model_with_a_joint_limit_runs_in_composers_arena():
  """MJX's elliptic solver failed ("Indexer must have integer or boolean
  type"); without contacts the cone changes nothing: compared with MuJoCo
  running the model as composed, elliptic cones and all."""
  arena = composer.Arena()
  arena.attach(_LimitedPole())
  env = composer.Environment(composer.NullTask(arena), time_limit=1.0)
  assert env.spec.option.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
  assert env.mj_model.opt.cone == mujoco.mjtCone.mjCONE_PYRAMIDAL
  state = jax.jit(env.reset)(jax.random.key(0))
  step = jax.jit(env.step)
  action = np.ones(1, np.float32)  # Drives the hinge into its limit.
  for _ in range(10):
    state = step(state, action)
  reference = env.spec.compile()  # The elliptic model, on the host.
  assert reference.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
  data = mujoco.MjData(reference)
  data.ctrl[:] = action
  for _ in range(10 * env.n_sub_steps):
    mujoco.mj_step(reference, data)
  assert data.qpos[0] > 0.29  # At the limit: its constraint was active.
  np.testing.assert_allclose(state.data.qpos, data.qpos, atol=1e-4)


def test_elliptic_cones_with_frictionless_contacts_say_what_to_change():
  arena = composer.Arena()
  arena.attach(_LimitedPole(condim=1))
  with pytest.raises(
      NotImplementedError,
      match=r'elliptic friction cones.*condim 1.*option.cone = '
      r'mujoco.mjtCone.mjCONE_PYRAMIDAL.*condim 3',
  ):
    composer.Environment(
        composer.NullTask(arena), options=composer.ExecutionOptions(impl='jax')
    )


# -- first use: a cold demo says what it compiles before compiling -----------


def test_demo_says_what_it_compiles_before_compiling(capsys, monkeypatch):
  from mjx_composer import cli  # pylint: disable=g-import-not-at-top
  from mjx_composer.tasks import registry  # pylint: disable=g-import-not-at-top

  before_compiling = []
  make_rollout = cli.make_rollout

  def recording_make_rollout(*args):
    rollout = make_rollout(*args)

    def first_call(*call_args):
      if not before_compiling:
        before_compiling.append(capsys.readouterr().out)
      return rollout(*call_args)

    return first_call

  monkeypatch.setattr(cli, 'make_rollout', recording_make_rollout)
  registry.register('swing_for_the_demo_test', conftest.SwingTask)
  try:
    assert (
        cli.demo(
            [
                '--task',
                'swing_for_the_demo_test',
                '--worlds',
                '2',
                '--steps',
                '2',
                '--chunk',
                '2',
                '--time-limit',
                '0.05',
            ]
        )
        == 0
    )
  finally:
    registry.unregister('swing_for_the_demo_test')
  (printed,) = before_compiling
  assert re.search(
      r'Compiling the reset of 2 worlds and a 2-step rollout \(seconds on a '
      r'GPU, minutes on a CPU; .*compilation cache',
      printed,
  ), printed
  assert 'Compiled reset' in capsys.readouterr().out
