"""The part of a reset's forward pass that something reads.

Composer's reset runs `mj_forward` (actuation disabled) after the
`initialize_episode` hooks, so that the first observation and whatever reads
the new state see consistent derived quantities. In a batched program that
forward pass is a second copy of the physics beside the step's: collision
detection, the constraint solver, the mass matrix. Yet `mjx.step` recomputes
every derived quantity from the integration state (`qpos`, `qvel`, `act`,
`ctrl`, `qacc_warmstart`, ...), so the reset's results matter only to what
reads the FIRST state before the next step's physics: the observables
sampled at reset, the episode's start metrics, and the next step's hooks
that run before its physics.

This module finds, at trace time, which `mjx.Data` fields those readers use
(`data_reads.reads`: dead-code elimination of their jaxpr) and picks the
cheapest stage of the forward pass that computes them (`choose_stage`):

* `'none'`: nothing the forward pass writes is read (e.g. only joint
  velocities and task state; MJX's kinematics rewrites `qpos`, its
  quaternions normalized, so reading `qpos` takes the position stage);
* `'position'`: kinematics, centres of mass, cameras and lights, tendon
  lengths, actuator transmissions and position sensors;
* `'velocity'`: the position stage, then body velocities, tendon and
  actuator velocities and velocity sensors;
* `'full'`: `mjx.forward`, everything.

Sensors are computed by a reduced stage only where `sensordata` is read,
and only where every sensor read is one the stage computes exactly
(`POSITION_SENSORS`, `VELOCITY_SENSORS`), else the stage is `'full'`. Which
fields and sensors are read comes from the readers' jaxpr
(`data_reads.reads`): the elements its static slices and constant-index
gathers take, or every sensor where `sensordata` reaches anything else. So
a humanoid whose observations read its centre-of-mass velocity sensor takes
the velocity stage although the model also has an accelerometer and force
sensors; a reduced stage then computes every sensor
it computes exactly, and the others keep their values from before the
forward pass, as the fields the stage does not compute do.

Every stage ends as `mjx.forward` with actuation disabled does
(`mjx.fwd_actuation`: `act_dot` and `qfrc_actuator` zero). Fields the stage
does not compute keep their values from before the forward pass.
ExecutionOptions(reset_forward='full') always runs `'full'`, as composer does.
"""

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np

from mjx_composer.physics import bindings
from mjx_composer.platform import internals
from mjx_composer.runtime import data_reads
from mjx_composer.runtime import dirty_forward
from mjx_composer.runtime import keys as keys_lib
from mjx_composer.runtime import substep_sensors

STAGES = ('none', 'position', 'velocity', 'full')

# Sensor types whose values the reduced stages compute exactly as
# `mjx.forward` does (tests/runtime/test_reset_forward.py checks each against it).
# A model with any other sensor takes the full forward pass whenever
# `sensordata` is read.
_S = mujoco.mjtSensor
POSITION_SENSORS = frozenset(
    {
        _S.mjSENS_JOINTPOS,
        _S.mjSENS_TENDONPOS,
        _S.mjSENS_ACTUATORPOS,
        _S.mjSENS_BALLQUAT,
        _S.mjSENS_FRAMEPOS,
        _S.mjSENS_FRAMEQUAT,
        _S.mjSENS_FRAMEXAXIS,
        _S.mjSENS_FRAMEYAXIS,
        _S.mjSENS_FRAMEZAXIS,
        _S.mjSENS_SUBTREECOM,
        _S.mjSENS_CLOCK,
    }
)
VELOCITY_SENSORS = frozenset(
    {
        _S.mjSENS_VELOCIMETER,
        _S.mjSENS_GYRO,
        _S.mjSENS_JOINTVEL,
        _S.mjSENS_TENDONVEL,
        _S.mjSENS_ACTUATORVEL,
        _S.mjSENS_BALLANGVEL,
        _S.mjSENS_FRAMELINVEL,
        _S.mjSENS_FRAMEANGVEL,
        _S.mjSENS_SUBTREELINVEL,
        _S.mjSENS_SUBTREEANGMOM,
    }
)


def _without_actuation(model):
  opt = model.opt
  return model.replace(
      opt=opt.replace(disableflags=opt.disableflags | mjx.DisableBit.ACTUATION)
  )


