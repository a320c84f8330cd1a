"""Sensors computed once per control step, where nothing reads them between.

`mjx.step` computes every sensor of the model at every physics step: the
position, velocity and acceleration stages of `mjx.forward` each end with
their sensors, and force, torque and accelerometer sensors add a
post-constraint pass over the kinematic tree (`cacc`, `cfrc_int`,
`cfrc_ext`). A control step of `n` sub-steps thus computes the sensors `n`
times, yet between two sub-steps only the sub-step hooks and the observables
sampled at sub-steps see the data. Where none of them reads what the sensor
stages write (`OUTPUTS`; `once_per_step` finds that from their jaxpr), the
sub-steps run with MuJoCo's sensor flag disabled (`without_sensors`) and the
control step computes the sensors once, after its last sub-step
(`sensors_of`), from that sub-step's integration state (`IntegrationState`),
as its `mjx.step` would have. The control step's data, observations and
rewards are those of `n` plain `mjx.step` calls (to float rounding:
`tests/runtime/test_substep_sensors.py` compares them). Where the restart is fused
into the sub-step loop (`ExecutionOptions(share_reset_forward=True)`), the
restart's forward pass skips them too and the restart computes those its
reset's stage computes (`ResetForward.sensors_of`).

`mjx.step` computes the sensors after the forward pass and before the
integrator advances `qpos`, `qvel`, `act` and `time`; every other field a
sensor reads keeps its value through the integrator. So the sensors of the
last sub-step are those of its end data with those four fields set back to
the values the sub-step started from, provided nothing after the sub-step's
physics wrote another field (the after-substep hooks; `once_per_step`
checks which data they write).
"""

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx

from mjx_composer.runtime import data_reads
from mjx_composer.runtime import keys as keys_lib

from mjx_composer.platform import internals

# The `mjx.Data` leaves (`data_reads.leaf_names`) that the sensor stages of
# `mjx.forward` write (`tests/runtime/test_substep_sensors.py` checks the list).
OUTPUTS = frozenset(
    {
        'sensordata',
        '_impl.subtree_linvel',
        '_impl.subtree_angmom',
        '_impl.cacc',
        '_impl.cfrc_int',
        '_impl.cfrc_ext',
    }
)

# The leaves MJX's Euler and implicitfast integrators advance, and the
# sensors read; `qacc_warmstart`, which they also write, no sensor reads.
ADVANCED = ('qpos', 'qvel', 'act', 'time')

# What `mjx.step` runs after `mjx.forward`, by integrator: the integrators
# whose step splits into a forward pass and an update of `ADVANCED` (and
# `qacc_warmstart`).
INTEGRATORS = {
    int(mujoco.mjtIntegrator.mjINT_EULER): mjx.euler,
    int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST): mjx.implicit,
}


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class IntegrationState:
  """What a physics step's integrator advances, as the step started."""

  qpos: jax.Array
  qvel: jax.Array
  act: jax.Array
  time: jax.Array

  @classmethod
  def of(cls, data: mjx.Data) -> 'IntegrationState':
    return cls(*(getattr(data, name) for name in ADVANCED))


def without_sensors(model: mjx.Model) -> mjx.Model:
  """`model` with MuJoCo's sensor stage disabled (`mjDSBL_SENSOR`)."""
  opt = model.opt
  return model.replace(
      opt=opt.replace(disableflags=opt.disableflags | mjx.DisableBit.SENSOR)
  )


def sensors_of(
    model: mjx.Model,
    data: mjx.Data,
    started: IntegrationState,
    recomputed: int = 0,
) -> mjx.Data:
  """`data` with the sensors its last physics step would have computed.

  Args:
    model: the model the step ran with, sensors enabled.
    data: the data after a step run with `without_sensors(model)`.
    started: the step's integration state before the step
      (`IntegrationState.of` of the data it stepped).
    recomputed: the sensor stages (1 position, 2 velocity, 3 all) that the
      caller computes again right after, at the new state
      (`reset_forward.StepForward.sensor_stages`): these are skipped here,
      their results would be overwritten. Their `OUTPUTS` then keep their
      values until the caller writes them.

  Returns:
    `data`, its `OUTPUTS` (but those of the `recomputed` stages) as
    `mjx.step(model, ...)` leaves them.
  """
  if recomputed >= 3:
    return data
  advanced = {name: getattr(data, name) for name in ADVANCED}
  data = data.replace(**dataclasses.asdict(started))
  if recomputed < 1:
    data = mjx.sensor_pos(model, data)
  if recomputed < 2:
    data = mjx.sensor_vel(model, data)
  # `mjx.forward` skips the acceleration stage's sensors where the model has
  # no constraint rows (its solver does not run).
  if internals.data_impl(data).efc_J.size:
    data = mjx.sensor_acc(model, data)
  return data.replace(**advanced)


def once_per_step(transitions) -> bool:
  """Whether `transitions`' sub-steps may leave the sensors to the end.

  Where the backend runs the forward pass in stages
  (`Backend.staged_forward`: MJX's JAX implementation), with an integrator
  of `INTEGRATORS`, more than one sub-step and the sensors enabled, where nothing between two
  sub-steps' physics reads what the sensor stages write (`OUTPUTS`) and
  the after-substep hooks write no data but the integration state
  (`ADVANCED`). Found from the jaxpr of that work, traced with the shapes
  of a reset's `State` (`Analysis.reset_shapes`).
  """
  model = transitions.initial.model
  if (
      transitions.n_sub_steps == 1
      or not transitions.backend.staged_forward
      or int(model.opt.integrator) not in INTEGRATORS
      or model.opt.disableflags & mjx.DisableBit.SENSOR
  ):
    return False
  read, written = _between_substeps(
      transitions, transitions.analysis.reset_shapes.state
  )
  return not (read.fields & OUTPUTS or written - set(ADVANCED))


def _between_substeps(t, state) -> tuple[data_reads.Reads, set[str]]:
  """What the work between two sub-steps' physics reads of `mjx.Data`,
  and the data leaves the after-substep hooks write.

  That work: a sub-step's after-substep hooks and observation update, then
  the next sub-step's before-substep hooks (of the `Transitions` `t`). The
  data those hooks pass on untouched to the physics is not read by them:
  `mjx.step` reads only the integration state. `state`: a `State`'s shapes.
  """
  action = jax.ShapeDtypeStruct(t.action_shape, jnp.float32)
  index = jax.ShapeDtypeStruct((), jnp.int32)
  hooks_wrote = set()

  def readers(data, state, key, action, i):
    keys = keys_lib.StepKeys.split(key)
    fields = tuple(state.model_fields)
    stepped = t.physics(state.replace(data=data))
    carry, obs_state = t.after_substep(
        stepped, state.obs_state, keys, i, fields
    )
    hooks_wrote.update(data_reads.replaced_names(data, carry.data))
    after = t.before_substep(
        t.restore(carry), action, keys, i + 1, fields
    ).carry(fields)
    written = data_reads.replaced(data, after.data)
    return (after.replace(data=None), obs_state, written), after.data

  read = data_reads.reads(
      readers, state.data, state, keys_lib.key_shape(), action, index
  )
  return read, hooks_wrote
