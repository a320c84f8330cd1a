"""The dm_control suite humanoid as a `Robot`, from MuJoCo Playground's XML.

`Humanoid` loads `assets/humanoid/humanoid.xml`: dm_control's suite humanoid
(21 hinge joints driven by 21 torque motors, capsule and sphere geoms) with
the changes MuJoCo Playground 0.2.0 made for MJX, the very file Playground's
`HumanoidWalk` loads (see `assets/humanoid/NOTICE`; Apache-2.0). The file is
vendored unchanged; `_build` adapts it to composition, in code:

* the XML's floor is removed: the arena provides the ground;
* the torso's freejoint is removed and the torso moved to the entity's
  origin: attach the humanoid with `arena.add_free_entity(humanoid)` (as
  composer's walkers), and put the frame at `humanoid.initial_height`. Then
  the composed `qpos`/`qvel` have the XML's layout and `qpos0`, the free
  joint's position is the torso's, and every body keeps its mass;
* the solver options and MJX's contact limits the XML sets
  (`simulation_options`) must be the root's: options of an attached spec
  are not carried into the composed model (MjSpec keeps the root's and warns
  where they differ), and MJX reads its limits from unprefixed numerics.
  `apply_simulation_options(root_spec)` writes them on the root, as tasks
  built on this robot do (see `simulation_options`);
* `collisions='feet'` (the default: 'all', the XML's) keeps the contacts
  of the foot capsules with the ground only (contype 0, conaffinity 1: not
  with each other nor the rest of the body), as a robot on a height field
  wants them: MJX collides each geom with the grid cells around it at every
  physics step (`locomotion.terrain`).

    arena = arenas.Floor()
    humanoid = Humanoid()
    frame = arena.add_free_entity(humanoid)
    frame.pos = (0.0, 0.0, humanoid.initial_height)
    humanoid.apply_simulation_options(arena.mjcf_model)
"""

import pathlib

import jax.numpy as jnp
import mujoco

from mjx_composer import define
from mjx_composer.observation import observable
from mjx_composer.suite.entities import simulation_options as options_lib
from mjx_composer.suite.entities import spec_robot

ASSET_DIR = pathlib.Path(__file__).parent / 'assets' / 'humanoid'
XML_PATH = ASSET_DIR / 'humanoid.xml'
# Playground's order of the extremities observation: per side, hand and foot.
EXTREMITIES = ('left_hand', 'left_foot', 'right_hand', 'right_foot')
# The two capsules of each foot, right foot first.
FOOT_GEOMS = (
    'right_right_foot',
    'left_right_foot',
    'left_left_foot',
    'right_left_foot',
)
COLLISIONS = ('all', 'feet')


class HumanoidObservables(observable.Observables):
  """Proprioception of a `Humanoid`: what Playground's HumanoidWalk observes.

  Besides Playground's (joint angles, head height, extremities in the torso
  frame, torso vertical orientation, centre-of-mass velocity and the
  velocities of all degrees of freedom), the torso's IMU-style sensors:
  velocimeter, gyro and accelerometer at the torso's `root` site.
  """

  @define.observable
  def joint_positions(self):
    return observable.MJCFFeature('qpos', self._entity.joints)

  @define.observable
  def joint_velocities(self):
    return observable.MJCFFeature('qvel', self._entity.joints)

  @define.observable
  def root_velocity(self):
    """The free joint's qvel: world linear, torso-frame angular velocity."""
    return observable.Generic(self._entity.root_velocity)

  @define.observable
  def head_height(self):
    return observable.MJCFFeature('xpos', self._entity.head)[2:]

  @define.observable
  def extremities(self):
    """Hands and feet relative to the torso, in its frame (12,)."""
    return observable.Generic(self._entity.extremities)

  @define.observable
  def torso_vertical(self):
    """The world's z axis in the torso frame (the last row of its flat
    xmat)."""
    return observable.MJCFFeature('xmat', self._entity.torso)[6:]

  @define.observable
  def center_of_mass_velocity(self):
    return observable.MJCFFeature('sensordata', self._entity.com_velocity)

  @define.observable
  def torso_velocity(self):
    return observable.MJCFFeature('sensordata', self._entity.velocimeter)

  @define.observable
  def gyro(self):
    return observable.MJCFFeature('sensordata', self._entity.gyro)

  @define.observable
  def accelerometer(self):
    return observable.MJCFFeature('sensordata', self._entity.accelerometer)

  @define.observable
  def actuator_forces(self):
    return observable.MJCFFeature('force', self._entity.actuators)