def _position(m, d, sensors):
  d = mjx.kinematics(m, d)
  d = mjx.com_pos(m, d)
  d = mjx.camlight(m, d)
  d = mjx.tendon(m, d)
  d = mjx.transmission(m, d)
  return mjx.sensor_pos(m, d) if sensors else d


def velocity_part(m, d):
  """What `mjx.fwd_velocity` computes before its force terms: actuator and
  tendon velocities, and the bodies' com-based velocities."""
  impl = internals.data_impl(d)
  d = internals.replace_data_impl(
      d,
      actuator_velocity=impl.actuator_moment @ d.qvel,
      ten_velocity=impl.ten_J @ d.qvel,
  )
  return mjx.com_vel(m, d)


def _velocity(m, d, sensors):
  d = velocity_part(m, _position(m, d, sensors))
  return mjx.sensor_vel(m, d) if sensors else d


_STAGE_FNS = {
    'none': lambda m, d, sensors: d,
    'position': _position,
    'velocity': _velocity,
}


def forward(stage, model, data, sensors=True):
  """`data` after `stage` of the forward pass, with actuation disabled.

  With `sensors=False`, a reduced stage leaves `sensordata` as it was.
  """
  model = _without_actuation(model)
  if stage == 'full':
    return mjx.forward(model, data)
  return mjx.fwd_actuation(model, _STAGE_FNS[stage](model, data, sensors))


# `written`'s answers: every environment of a model asks for the same few
# stages (the reset's choice, the control step's).
_WRITTEN = data_reads.PerStructure('reset_forward.written')


def written(
    stage, model, data, sensors=True, after_step=False
) -> frozenset[str]:
  """The leaves of `data` that `forward(stage, ...)` writes (by tracing).

  With `after_step`, those `StepForward(stage, sensors)` writes: the
  stage as a control step runs it after its physics, with actuation and
  (below `'full'`) without the reset's `fwd_actuation`. The answer
  depends on the shapes and structure of `model` and `data` only, so it
  is traced once per structure (and kept for this process).
  """
  key = (
      stage,
      bool(sensors),
      bool(after_step),
      data_reads.structure_key(model),
      data_reads.structure_key(data),
  )
  return _WRITTEN(
      key, lambda: _trace_written(stage, model, data, sensors, after_step)
  )


def _trace_written(
    stage, model, data, sensors, after_step=False
) -> frozenset[str]:
  out = {}

  def run(data):
    if after_step:
      result = StepForward(stage, sensors)(model, data)
    else:
      result = forward(stage, model, data, sensors)
    out['names'] = data_reads.replaced_names(data, result)
    return result

  jax.eval_shape(run, data)
  return out['names']


# The sensor types each reduced stage computes exactly.
_EXACT_SENSORS = {
    'position': POSITION_SENSORS,
    'velocity': POSITION_SENSORS | VELOCITY_SENSORS,
}


def _sensor_type(mj_model, i):
  return mujoco.mjtSensor(int(mj_model.sensor_type[i]))


def sensor_stage(mj_model, sensors=None) -> str:
  """The least stage that computes `sensors` of `mj_model` exactly.

  Args:
    mj_model: the host `MjModel`.
    sensors: sensor ids; None: every sensor of the model.
  """
  ids = range(mj_model.nsensor) if sensors is None else sensors
  types = {_sensor_type(mj_model, i) for i in ids}
  if not types:
    return 'none'
  for stage, exact in _EXACT_SENSORS.items():
    if types <= exact:
      return stage
  return 'full'


def sensors_of_elements(mj_model, elements) -> tuple[int, ...]:
  """The ids of the sensors with any `sensordata` element in `elements`.

  None (elements not known) gives every sensor.
  """
  if elements is None:
    return tuple(range(mj_model.nsensor))
  return tuple(
      i
      for i in range(mj_model.nsensor)
      if any(
          adr in elements
          for adr in range(
              mj_model.sensor_adr[i],
              mj_model.sensor_adr[i] + mj_model.sensor_dim[i],
          )
      )
  )


def _exact_rows(mj_model, stage) -> np.ndarray:
  """Mask of the `sensordata` elements `stage` computes exactly."""
  mask = np.zeros(mj_model.nsensordata, bool)
  for i in range(mj_model.nsensor):
    if _sensor_type(mj_model, i) in _EXACT_SENSORS[stage]:
      adr = mj_model.sensor_adr[i]
      mask[adr : adr + mj_model.sensor_dim[i]] = True
  return mask


