"""`ExecutionOptions`: how an `Environment` runs, apart from what it computes.

    options = composer.ExecutionOptions(auto_reset='same_step', impl='jax')
    env = composer.Environment(task, time_limit=10.0, options=options)

Every option chooses between programs that compute the same episodes (to
float rounding where a field says so): when an ended episode restarts, which
MJX implementation runs the physics, how a restart shares the step's forward
pass, what a reset's forward pass computes, how often the sensors are
computed, whether a restart restores a copy of the first state; one,
`dirty_forward`, chooses which state the acceleration stage
read after a control step belongs to (the trajectories are the same, to float
rounding). The task and `Environment`'s composer arguments say what the
episodes are. The options are checked when they are made, except for what
depends on the device (whether MuJoCo Warp runs there), which `Environment`
checks when it is built. Numbers for the choices are in docs/performance.md.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

from mjx_composer.model import element_index
from mjx_composer.platform import impl_choice
from mjx_composer.runtime import episode as episode_lib

AutoReset = Literal['next_step', 'same_step']
Impl = Literal['jax', 'warp']
ResetForward = Literal['observed', 'full']
SubstepSensors = Literal['read', 'all']
DirtyForward = Literal['composer', 'never']
CarryStage = Literal['auto', 'never']
StoredRestart = Literal['auto', 'never']
Branches = Literal['auto', 'loop', 'cond']


@dataclasses.dataclass(frozen=True)
class ExecutionOptions:
  """How an `Environment` runs its worlds (`Environment(options=...)`).

  Frozen: derive a variant with `dataclasses.replace(options, impl='jax')`.
  `Environment.options` holds the options as resolved for its device.

  Attributes:
    auto_reset: when a world whose episode ended starts the next one.
      'next_step' (composer's): `step` returns the LAST state, and the next
      `step` of that world returns the new episode's FIRST state instead of
      stepping (see `runtime.episode`). 'same_step': the step that ends an
      episode returns the new episode's first state, marked LAST, with the
      ended episode's reward, discount and metrics (what Brax and
      Playground's training loops expect).
    per_world_model_fields: model field names (e.g. 'geom_rgba', 'opt')
      made per world whatever the hooks write. Not needed for the fields
      that hooks write (`initialize_episode` and step hooks alike), which
      are found automatically by an abstract trace of the hooks.
    impl: which MJX implementation runs the physics: 'jax' (MJX's XLA
      implementation), 'warp' (MuJoCo Warp kernels through JAX's FFI, on a
      CUDA GPU or the CPU; `pip install 'mjx-composer[warp]'`), or None:
      'warp' on a CUDA GPU where MuJoCo Warp is installed (unless
      `share_reset_forward=True`), falling back to 'jax' with a logged
      warning when Warp refuses the environment; 'jax' everywhere else
      (`impl_choice.default_impls`). On 'warp', a model feature or a
      per-world model field that MuJoCo Warp cannot run is refused when the
      environment is built, with what to do (`backend`); building then
      traces `reset` once to find the per-world fields.
    naconmax: impl='warp' or None (ignored where None builds on 'jax'): the
      contacts MuJoCo Warp holds for all the worlds of one batch (one
      buffer shared by the batch). Default:
      `backend.DEFAULT_CONTACTS_PER_WORLD` per world for
      `backend.DEFAULT_WORLDS` worlds. Contacts beyond it are dropped and
      flagged in `backend.overflow(state.data)` and `metrics['overflow']`.
    njmax: impl='warp' or None (ignored where None builds on 'jax'):
      constraint rows per world. Default: `backend.default_njmax`, the
      larger of MuJoCo Warp's estimate and the rows MJX's JAX implementation
      allocates. Rows beyond it are dropped and flagged in
      `backend.overflow(state.data)` and `metrics['overflow']`.
    share_reset_forward: restart worlds (an ended episode's restart with
      same-step auto-reset, a LAST state's reset with next-step) in one more
      iteration of the sub-step loop, so that the step program holds one
      copy of the forward pass (`Transitions.step_and_restart`,
      `Transitions.reset_or_step`, with the sub-steps' copy of the carried
      stage where `carry_stage` applies): it compiles faster; on a GPU it
      runs a little slower than the separate restart where no episode ends,
      a fifth slower where many do (it restarts the whole batch), and holds
      more memory (docs/performance.md). False runs the sub-steps as a
      `lax.scan` and the restart separately. Both compute the same
      operations; where XLA fuses them alike the states are bit-identical
      (the tests' models), else (the humanoid's contacts and solver on a
      CPU) they agree to float rounding, and a reward, computed in other
      fusions of the compiled program, may differ in its last bits. Models
      the fused loop cannot run exactly (RK4, muscles, actuator gravity
      compensation) always take the separate restart. None (default): True
      on a CPU with impl='jax', where runs are short and compiling
      dominates; False elsewhere (and with an integer `auto_reset_batch`).
      impl='warp' refuses True (`backend`).
    auto_reset_batch: under `jax.vmap`, how many worlds' auto-resets are
      computed together, where the restart runs separately from the
      sub-steps (not `share_reset_forward`) on impl='jax'. An integer K: at
      a step in which some worlds' episodes end, those worlds are gathered
      into batches of K, reset and scattered back
      (`control_flow.select_reset`), so the step pays for K resets, not for
      all, and its program holds the buffers of K worlds' resets, not the
      whole batch's: less peak memory at the same speed where few worlds
      end (docs/performance.md). 'auto' (default): an eighth of the batch, for
      batches of 1,024 worlds or more (`control_flow.chunk_size`); the
      whole batch for smaller ones, for the fused restart and on
      impl='warp'. None: the reset of the whole batch is computed wherever
      any world's episode ends, and selected per world. The results are
      the same to float rounding. An integer needs impl='jax' (None then
      resolves to 'jax') and refuses `share_reset_forward=True`, which runs
      the reset inside the sub-step loop.
    reset_forward: 'observed' (default): a reset runs only the stage of the
      forward pass whose results something reads before the next physics
      step (the observables sampled at reset, the start metrics, the next
      step's hooks before its physics; `mjx.step` recomputes the rest):
      'none', 'position' (kinematics, centres of mass, position sensors,
      ...), 'velocity' (also velocities and velocity sensors) or 'full'
      (`runtime.reset_forward`; `Environment.reset_forward_stage` says
      which). The other derived fields of the reset's `State.data` (e.g.
      `contact`, `qacc`, `efc_*`) keep their values from before the forward
      pass (`Environment.physics(state)` completes them). Observations,
      rewards and trajectories are the same as with 'full', which computes
      everything as composer's reset does.
    substep_sensors: 'read' (default): where nothing between a control
      step's sub-steps reads the sensors (the sub-step hooks, the
      observables sampled at sub-steps), the sub-steps skip MuJoCo's sensor
      stage and the control step computes the sensors once, after its last
      sub-step, as its `mjx.step` would have; a fused restart
      (`share_reset_forward`) computes the sensors its reset's stage of the
      forward pass computes once, too (`runtime.substep_sensors`;
      `Environment.sensors_once_per_step` says whether). 'all': every
      sub-step computes them, as `mjx.step` does.
    dirty_forward: 'composer' (default): where the hooks until a control
      step's sub-steps end leave composer's physics dirty (a binding
      write of `ctrl`, `qpos`, `qvel`, `act`, `qfrc_applied`,
      `xfrc_applied` or a non-visual model field, as every dm_control
      walker's `apply_action` writes `ctrl`, with no binding read of
      anything else and no `physics.forward()` after it), and the control step's readers read,
      through a binding, what only the acceleration stage computes
      (accelerometer, touch, force and torque sensors, `qacc`, actuator
      and contact forces, the contacts), the control step ends with
      `mjx.forward` of the new state: what composer's forward pass at the
      first binding read after the step gives. Otherwise (`set_control`,
      no such reader) nothing changes (`runtime.dirty_forward`;
      `Environment.step_forward_stage` says 'full' where it applies).
      'never': the acceleration stage read after a control step is always
      that of the state its last sub-step started from (MJX's
      `mj_step`, composer's after `set_control`), one forward pass per
      control step fewer for such tasks. Trajectories are the same either
      way (to float rounding); what is read of the acceleration stage
      after a step differs.
    carry_stage: 'auto' (default): where a control step recomputes the
      position (or velocity) stage after its last sub-step
      (`step_forward_stage`) and nothing between physics steps disturbs
      it, every physics step computes that stage of its new state at its
      end, and the next one starts from it instead of computing it again:
      one copy of the stage in the step program instead of two, the same
      trajectories, observations and rewards to float rounding
      (`runtime.carried_stage`; `Environment.carried_stage` says which
      stage). A reset then computes at least that stage. 'never': every
      physics step is `mjx.step`, and the control step recomputes the
      stage after its last.
    stored_restart: 'auto' (default): where every restart of a world is
      its first reset's function of the episode's key (the world carries
      no per-world model fields, persistent entries or scheduled hooks)
      and the physics the episode starts from does not depend on that key
      (the pose is fixed, or `fixed_initial_state` repeats the first
      episode's key), an auto-reset restores that physics and computes
      from the key only what depends on it (`runtime.stored_restart`;
      `Environment.stored_restart` says whether): the step program holds
      no reset, and a restart costs a select. What does not depend on the
      key is computed once on the host's CPU when the first program is
      traced; with `fixed_initial_state`, each world keeps a copy of its
      first state instead (`State.stored_first`). The episodes are the
      same, to float rounding in the derived fields of a first state.
      'never': the step program runs the reset.
    branches: how the step program skips what runs at some steps only (the
      restart of the worlds whose episodes ended; in the fused sub-step
      loop, the end of the step and the restart): 'loop', a while loop
      run once or never (`control_flow.once_or_never`: on a GPU, where a
      conditional reads its predicate on the host and copies the state
      into the output of the branch not taken); 'cond', a `lax.cond`
      (`control_flow.run_if`: on a CPU, where XLA compiles it faster
      than a loop and it runs no slower); 'auto' (default): 'cond' on a
      CPU, 'loop' elsewhere (`Environment.branches` says which). The
      states are the same (bit for bit on the tests' swing task);
      docs/performance.md has the figures.

  Raises:
    ValueError: for a value outside a field's choices, or options that
      contradict each other (an integer `auto_reset_batch` with
      `share_reset_forward=True` or impl='warp'; Warp's buffer sizes with
      impl='jax').
  """

  auto_reset: AutoReset = 'next_step'
  per_world_model_fields: tuple[str, ...] = ()
  impl: Impl | None = None
  naconmax: int | None = None
  njmax: int | None = None
  share_reset_forward: bool | None = None
  auto_reset_batch: int | Literal['auto'] | None = 'auto'
  reset_forward: ResetForward = 'observed'
  substep_sensors: SubstepSensors = 'read'
  dirty_forward: DirtyForward = 'composer'
  carry_stage: CarryStage = 'auto'
  stored_restart: StoredRestart = 'auto'
  branches: Branches = 'auto'

  def __post_init__(self):
    if isinstance(self.per_world_model_fields, str):
      raise ValueError(
          'ExecutionOptions(per_world_model_fields=...) takes a sequence of '
          f'field names, got the string {self.per_world_model_fields!r}.'
      )
    # A tuple, so that the options stay hashable whatever sequence was given.
    object.__setattr__(
        self, 'per_world_model_fields', tuple(self.per_world_model_fields)
    )
    _check_choice('auto_reset', self.auto_reset, episode_lib.AUTO_RESET_MODES)
    _check_choice('reset_forward', self.reset_forward, ('observed', 'full'))
    _check_choice('substep_sensors', self.substep_sensors, ('read', 'all'))
    _check_choice('dirty_forward', self.dirty_forward, ('composer', 'never'))
    _check_choice('carry_stage', self.carry_stage, ('auto', 'never'))
    _check_choice('stored_restart', self.stored_restart, ('auto', 'never'))
    _check_choice('branches', self.branches, ('auto', 'loop', 'cond'))
    impl_choice.check_impl(self.impl, 'ExecutionOptions(impl=...)')
    impl_choice.check_buffer_arguments(
        self.impl, self.naconmax, self.njmax, requested=self.impl
    )
    unknown = set(self.per_world_model_fields) - element_index.MODEL_FIELDS
    if unknown:
      raise ValueError(
          f'Unknown mjx.Model fields {sorted(unknown)} in '
          'ExecutionOptions(per_world_model_fields=...).'
      )
    _check_auto_reset_batch(
        self.auto_reset_batch, self.share_reset_forward, self.impl
    )


def _check_choice(name, value, choices):
  if value not in choices:
    listed = ' or '.join(repr(choice) for choice in choices)
    raise ValueError(
        f'ExecutionOptions({name}=...): {name} must be {listed}, got '
        f'{value!r}.'
    )


def gathers_resets(batch) -> bool:
  """Whether `auto_reset_batch` asks for the gathered restart whatever the
  device (an integer, not 'auto' or None)."""
  return batch is not None and not isinstance(batch, str)


def _check_auto_reset_batch(batch, share_reset_forward, impl):
  if batch is None or isinstance(batch, str) and batch == 'auto':
    return
  if isinstance(batch, (bool, str)) or int(batch) != batch or batch < 1:
    raise ValueError(
        'ExecutionOptions(auto_reset_batch=...): auto_reset_batch must be a '
        f"positive integer, 'auto' or None, got {batch!r}."
    )
  if share_reset_forward:
    raise ValueError(
        'ExecutionOptions(auto_reset_batch=...) gathers the worlds that end '
        'into a separate, smaller reset; share_reset_forward=True runs the '
        'reset of the whole batch inside the sub-step loop instead. Set one '
        'of them.'
    )
  impl_choice.check_auto_reset_batch(impl)
