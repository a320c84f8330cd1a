"""Timesteps and model options MJX cannot run are refused, saying the fix."""

import math
import warnings

import jax
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.model import model_checks
from mjx_composer import task as task_lib
from tests import conftest
from tests.package.bad_inputs import common

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
  arena = common.in_arena(common.Arm())
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
  arena = common.in_arena(common.Arm())
  arena.mjcf_model.option.noslip_iterations = 5
  with pytest.warns(
      model_checks.MjxIgnoredOptionWarning, match=r'noslip_iterations=5'
  ):
    composer.Environment(composer.NullTask(arena))


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


def test_shapes_mjx_cannot_collide_are_named_with_the_fix():
  """MJX fails sizing its contacts with only the two type numbers
  ("Collision function not found for geom types 5, 6")."""
  arena = composer.Arena()
  cylinder = composer.ModelWrapperEntity(mujoco.MjSpec())
  body = cylinder.mjcf_model.worldbody.add_body(name='drum')
  body.add_geom(
      name='drum_geom', type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[0.1, 0.1, 0]
  )
  arena.add_free_entity(cylinder)
  arena.mjcf_model.worldbody.add_geom(
      name='crate', type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.2, 0.2, 0.2]
  )
  with pytest.raises(
      NotImplementedError,
      match=r'no collision function.*mjGEOM_CYLINDER with mjGEOM_BOX: '
      r"'modelwrapperentity/drum_geom' with 'crate'.*capsule or box instead "
      r'of a cylinder.*<exclude>',
  ):
    composer.Environment(
        composer.NullTask(arena), options=composer.ExecutionOptions(impl='jax')
    )
