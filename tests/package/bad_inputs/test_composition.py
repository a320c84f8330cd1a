"""Composition never drops an element: a dangling reference is refused."""

import mujoco
import pytest

import mjx_composer as composer
from tests.package.bad_inputs import common

_OBJ = mujoco.mjtObj

# -- 1. composition never drops an element ------------------------------------


def test_valid_composition_keeps_every_element():
  arena = common.in_arena(common.Arm(edit=_typo_sensor_fixed))
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
    common.Arm(edit=common.typo_actuator).compose()


def test_child_actuator_typo_raises():
  with pytest.raises(
      ValueError,
      match=(
          r"Actuator 'arm/motor' targets joint 'arm/shoulderr', which does not"
          r" exist in the composed model: fix the target name in entity 'arm'"
      ),
  ):
    common.in_arena(common.Arm(edit=common.typo_actuator)).compose()


def test_root_sensor_typo_raises():
  with pytest.raises(
      ValueError,
      match=r"Sensor 'touch' is attached to site 'tipp'.*fix the sensor's "
      r"objname in entity 'arm'.*did you mean 'tip'",
  ):
    common.Arm(edit=common.typo_sensor).compose()


def test_child_sensor_typo_raises():
  with pytest.raises(
      ValueError,
      match=r"Sensor 'arm/touch' is attached to site 'arm/tipp'.*fix the "
      r"sensor's objname in entity 'arm'",
  ):
    common.in_arena(common.Arm(edit=common.typo_sensor)).compose()


def test_grandchild_typo_names_the_full_path():
  hand = common.Arm(edit=common.typo_actuator, name='hand')
  arm = common.Arm()
  arm.attach(hand)
  with pytest.raises(
      ValueError,
      match=r"Actuator 'arm/hand/motor' targets joint 'arm/hand/shoulderr'.*"
      r"fix the target name in entity 'hand'",
  ):
    common.in_arena(arm).compose()


def test_every_dropped_element_is_reported():
  def two_typos(spec):
    common.typo_actuator(spec)
    common.typo_sensor(spec)

  with pytest.raises(ValueError, match=r'would drop 2 elements') as error:
    common.in_arena(common.Arm(edit=two_typos)).compose()
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
    common.in_arena(common.Arm(edit=edit)).compose()


def test_reference_into_a_child_entity_is_kept():
  # Composer lets an entity refer to the elements of entities attached below
  # it by full name; composition adds such elements after the attach.
  arena = common.in_arena(common.Arm())
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
  arena = common.in_arena(common.Arm())
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
  arena = common.in_arena(common.Arm())
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
  assert common.Arm(edit=world_sensor).compose()[0].compile().nsensor == 1
  with pytest.raises(
      ValueError,
      match=r"Sensor 'arm/frame' is attached to the worldbody of entity "
      r"'arm'.*make it refer to a body inside entity 'arm'",
  ):
    common.in_arena(common.Arm(edit=world_sensor)).compose()


def test_environment_build_raises_on_a_dropped_element():
  task = composer.NullTask(
      common.in_arena(common.Arm(edit=common.typo_actuator))
  )
  with pytest.raises(ValueError, match=r"fix the target name in entity 'arm'"):
    composer.Environment(task)