def choose_stage(needed, model, data, mj_model, sensordata=None):
  """The cheapest stage that computes every field of `needed` as `'full'`.

  Where `sensordata` is needed, a reduced stage is chosen only where it
  computes every sensor read exactly (`sensor_stage`); it then computes
  every sensor it computes exactly, and leaves the others as they were.
  Elsewhere the reduced stages skip the sensors.

  Args:
    needed: the names (`leaf_names`) of the fields the readers use.
    model: the `mjx.Model`.
    data: an `mjx.Data` of the model (shapes suffice).
    mj_model: the host `MjModel` (its sensor types).
    sensordata: the `sensordata` elements read (`data_reads.reads`);
      None: all.

  Returns:
    The `ResetForward` of the stage.
  """
  needed = frozenset(needed)
  read = sensors_of_elements(mj_model, sensordata)
  if 'sensordata' in needed and sensor_stage(mj_model, read) == 'full':
    # Settled without tracing the full pass (about a second).
    return ResetForward('full', True, frozenset(), frozenset())
  derived = written('full', model, data)
  needed &= derived
  sensors = 'sensordata' in needed
  floor = sensor_stage(mj_model, read) if sensors else 'none'
  for stage in STAGES[STAGES.index(floor) : -1]:
    writes = written(stage, model, data, sensors)
    if needed <= writes:
      rows = _exact_rows(mj_model, stage) if sensors else None
      if rows is not None and rows.all():
        rows = None  # Every sensor: nothing to keep from before.
      return ResetForward(stage, sensors, writes, derived, rows)
  return ResetForward('full', True, derived, derived)


def keep_only(keep, derived, computed, before):
  """`computed`, but `before`'s leaves where in `derived` and not in `keep`."""
  names = data_reads.leaf_names(computed)
  leaves = [
      old if name in derived and name not in keep else new
      for name, new, old in zip(
          names, jax.tree.leaves(computed), jax.tree.leaves(before)
      )
  ]
  return jax.tree.unflatten(jax.tree.structure(computed), leaves)


@dataclasses.dataclass(frozen=True)
class ResetForward:
  """The stage of the forward pass a reset runs.

  Attributes:
    stage: one of `STAGES`.
    sensors: whether a reduced stage computes `sensordata`.
    writes: the fields the stage writes (`written`; for `'full'`, which
      `restrict` leaves alone, may be left empty).
    derived: every field `mjx.forward` writes (likewise).
    sensor_rows: where a reduced stage computes `sensordata` but not all
      of it exactly, the mask of the elements it does (the others keep
      their values from before); else None.
  """

  stage: str
  sensors: bool
  writes: frozenset
  derived: frozenset
  sensor_rows: np.ndarray | None = dataclasses.field(
      default=None, compare=False
  )

  def __call__(self, model, data):
    """`data` after the stage (see the module docstring)."""
    return self._keep_inexact_sensors(
        forward(self.stage, model, data, self.sensors), data
    )

  def _keep_inexact_sensors(self, computed, before):
    if self.sensor_rows is None:
      return computed
    return computed.replace(
        sensordata=jnp.where(
            self.sensor_rows, computed.sensordata, before.sensordata
        )
    )

  def at_least(self, stage, model, data, mj_model) -> 'ResetForward':
    """This stage, or `stage` where that is later: a reset whose state
    must carry `stage` (`runtime.carried_stage`) computes it.

    Arguments as `choose_stage`'s. The later stage computes the sensors
    where this one does, as `choose_stage` would have chosen them.
    """
    if STAGES.index(self.stage) >= STAGES.index(stage):
      return self
    rows = None
    if self.sensors:
      rows = _exact_rows(mj_model, stage)
      if rows.all():
        rows = None
    return ResetForward(
        stage,
        self.sensors,
        written(stage, model, data, self.sensors),
        self.derived or written('full', model, data),
        rows,
    )

  def sensors_of(self, model, data):
    """`data`, through the full forward pass with its sensors skipped
    (`mjDSBL_SENSOR`), with the sensors this stage computes.

    For a restart fused into the sub-step loop that leaves the sensors to
    the control step's end; `restrict` then keeps what the stage computes.
    """
    if self.stage == 'full':
      return substep_sensors.sensors_of(
          model, data, substep_sensors.IntegrationState.of(data)
      )
    if not self.sensors:
      return data  # `restrict` keeps the sensors from before the forward pass
    data = mjx.sensor_pos(model, data)
    return mjx.sensor_vel(model, data) if self.stage == 'velocity' else data

  def read_before(self) -> frozenset:
    """The leaves of `mjx.Data` (`data_reads.leaf_names`) whose values
    `restrict` takes from `before`."""
    if self.stage == 'full':
      return frozenset()
    names = set(self.derived) - set(self.writes)
    if self.sensor_rows is not None:
      names.add('sensordata')
    return frozenset(names)

  def restrict(self, computed, before):
    """A full forward pass's `computed` data, as this stage leaves it.

    The fields the stage writes are `computed`'s (the stage computes them
    as the full pass does); the other derived fields are `before`'s. So a
    same-step restart fused into the sub-step loop, whose forward pass is
    the full one, leaves what `reset` leaves.
    """
    if self.stage == 'full':
      return computed
    return self._keep_inexact_sensors(
        keep_only(self.writes, self.derived, computed, before), before
    )


