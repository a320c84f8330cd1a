"""`Physics`: one world's model, data and task state, with dm_control-style access.

A `Physics` is a pytree (a `flax.struct` dataclass) that hooks, observables and
rewards receive instead of dm_control's stateful `mjcf.Physics`. Reads look like
dm_control::

    physics.bind(hand_site).xpos              # (3,)
    physics.bind([j1, j2]).qpos               # (2,)
    physics.named.data.qpos['arm/shoulder']   # (1,)
    physics.named.model.body_mass[['arm/upper', 'arm/lower']]

and writes are functional: they return a new `Physics`::

    physics = physics.bind(joint).set(qpos=0.3)
    physics = physics.named.data.set('qvel', 'arm/shoulder', 0.0)

Elements are MjSpec handles (`mujoco.MjsBody`, `MjsGeom`, `MjsSite`, `MjsJoint`,
`MjsActuator`, `MjsSensor`, `MjsTendon`, `MjsCamera`, `MjsLight`, `MjsEquality`)
taken from an entity's own spec, or fully qualified names. They are resolved to
static integer indices while tracing, through the `ElementIndex` built once when
the environment compiles; nothing on the device looks a name up.

Shapes are dm_control's: `physics.bind(...)` and `physics.named` give the
rotation matrices `xmat`, `ximat`, `geom_xmat`, `site_xmat` and `cam_xmat` as
flat 9-vectors (`(9,)` for one element, `(n, 9)` for a list), as
`dm_control.mujoco.Physics.bind` does; `physics.data` is the raw `mjx.Data`,
whose matrices are `(n, 3, 3)`.

Fields that MJX computes only when a sensor needs them (`subtree_linvel`,
`subtree_angmom`: `mjx.subtree_vel`; `cacc`, `cfrc_int`, `cfrc_ext`:
`mjx.rne_postconstraint`) are computed from the data when read through a
binding, so they hold what MuJoCo's `mj_forward` followed by
`mj_subtreeVel` / `mj_rnePostConstraint` gives on the same state.

dm_control's bindings run `mj_forward` lazily: a read after a write of
`qpos`, `qvel`, `act`, `ctrl`, `qfrc_applied`, `xfrc_applied` or a model field
(but the visual ones, such as `rgba`) sees the new state. Here a binding read
of a derived quantity after such a write, with no forward pass between:

* in the `initialize_episode` hooks (`forward_stale_reads`), reads it from the
  stage of the forward pass that computes it (kinematics for positions, the
  full pass otherwise), as composer's reset context does; the hooks start
  from the reset's state, whose positions are computed and whose velocities
  and sensors are not, nor, where the episode's masses vary, its centres of
  mass and composite inertias (`mark_written`);
* in the step hooks, raises at trace time (`StaleReadError`): there an
  unseen forward pass would add a second copy of the physics to every
  control step. Call `physics.forward()` (or `physics.kinematics()`)
  yourself.

Where things live: `world` holds the `Physics` class; `world_fields` what the
runtime carries of a world (`WorldFields`, `PhysicsCarry`); `bindings` what
`physics.bind(...)` and `physics.named` read and write.
"""

from mjx_composer.physics import bindings
from mjx_composer.physics.bindings import Binding
from mjx_composer.physics.bindings import EmptyBinding
from mjx_composer.physics.bindings import FLAT_MATRIX_FIELDS
from mjx_composer.physics.bindings import ON_DEMAND_FIELDS
from mjx_composer.physics.bindings import StaleReadError
from mjx_composer.physics.bindings import STATE_INPUT_FIELDS
from mjx_composer.physics.world import Physics
from mjx_composer.physics.world import ReadOnlyPhysicsError
from mjx_composer.physics.world_fields import changed_model_fields
from mjx_composer.physics.world_fields import PhysicsCarry
from mjx_composer.physics.world_fields import WorldFields
