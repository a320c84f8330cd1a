"""What a varied attribute makes the compiler recompute (`Effect`).

Each record of the attribute catalogue (`attributes.CATALOGUE`) names its
effects. The planner (`planner.ModelCompiler`) combines the effects of all
bound attributes, statically, into what runs on the device; the structure
checks (`structure`) use them to find what a variation would change.

Besides its own effects, an attribute writes the compiled fields it maps to
(`attributes.Attribute.fields`). Derived quantities follow from the
combination:

* inertia: the bodies whose inertial is recomputed (`inertia`) are those
  with a `BODY_INERTIAL` attribute, those that infer their inertial from a
  geom with `GEOM_INERTIA`, and those whose inertial frame copies a body
  frame that a `BODY_FRAME` attribute moves; then `body_subtreemass`;
* the mass matrix at qpos0 (`set_const`: `dof_M0`, `*_invweight0`,
  `actuator_acc0`, `meaninertia`) changes with inertia, `MASS_MATRIX` and
  `BODY_FRAME`;
* positions at qpos0 (`tendon_length0`, tendon spring lengths, `extent`,
  `center`, `meansize`) change with inertia, `BODY_FRAME` and
  `KINEMATICS`;
* actuator moments (`actuator_acc0`, dampratio) change with those
  positions and `TRANSMISSION`; dampratios also with `ACTUATOR_GAINS`;
* camera and light `*0` fields change with inertia and `BODY_FRAME`; the
  connect/weld `eq_data` with `BODY_FRAME`.
"""

import enum


class Effect(enum.Flag):
  """What an attribute affects beyond the fields it writes."""

  NONE = 0
  # The geom's mass, inertia or frame, from which its body may infer its
  # inertial (geom size, mass, density, pos, quat).
  GEOM_INERTIA = enum.auto()
  # The geom's frame relative to its body (geom pos, quat).
  GEOM_FRAME = enum.auto()
  # The body's explicit inertial (body mass, inertia, ipos, iquat).
  BODY_INERTIAL = enum.auto()
  # The explicit inertial frame relative to the body frame (ipos, iquat).
  INERTIAL_FRAME = enum.auto()
  # The body frame: free-joint qpos0, inertial frames that copy it,
  # everything positioned at qpos0 (body pos, quat).
  BODY_FRAME = enum.auto()
  # Positions at qpos0 of things other than body frames (geom size, pos,
  # quat; site pos, quat).
  KINEMATICS = enum.auto()
  # The joint-space inertia at qpos0 (joint armature).
  MASS_MATRIX = enum.auto()
  # Actuator transmissions (actuator gear).
  TRANSMISSION = enum.auto()
  # Actuator gains and biases, from which dampratios derive a damping
  # (actuator kp, kv, gainprm, biasprm).
  ACTUATOR_GAINS = enum.auto()
  # Joint ranges, which actuators may inherit (inheritrange) and muscles
  # simulate length ranges over (joint range).
  JOINT_RANGE = enum.auto()


# Attributes that change a body's frame, its inertial or what it carries:
# the structure checks look at that body (`structure.check_body`).
ON_BODY = (
    Effect.GEOM_INERTIA
    | Effect.BODY_INERTIAL
    | Effect.BODY_FRAME
    | Effect.KINEMATICS
)