# -- after a physics step: what composer's `Physics.step` leaves current ------
#
# dm_control's `Physics.step` runs `mj_step2` then `mj_step1`: after a step,
# everything of the position and velocity stages (poses, com velocities,
# tendon and actuator lengths and velocities, position and velocity
# sensors) is of the NEW state, and the acceleration stage (`qacc`, forces,
# acceleration sensors, touch) of the state the step started from.
# `mjx.step` is MuJoCo's `mj_step`: everything but the integration state is
# of the state the step started from. So the control step recomputes, after
# its last physics step, the least stage (`AFTER_STEP_STAGES`) that covers
# what its readers read of the position and velocity stages (found from
# their jaxpr, as for the reset); the acceleration stage keeps the step's
# values, as composer's does, except where composer's physics is dirty
# after the step (a binding wrote the action, `dirty_forward`) and a
# binding read after the step runs `mj_forward`: there the stage is
# `'full'`, `mjx.forward` of the new state.

AFTER_STEP_STAGES = ('none', 'position', 'velocity', 'full')


@dataclasses.dataclass(frozen=True)
class StepForward:
  """The stage of the forward pass a control step runs after its physics.

  Attributes:
    stage: one of `AFTER_STEP_STAGES`.
    sensors: whether the stage recomputes the sensors of its stages (the
      position sensors; for `'velocity'` the velocity sensors too; for
      `'full'` every sensor); below `'full'` the acceleration sensors keep
      the step's values either way.
  """

  stage: str = 'none'
  sensors: bool = False

  @property
  def sensor_stages(self) -> int:
    """The sensor stages this recomputes: 0 none, 1 position, 2 position
    and velocity, 3 all (what `substep_sensors.sensors_of` may skip)."""
    if self.stage == 'full':
      return 3
    if not self.sensors:
      return 0
    return AFTER_STEP_STAGES.index(self.stage)

  def __call__(self, model, data):
    """`data` with the stage recomputed at its (new) integration state.

    `'full'` is `mjx.forward` with actuation, as dm_control's
    `mj_forward` at a dirty physics' read. It leaves `qvel`, `act`,
    `time`, `ctrl` and `qacc_warmstart` as they are and writes `qpos` back
    with its quaternions normalized, as the next step's forward pass does
    first: the trajectory is the one without it, to float rounding.
    """
    if self.stage == 'none':
      return data
    if self.stage == 'full':
      return mjx.forward(model, data)
    return _STAGE_FNS[self.stage](model, data, self.sensors)


def _sensor_floor(mj_model, sensors) -> int:
  """The last of the position (1) and velocity (2) stages that `sensors`
  need; 0 where they are all acceleration sensors."""
  stages = [int(mj_model.sensor_needstage[i]) for i in sensors]
  return max([s for s in stages if s <= 2], default=0)


def choose_after_step(
    needed, model, data, mj_model, sensordata=None
) -> StepForward:
  """The least stage that brings what `needed` reads of the position and
  velocity stages up to date.

  Args:
    needed: the names (`data_reads.leaf_names`) of the fields the readers
      use.
    model: the `mjx.Model`.
    data: an `mjx.Data` of the model (shapes suffice).
    mj_model: the host `MjModel` (its sensors' stages).
    sensordata: the `sensordata` elements read; None: all.

  Returns:
    The `StepForward`: `'none'` where nothing read is of the position or
    velocity stages.
  """
  needed = frozenset(needed) & written('velocity', model, data)
  floor = 0
  if 'sensordata' in needed:
    floor = _sensor_floor(mj_model, sensors_of_elements(mj_model, sensordata))
    if not floor:  # Only acceleration sensors: the step's values stand.
      needed -= {'sensordata'}
  if not needed:
    return StepForward()
  sensors = 'sensordata' in needed
  for stage in AFTER_STEP_STAGES[max(floor, 1) : -1]:
    if needed <= written(stage, model, data, sensors):
      return StepForward(stage, sensors)
  return StepForward('velocity', sensors)


