"""The Unitree Go1 quadruped as a `Robot`, from MuJoCo Menagerie's model.

`Go1` loads `assets/go1/go1.xml`, Menagerie's `unitree_go1/go1.xml`
unchanged (BSD-3-Clause, see `assets/go1/NOTICE`): a trunk and four legs of
three hinges each, driven by 12 position actuators. `_build` makes these
changes in code, each for a reason:

* Composition. The trunk's freejoint is removed and the trunk moved to the
  entity's origin: attach the robot with `arena.add_free_entity(go1)` and put
  the frame at `go1.home_height`. The `home` keyframe is read into
  `home_joint_positions` / `home_height` and removed (an attached spec's
  keyframe would not match the composed model's `qpos`).
* No meshes. Menagerie's visual meshes are not vendored (~10 MB, and
  `mujoco-menagerie` downloads them at run time): the mesh geoms and assets
  are removed and the collision primitives are drawn instead (group 2).
  Bodies have explicit inertials, so the dynamics do not change.
* Contacts for MJX (`collisions`). 'feet': as MuJoCo Playground's
  `go1_mjx_feetonly.xml`, only the feet collide, and only with the ground
  (contype 0, conaffinity 1: not with each other nor the rest of the robot);
  on a height field each foot costs a 2 x 2 cell patch, where the trunk's
  box would cost dozens (see `locomotion.terrain.generator`), so a fall is
  read from the trunk's pose (`trunk_below`), not from a contact.
  'minimal' (the default): the trunk's box collides with the ground too,
  so a fallen robot lies on the floor instead of sinking through it (a
  cheap box-plane pair) and `trunk_contact` can report falls.
  Feet keep Menagerie's priority, friction and soft `solimp`, but use
  `condim=3` instead of 6 (torsional and rolling friction would add six
  constraint rows per foot contact), and no contact margin (Menagerie's
  1 mm; MJX refuses margins against height fields). `collisions='full'` keeps Menagerie's
  geoms (cylinders included: MJX collides them with planes, not with height
  fields).
* Solver options for MJX (`simulation_options`, written on the root by
  `apply_simulation_options`): Playground's, which MJX trains this robot
  with: timestep 4 ms, Euler with `eulerdamp` disabled, pyramidal cones,
  `impratio` 1, one Newton iteration and 5 line-search iterations.
  Menagerie's elliptic cones with `impratio=100` need many more solver
  iterations to converge, each a dense factorization on every world.
* Optional PD gains: `kp` (position actuators' gain) and `kd` (joint
  damping), e.g. Playground's `kp=35, kd=0.5`; Menagerie's by default.
* Sensors (Menagerie's model has none), Playground's names: at the `imu`
  site `gyro`, `local_linvel` (velocimeter), `accelerometer`, `upvector`
  (frame z axis), `global_linvel`, `global_angvel`; per foot site
  `<foot>_global_linvel`; per foot geom a contact sensor `<foot>_contact`
  ("found", any contact partner), and `trunk_contact` for the trunk's box.
"""

import pathlib

import jax.numpy as jnp
import mujoco
import numpy as np

from mjx_composer import define
from mjx_composer.observation import observable
from mjx_composer.suite.entities import simulation_options as options_lib
from mjx_composer.suite.entities import spec_robot

ASSET_DIR = pathlib.Path(__file__).parent / 'assets' / 'go1'
XML_PATH = ASSET_DIR / 'go1.xml'
FEET = ('FR', 'FL', 'RR', 'RL')
COLLISIONS = ('feet', 'minimal', 'full')
# Playground's MJX settings for this robot (go1_mjx_feetonly.xml).
MJX_OPTIONS = {
    'timestep': 0.004,
    'integrator': mujoco.mjtIntegrator.mjINT_EULER,
    'cone': mujoco.mjtCone.mjCONE_PYRAMIDAL,
    'impratio': 1.0,
    'iterations': 1,
    'ls_iterations': 5,
    'disableflags': int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP),
}
_SITE = mujoco.mjtObj.mjOBJ_SITE
_GEOM = mujoco.mjtObj.mjOBJ_GEOM
_COLLISION_RGBA = (0.35, 0.37, 0.42, 1.0)
_FOOT_RGBA = (0.1, 0.1, 0.1, 1.0)
# A contact sensor's intprm: data="found", reduce="mindist", num=1.
_CONTACT_FOUND = (1, 1, 1)


