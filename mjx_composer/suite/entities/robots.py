"""A three-joint arm on a fixed pedestal, built in code with MjSpec."""

import mujoco

from mjx_composer import define
from mjx_composer.observation import observable
from mjx_composer.suite.entities import spec_robot
from mjx_composer.suite.entities.manipulators import base as manipulators


class ArmObservables(observable.Observables):
  """Proprioception and the hand position of an `Arm`."""

  @define.observable
  def joint_positions(self):
    return observable.MJCFFeature('qpos', self._entity.joints)

  @define.observable
  def joint_velocities(self):
    return observable.MJCFFeature('qvel', self._entity.joints)

  @define.observable
  def hand_position(self):
    return observable.MJCFFeature('xpos', self._entity.hand)

  @define.observable
  def actuator_forces(self):
    return observable.MJCFFeature('force', self._entity.actuators)


class Arm(spec_robot.SpecRobot, manipulators.RobotArm):
  """A three-joint arm: base yaw, shoulder and elbow pitch, torque motors.

  A `RobotArm` whose `wrist_site` is its `hand` site: three joints place
  the hand's position (not its orientation) with `set_site_to_xpos`.

  Args:
    name: entity name (the prefix of its compiled names).
    upper_length, lower_length: link lengths in metres.
    rgba: link colour.
  """

  def _build(
      self,
      name='arm',
      upper_length=0.35,
      lower_length=0.3,
      rgba=(0.8, 0.5, 0.2, 1.0),
  ):
    spec = mujoco.MjSpec()
    spec.modelname = name
    # Joint ranges below are in radians; MjSpec's compiler defaults to degrees.
    spec.compiler.degree = False
    hinge = mujoco.mjtJoint.mjJNT_HINGE
    capsule = mujoco.mjtGeom.mjGEOM_CAPSULE
    # The pedestal is fixed to the parent; yaw and shoulder share a body.
    # It is a box, not a cylinder: MJX collides cylinders with capsules and
    # spheres through an iterative SDF search, which costs more to compile
    # and to run than all the arm's other contacts, and not with boxes at all.
    base = spec.worldbody.add_body(name='base', pos=[0, 0, 0.05])
    base.add_geom(
        name='base',
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[0.06, 0.06, 0.05],
        rgba=[0.3, 0.3, 0.3, 1],
    )
    upper = base.add_body(name='upper', pos=[0, 0, 0.06])
    yaw = upper.add_joint(
        name='yaw', type=hinge, axis=[0, 0, 1], damping=1.0, armature=0.05
    )
    shoulder = upper.add_joint(
        name='shoulder',
        type=hinge,
        axis=[0, 1, 0],
        range=[-1.6, 1.6],
        limited=True,
        damping=1.0,
        armature=0.05,
    )
    upper.add_geom(
        name='upper',
        type=capsule,
        size=[0.03, 0, 0],
        fromto=[0, 0, 0, 0, 0, upper_length],
        rgba=rgba,
    )
    lower = upper.add_body(name='lower', pos=[0, 0, upper_length])
    elbow = lower.add_joint(
        name='elbow',
        type=hinge,
        axis=[0, 1, 0],
        range=[-2.5, 2.5],
        limited=True,
        damping=0.5,
        armature=0.05,
    )
    lower.add_geom(
        name='lower',
        type=capsule,
        size=[0.025, 0, 0],
        fromto=[0, 0, 0, 0, 0, lower_length],
        rgba=rgba,
    )
    # The upper link's capsule starts inside the pedestal. MuJoCo's parent
    # filter does not apply here (the pedestal is welded to the world), so
    # exclude the pair explicitly.
    spec.add_exclude(bodyname1='base', bodyname2='upper')
    self._hand = lower.add_site(
        name='hand',
        pos=[0, 0, lower_length],
        size=[0.03, 0, 0],
        rgba=[0.9, 0.9, 0.1, 1],
    )
    self._joints = (yaw, shoulder, elbow)
    self._actuators = tuple(
        spec.add_actuator(
            name=joint.name,
            target=joint.name,
            trntype=mujoco.mjtTrn.mjTRN_JOINT,
            gear=[gear] + [0] * 5,
            ctrlrange=[-1, 1],
            ctrllimited=True,
        )
        for joint, gear in zip(self._joints, (1.5, 3.0, 2.0))
    )
    self._spec = spec

  def _build_observables(self):
    return ArmObservables(self)

  @property
  def hand(self):
    """The site at the tip of the arm."""
    return self._hand

  @property
  def wrist_site(self):
    """The `hand` site (the arm has no separate hand entity)."""
    return self._hand