def reads_acceleration(
    needed, model, data, mj_model, sensordata=None, bound=()
) -> bool:
  """Whether `needed` reads what only the full forward pass computes.

  That is: a field `mjx.forward` writes and the velocity stage does not
  (actuator, constraint and contact forces, the contacts, ...), or a
  sensor of the acceleration stage (`mjSTAGE_ACC`: accelerometer, touch,
  force, torque, ...). `qacc` counts only where a binding reads it (in
  `bound`, the fields of the readers' binding reads): the environment's
  own divergence check (`episode.diverged`) reads it after every step.
  Other arguments as `choose_after_step`'s.
  """
  needed = frozenset(needed)
  if 'qacc' not in bound:
    needed -= {'qacc'}
  if 'sensordata' in needed:
    sensors = sensors_of_elements(mj_model, sensordata)
    if any(
        int(mj_model.sensor_needstage[i]) == int(mujoco.mjtStage.mjSTAGE_ACC)
        for i in sensors
    ):
      return True
  needed -= {'sensordata'}
  if not needed:
    return False
  # As a control step runs the stages (`StepForward`): actuator forces are
  # of the acceleration stage.
  full = written('full', model, data, after_step=True)
  velocity = written('velocity', model, data, after_step=True)
  return bool(needed & (full - velocity))


def after_step(transitions) -> StepForward:
  """What `transitions`' control step recomputes after its physics.

  Its readers: the `after_step` hooks, the control step's last observation
  update, the reward, discount, termination and metrics, and the next
  step's hooks before its physics (scheduled, `before_step`, the first
  `before_substep`). Found from their jaxpr, traced with the shapes of a
  reset's `State` (`Analysis.reset_shapes`): the position or velocity
  stage where they read them (`choose_after_step`), and the full forward
  pass where, in composer, the physics is dirty after the control step's
  sub-steps (`dirty_forward.dirty_after_substeps`), a binding read among them
  runs `mj_forward` (`dirty_forward.forwarding_read`) and they read what
  only the acceleration stage computes (`reads_acceleration`), unless
  `transitions.dirty_forward` is 'never'. Where the backend's forward pass
  is one kernel sequence (`Backend.staged_forward` False: MuJoCo Warp),
  nothing is recomputed (its observations lag the state by one physics
  step).
  """
  t = transitions
  model = t.initial.model
  if not t.backend.staged_forward:
    return StepForward()
  state = t.analysis.reset_shapes.state
  action = jax.ShapeDtypeStruct(t.action_shape, jnp.float32)

  def readers(data, state, key, action):
    keys = keys_lib.StepKeys.split(key)
    physics = t.physics(state.replace(data=data))
    stepped = t.end_step(
        state, physics, state.obs_state, keys, jnp.zeros((), bool)
    )
    next_keys = keys_lib.StepKeys.split(stepped.key)
    fields = tuple(stepped.model_fields)
    before = t.before_step(stepped, action, next_keys)
    before = t.before_substep(before, action, next_keys, 0, fields)
    after = before.carry(fields)
    read = (
        stepped.replace(data=None),
        after.replace(data=None),
        data_reads.replaced(data, after.data),
    )
    return read, stepped.data

  with bindings.recording_dirty_events() as events:
    read = data_reads.reads(
        readers, state.data, state, keys_lib.key_shape(), action
    )
  mj_model = t.initial.index.mj_model
  if (
      t.dirty_forward == 'composer'
      and dirty_forward.forwarding_read(events)
      and dirty_forward.dirty_after_substeps(t)
      and reads_acceleration(
          read.fields,
          model,
          state.data,
          mj_model,
          sensordata=read.sensordata,
          bound={field for _, field in events},
      )
  ):
    return StepForward('full', True)
  return choose_after_step(
      read.fields,
      model,
      state.data,
      mj_model,
      sensordata=read.sensordata,
  )