class Go1Observables(observable.Observables):
  """Proprioception of a `Go1`: joints, IMU, feet (Playground's signals)."""

  @define.observable
  def joint_positions(self):
    return observable.MJCFFeature('qpos', self._entity.joints)

  @define.observable
  def joint_velocities(self):
    return observable.MJCFFeature('qvel', self._entity.joints)

  @define.observable
  def gyro(self):
    return observable.MJCFFeature('sensordata', self._entity.sensor('gyro'))

  @define.observable
  def local_linvel(self):
    return observable.MJCFFeature(
        'sensordata', self._entity.sensor('local_linvel')
    )

  @define.observable
  def accelerometer(self):
    return observable.MJCFFeature(
        'sensordata', self._entity.sensor('accelerometer')
    )

  @define.observable
  def gravity(self):
    """Unit gravity in the IMU frame (Playground's projected gravity)."""
    return observable.Generic(self._entity.gravity)

  @define.observable
  def upvector(self):
    return observable.MJCFFeature('sensordata', self._entity.sensor('upvector'))

  @define.observable
  def global_linvel(self):
    return observable.MJCFFeature(
        'sensordata', self._entity.sensor('global_linvel')
    )

  @define.observable
  def global_angvel(self):
    return observable.MJCFFeature(
        'sensordata', self._entity.sensor('global_angvel')
    )

  @define.observable
  def foot_contacts(self):
    """1 where a foot touches anything, in `FEET` order (4,)."""
    return observable.Generic(
        lambda physics: self._entity.foot_contacts(physics).astype(jnp.float32)
    )

  @define.observable
  def foot_velocities(self):
    """World linear velocities of the foot sites, flattened (12,)."""
    return observable.Generic(
        lambda physics: jnp.ravel(self._entity.foot_velocities(physics))
    )

  @define.observable
  def foot_positions(self):
    return observable.MJCFFeature('xpos', self._entity.foot_sites)

  @define.observable
  def actuator_forces(self):
    return observable.MJCFFeature('force', self._entity.actuators)