class Humanoid(spec_robot.SpecRobot):
  """The dm_control suite humanoid, as MuJoCo Playground's MJX XML has it.

  Its `joints` are the 21 hinges in the XML's (qpos) order; the actuators
  (the action) come in the XML's actuator order, which is not the same:
  `abdomen_y` drives the second joint, for one.

  Args:
    name: the entity's name (its compiled names' prefix).
    collisions: 'all' (the XML's contacts, the body's own pairs included)
      or 'feet' (the foot capsules against the ground only).
  """

  def _build(self, name='humanoid', collisions='all'):
    if collisions not in COLLISIONS:
      raise ValueError(
          f'Humanoid: collisions must be one of {COLLISIONS}, got '
          f'{collisions!r}.'
      )
    spec = mujoco.MjSpec.from_file(str(XML_PATH))
    spec.modelname = name
    spec.delete(spec.geom('floor'))
    torso = spec.body('torso')
    self._initial_height = spec_robot.free_at_origin(spec, torso)
    self._simulation_options = options_lib.take(spec)
    self._spec = spec
    self._torso = torso
    self._head = spec.body('head')
    self._extremity_bodies = tuple(spec.body(n) for n in EXTREMITIES)
    # Joints and actuators in the XML's order (the action's order).
    self._joints = tuple(
        j for j in spec.joints if j.type == mujoco.mjtJoint.mjJNT_HINGE
    )
    self._actuators = tuple(spec.actuators)
    self._root_site = spec.site('root')
    self._com_velocity = spec.sensor('torso_subtreelinvel')
    self._velocimeter = spec.sensor('torso_vel')
    self._gyro = spec.sensor('torso_gyro')
    self._accelerometer = spec.sensor('torso_accel')
    self._foot_geoms = tuple(spec.geom(n) for n in FOOT_GEOMS)
    if collisions == 'feet':
      feet = set(id(g) for g in self._foot_geoms)
      for geom in spec.geoms:
        # Collides with geoms whose contype has bit 0 (the ground).
        geom.contype, geom.conaffinity = (0, 1) if id(geom) in feet else (0, 0)

  def _build_observables(self):
    return HumanoidObservables(self)

  # -- elements ------------------------------------------------------------

  @property
  def torso(self):
    return self._torso

  @property
  def head(self):
    return self._head

  @property
  def foot_geoms(self):
    """The feet's capsules, `FOOT_GEOMS` order."""
    return self._foot_geoms

  @property
  def extremity_bodies(self):
    """Hand and foot bodies, in `EXTREMITIES` order."""
    return self._extremity_bodies

  @property
  def root_site(self):
    """The torso's force-torque site, where the IMU sensors sit."""
    return self._root_site

  @property
  def com_velocity(self):
    """The torso subtree's linear velocity sensor (world frame)."""
    return self._com_velocity

  @property
  def velocimeter(self):
    return self._velocimeter

  @property
  def gyro(self):
    return self._gyro

  @property
  def accelerometer(self):
    return self._accelerometer

  @property
  def initial_height(self):
    """The torso's height in the XML (1.5 m): where to put the free frame."""
    return self._initial_height

  # -- simulation options --------------------------------------------------

  @property
  def simulation_options(self):
    """The XML's solver settings and MJX contact limits (a dict)."""
    return dict(self._simulation_options)

  def apply_simulation_options(self, root_spec):
    """Writes `simulation_options` on the root (arena) spec."""
    options_lib.put(root_spec, self._simulation_options)

  # -- readings (device) ---------------------------------------------------

  def root_velocity(self, physics):
    """The free joint's qvel (6,); needs `arena.add_free_entity(self)`."""
    if self.freejoint is None:
      raise ValueError(
          'root_velocity needs a free humanoid: attach it with '
          'arena.add_free_entity(humanoid).'
      )
    return physics.bind(self.freejoint).qvel

  def extremities(self, physics):
    """Hand and foot positions relative to the torso, torso frame (12,)."""
    torso = physics.bind(self._torso)
    limbs = physics.bind(list(self._extremity_bodies)).xpos
    return jnp.ravel((limbs - torso.xpos) @ torso.xmat.reshape(3, 3))

  def upright(self, physics):
    """The torso z axis' projection on the world's z axis (xmat[8])."""
    return physics.bind(self._torso).xmat[8]

  def head_height(self, physics):
    return physics.bind(self._head).xpos[2]