class Go1(spec_robot.SpecRobot):
  """Unitree Go1 from MuJoCo Menagerie, set up for MJX (module docstring).

  Its `joints` are the 12 leg hinges, in the actuators' order (FR, FL, RR,
  RL legs).

  Args:
    name: the entity's name (its compiled names' prefix).
    collisions: 'feet' (the feet against the ground), 'minimal' (the feet
      and the trunk's box against the ground) or 'full' (Menagerie's
      collision geoms, the robot's own pairs included).
    kp: position gain of every actuator (Menagerie: 100), or None.
    kd: damping of every leg joint (Menagerie: 1 abduction, 2 others), or
      None.
  """

  def _build(self, name='go1', collisions='minimal', kp=None, kd=None):
    if collisions not in COLLISIONS:
      raise ValueError(
          f'collisions must be one of {COLLISIONS}, got {collisions!r}.'
      )
    spec = mujoco.MjSpec.from_file(str(XML_PATH))
    spec.modelname = name
    # Menagerie's elliptic cone and impratio give way to MJX_OPTIONS, on
    # this spec too, so that a root with them composes without warnings.
    options_lib.put(spec, MJX_OPTIONS)
    _remove_meshes(spec)
    trunk = spec.body('trunk')
    spec_robot.free_at_origin(spec, trunk)
    home = spec.key('home')
    home_qpos = np.array(list(home.qpos))
    self._home_height = float(home_qpos[2])
    self._home_joint_positions = home_qpos[7:].astype(np.float32)
    spec.delete(home)

    self._spec = spec
    self._trunk = trunk
    self._joints = tuple(
        j for j in spec.joints if j.type == mujoco.mjtJoint.mjJNT_HINGE
    )
    self._actuators = tuple(spec.actuators)
    self._imu = spec.site('imu')
    self._foot_geoms = tuple(spec.geom(f) for f in FEET)
    self._foot_sites = tuple(spec.site(f) for f in FEET)
    # The trunk's first collision geom, Menagerie's main box (unnamed).
    self._trunk_geom = next(
        g for g in trunk.geoms if g.type == mujoco.mjtGeom.mjGEOM_BOX
    )
    self._trunk_geom.name = 'trunk_collision'
    self._collisions = collisions
    self._set_up_collisions(collisions)
    if kp is not None:
      for actuator in self._actuators:
        actuator.gainprm[0] = kp
        actuator.biasprm[1] = -kp
    if kd is not None:
      for joint in self._joints:
        # MjSpec's damping is a polynomial; its first entry is MJCF's.
        joint.damping = [kd] + list(joint.damping)[1:]
    self._sensors = self._add_sensors()

  def _set_up_collisions(self, collisions):
    for geom in self._spec.geoms:
      geom.group = 2
      geom.rgba = _COLLISION_RGBA
      geom.material = ''
    for geom in self._foot_geoms:
      geom.rgba = _FOOT_RGBA
    if collisions == 'full':
      return
    ground_only = self._foot_geoms
    if collisions == 'minimal':
      ground_only += (self._trunk_geom,)
    ground_only = set(id(g) for g in ground_only)
    for geom in self._spec.geoms:
      if id(geom) in ground_only:
        # Collides with geoms whose contype has bit 0 (the ground), never
        # with each other.
        geom.contype, geom.conaffinity = 0, 1
      else:
        geom.contype, geom.conaffinity = 0, 0
    for geom in self._foot_geoms:
      geom.condim = 3
    for geom in self._spec.geoms:
      # MJX refuses contact margins against height fields (Menagerie sets
      # 1 mm; Playground's MJX model none).
      geom.margin = 0.0

  def _add_sensors(self):
    spec = self._spec
    sensors = {}

    def add(name, sensor_type, objtype, objname, **kwargs):
      sensors[name] = spec.add_sensor(
          name=name,
          type=sensor_type,
          objtype=objtype,
          objname=objname,
          **kwargs,
      )

    types = mujoco.mjtSensor
    add('gyro', types.mjSENS_GYRO, _SITE, 'imu')
    add('local_linvel', types.mjSENS_VELOCIMETER, _SITE, 'imu')
    add('accelerometer', types.mjSENS_ACCELEROMETER, _SITE, 'imu')
    add('upvector', types.mjSENS_FRAMEZAXIS, _SITE, 'imu')
    add('global_linvel', types.mjSENS_FRAMELINVEL, _SITE, 'imu')
    add('global_angvel', types.mjSENS_FRAMEANGVEL, _SITE, 'imu')
    for foot in FEET:
      add(f'{foot}_global_linvel', types.mjSENS_FRAMELINVEL, _SITE, foot)
    for foot in FEET:
      add(
          f'{foot}_contact',
          types.mjSENS_CONTACT,
          _GEOM,
          foot,
          intprm=list(_CONTACT_FOUND),
      )
    add(
        'trunk_contact',
        types.mjSENS_CONTACT,
        _GEOM,
        'trunk_collision',
        intprm=list(_CONTACT_FOUND),
    )
    return sensors

  def _build_observables(self):
    return Go1Observables(self)

  # -- elements ------------------------------------------------------------

  @property
  def trunk(self):
    return self._trunk

  @property
  def collisions(self):
    """Which geoms collide: 'feet', 'minimal' or 'full' (`Go1`'s argument)."""
    return self._collisions

  @property
  def trunk_geom(self):
    """The trunk's box, the trunk's geom that collides in 'minimal' mode."""
    return self._trunk_geom

  @property
  def imu(self):
    return self._imu

  @property
  def foot_geoms(self):
    return self._foot_geoms

  @property
  def foot_sites(self):
    return self._foot_sites

  def sensor(self, name):
    """One of the sensors the module docstring lists, by its short name."""
    return self._sensors[name]

  # -- defaults ------------------------------------------------------------

  @property
  def home_joint_positions(self):
    """Menagerie's `home` keyframe joint angles (12,), standing."""
    return self._home_joint_positions.copy()

  @property
  def home_height(self):
    """The trunk's height in the `home` keyframe (0.27 m)."""
    return self._home_height

  @property
  def simulation_options(self):
    return dict(MJX_OPTIONS)

  def apply_simulation_options(self, root_spec):
    """Writes `simulation_options` on the root (arena) spec."""
    options_lib.put(root_spec, MJX_OPTIONS)

  # -- readings (device) ---------------------------------------------------

  def _sensordata(self, physics, name):
    return physics.bind(self._sensors[name]).sensordata

  def gyro(self, physics):
    return self._sensordata(physics, 'gyro')

  def local_linvel(self, physics):
    return self._sensordata(physics, 'local_linvel')

  def upvector(self, physics):
    return self._sensordata(physics, 'upvector')

  def global_linvel(self, physics):
    return self._sensordata(physics, 'global_linvel')

  def global_angvel(self, physics):
    return self._sensordata(physics, 'global_angvel')

  def gravity(self, physics):
    """World gravity's direction in the IMU frame, `xmat.T @ (0, 0, -1)`."""
    return -physics.bind(self._imu).xmat[6:]

  def foot_velocities(self, physics):
    """World linear velocities of the foot sites (4, 3), `FEET` order."""
    return jnp.stack(
        [self._sensordata(physics, f'{foot}_global_linvel') for foot in FEET]
    )

  def foot_contacts(self, physics):
    """Whether each foot touches anything (4,) bool, `FEET` order."""
    found = jnp.concatenate(
        [self._sensordata(physics, f'{foot}_contact') for foot in FEET]
    )
    return found > 0

  def foot_heights(self, physics):
    """World z of the foot sites (4,)."""
    return physics.bind(list(self._foot_sites)).xpos[:, 2]

  def trunk_contact(self, physics):
    """Whether the trunk's box touches anything (a fall, in 'minimal')."""
    return self._sensordata(physics, 'trunk_contact')[0] > 0

  def trunk_below(self, physics, ground_height):
    """Whether the trunk's box reaches below `ground_height` (a scalar).

    Its lowest corner, from the trunk's pose and the box's half-sizes,
    against the ground's height below the trunk: the fall that
    `trunk_contact` reports where the box collides ('minimal'), read from
    the pose where it does not ('feet').
    """
    geom = physics.bind(self._trunk_geom)
    rotation = jnp.reshape(geom.xmat, (3, 3))
    reach = jnp.sum(jnp.abs(rotation[2]) * geom.size)
    return geom.xpos[2] - reach < ground_height


def _remove_meshes(spec):
  """Deletes mesh geoms and mesh assets (the meshes are not vendored)."""
  for geom in list(spec.geoms):
    if geom.type == mujoco.mjtGeom.mjGEOM_MESH:
      spec.delete(geom)
  for mesh in list(spec.meshes):
    spec.delete(mesh)
