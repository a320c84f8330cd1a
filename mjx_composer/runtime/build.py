"""The host build of an environment: from a task to its reset and step.

`build` runs, once, what `Environment(task)` does on the host: the
build-time hooks (`initialize_episode_mjcf`), the composition of the
entity tree into one `MjSpec`, its compilation and checks, the element
index, the choice of the MJX implementation (`backend.resolve`: on
`impl=None` MuJoCo Warp first where it runs, then 'jax' if Warp refuses the
environment), the device model (`Backend.put`), the `after_compile`
hooks, and the parts that run the worlds: the episode rules, the
observation updater, the `Transitions` and the step program
(`auto_reset.step_program`). It returns them as a `Built`, which the
`Environment` facade keeps.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Callable

from dm_env import specs
import jax
import mujoco
import numpy as np

from mjx_composer import physics as physics_lib
from mjx_composer.model import element_index
from mjx_composer.model import model_checks
from mjx_composer.observation import updater as updater_lib
from mjx_composer.platform import backend as backend_lib
from mjx_composer.platform import impl_choice
from mjx_composer.platform import internals
from mjx_composer.runtime import auto_reset as auto_reset_lib
from mjx_composer.runtime import episode as episode_lib
from mjx_composer.runtime import options as options_lib
from mjx_composer.runtime import transitions as transitions_lib


@dataclasses.dataclass(frozen=True)
class Arguments:
  """`Environment`'s arguments that shape the build, checked."""

  time_limit: float
  n_sub_steps: int | None
  strip_singleton_obs_buffer_dim: bool
  delayed_observation_padding: updater_lib.ObservationPadding
  observation_groups: dict | None
  max_reset_attempts: int
  fixed_initial_state: bool


@dataclasses.dataclass(frozen=True)
class Built:
  """What an `Environment` runs, as its host build left it.

  Attributes:
    spec: the composed spec that was compiled.
    mj_model: the compiled host model.
    backend: the MJX implementation's `Backend`.
    options: the `ExecutionOptions` as resolved (`impl`,
      `share_reset_forward` and `auto_reset_batch` chosen; Warp's sizes
      None where ignored).
    control_timestep: seconds per control step.
    episode: the `EpisodeRules`.
    updater: the observation `Updater`.
    transitions: the `Transitions` of one world.
    step: the step program (`auto_reset.step_program`).
  """

  spec: mujoco.MjSpec
  mj_model: mujoco.MjModel
  backend: backend_lib.Backend
  options: options_lib.ExecutionOptions
  control_timestep: float
  episode: episode_lib.EpisodeRules
  updater: updater_lib.Updater
  transitions: transitions_lib.Transitions
  step: Callable


def reward_spec(task):
  """The task's reward spec, or composer's default (a float32 scalar)."""
  spec = task.get_reward_spec()
  if spec is not None:
    return spec
  return specs.Array(shape=(), dtype=np.float32, name='reward')


def discount_spec(task):
  """The task's discount spec, or composer's default (a scalar in [0, 1])."""
  spec = task.get_discount_spec()
  if spec is not None:
    return spec
  return specs.BoundedArray(
      shape=(), dtype=np.float32, minimum=0.0, maximum=1.0, name='discount'
  )


def build(
    task,
    hooks,
    random_state: np.random.RandomState,
    options: options_lib.ExecutionOptions,
    arguments: Arguments,
) -> Built:
  """Composes, compiles and puts `task` on the device; plans its steps.

  Args:
    task: the `Task`.
    hooks: its `EnvironmentHooks`.
    random_state: the build-time hooks' random state.
    options: the requested `ExecutionOptions`.
    arguments: the rest of `Environment`'s arguments.

  Raises:
    ValueError, NotImplementedError, ImportError: for models or per-world
      fields the chosen implementation cannot run (`backend`).
  """
  hooks.initialize_episode_mjcf(random_state)
  spec, handles = task.root_entity.compose()
  try:
    mj_model = spec.compile()
  except Exception as e:
    raise ValueError(f'The composed model failed to compile: {e}') from e
  model_checks.check_compiled_model(mj_model)
  handle_names = {
      key: (original, kind, composed.name)
      for key, (original, kind, composed) in handles.items()
  }
  index = element_index.ElementIndex(mj_model, handle_names)
  # This process's first device: MJX's default, `jax.devices()[0]`, is
  # another process's on every host but the first.
  device = jax.local_devices()[0]
  # The fused restart and the gathered reset run on 'jax' only.
  candidates = backend_lib.resolve(
      options.impl,
      device,
      share_reset_forward=(
          options.share_reset_forward
          or options_lib.gathers_resets(options.auto_reset_batch)
      ),
  )
  drawn = random_state.get_state()
  for i, backend in enumerate(candidates):
    try:
      return _build_on(
          backend,
          task,
          hooks,
          random_state,
          options,
          arguments,
          device,
          spec,
          mj_model,
          index,
      )
    except backend_lib.WarpUnsupportedError as e:
      if i + 1 == len(candidates):
        raise
      # impl=None: the default tries Warp first on a CUDA GPU. Rebuild on
      # the next implementation, its build-time hooks drawing from the
      # same random state as if it had been the only one tried.
      logging.warning(
          'impl=None: MuJoCo Warp cannot run this environment, so it runs '
          'on impl=%r. %s',
          candidates[i + 1].name,
          e,
      )
      random_state.set_state(drawn)
  raise AssertionError('unreachable: resolve returns one backend or more')


def _build_on(
    backend: backend_lib.Backend,
    task,
    hooks,
    random_state,
    options,
    arguments: Arguments,
    device,
    spec,
    mj_model,
    index,
) -> Built:
  """Puts the compiled model on `device` with `backend` and plans the steps.

  `options.impl` is the requested implementation (None for the default),
  which decides whether Warp's buffer sizes may be ignored.

  Runs the `after_compile` hooks on the device model, then builds the
  episode rules, the observation updater, the transitions and the step
  program.

  Raises:
    backend.WarpUnsupportedError: on 'warp', a model feature or per-world
      field that MuJoCo Warp cannot run.
  """
  impl_choice.check_buffer_arguments(
      backend.name, options.naconmax, options.njmax, requested=options.impl
  )
  backend.check_share_reset_forward(options.share_reset_forward)
  backend.check_per_world_fields(
      {
          name: ('ExecutionOptions(per_world_model_fields=...)',)
          for name in options.per_world_model_fields
      }
  )
  share_reset_forward = options.share_reset_forward
  if share_reset_forward is None:
    share_reset_forward = not options_lib.gathers_resets(
        options.auto_reset_batch
    ) and backend.default_share_reset_forward(device)
  # 'auto' gathers the ended worlds only where the restart runs apart from
  # the sub-steps and a batch's worlds can be gathered.
  auto_reset_batch = options.auto_reset_batch
  if auto_reset_batch == 'auto' and (
      share_reset_forward or backend.batch_shared_data
  ):
    auto_reset_batch = None
  sized = backend.sized_buffers
  branches = options.branches
  if branches == 'auto':
    branches = 'cond' if device.platform == 'cpu' else 'loop'
  resolved = dataclasses.replace(
      options,
      impl=backend.name,
      share_reset_forward=bool(share_reset_forward),
      auto_reset_batch=auto_reset_batch,
      branches=branches,
      # Ignored where the default builds on 'jax'.
      naconmax=options.naconmax if sized else None,
      njmax=options.njmax if sized else None,
  )
  if backend.jax_pipeline:
    model_checks.check_jax_collisions(mj_model)
    _choose_friction_cone(mj_model)
  mjx_model, data0 = backend.put(
      mj_model, device, naconmax=options.naconmax, njmax=options.njmax
  )
  compiled = hooks.after_compile(
      physics_lib.Physics(mjx_model, data0, index=index), random_state
  )
  physics = transitions_lib.initial_physics(task, compiled.model, data0, index)

  n_sub_steps = arguments.n_sub_steps
  if n_sub_steps is not None:
    logging.warning('n_sub_steps is deprecated: set the task timesteps.')
    n_sub_steps = int(n_sub_steps)
  else:
    n_sub_steps = task.physics_steps_per_control_step
  control_timestep = float(mj_model.opt.timestep) * n_sub_steps
  episode = episode_lib.EpisodeRules(
      task,
      episode_lib.step_limit(arguments.time_limit, control_timestep),
      reward_spec(task).shape,
      discount_spec(task).shape,
  )
  observation_groups = arguments.observation_groups
  if observation_groups is None:
    observation_groups = task.observation_groups()
  updater = updater_lib.Updater(
      task.observables,
      n_sub_steps,
      strip_singleton_buffer_dim=arguments.strip_singleton_obs_buffer_dim,
      pad_with_initial_value=(
          arguments.delayed_observation_padding
          == updater_lib.ObservationPadding.INITIAL_VALUE
      ),
      groups=observation_groups or None,
      physics=physics,
  )
  transitions = transitions_lib.Transitions(
      initial=physics,
      hooks=hooks,
      updater=updater,
      episode=episode,
      n_sub_steps=n_sub_steps,
      max_reset_attempts=int(arguments.max_reset_attempts),
      declared_model_fields=options.per_world_model_fields,
      reset_forward_mode=options.reset_forward,
      action_shape=tuple(task.action_spec(physics).shape),
      fixed_initial_state=arguments.fixed_initial_state,
      substep_sensors=options.substep_sensors,
      dirty_forward=options.dirty_forward,
      carry_stage=options.carry_stage,
      stored_restart_mode=options.stored_restart,
  )
  # `can_fuse_restart` is a fact of the host model: decide here, once.
  step = auto_reset_lib.step_program(
      transitions,
      auto_reset=options.auto_reset,
      fuse=resolved.share_reset_forward and transitions.can_fuse_restart(),
      chunk=resolved.auto_reset_batch,
      conditional=resolved.branches == 'cond',
  )
  # What the programs' shapes depend on (the reset's shapes and the
  # per-world model fields its hooks write, the reset's stage of the
  # forward pass, sensors once per control step) is found from abstract
  # traces that read shapes only, once, on first use (`runtime.analysis`):
  # building stays cheap for an environment that is never traced, and the
  # answer is the same whenever they run. A backend that cannot batch
  # every model field needs the per-world fields now, to refuse at build.
  if not backend.batches_every_model_field:
    backend.check_per_world_fields(transitions.per_world_model_fields())
  return Built(
      spec=spec,
      mj_model=mj_model,
      backend=backend,
      options=resolved,
      control_timestep=control_timestep,
      episode=episode,
      updater=updater,
      transitions=transitions,
      step=step,
  )


def _choose_friction_cone(mj_model):
  """Makes the compiled model's friction cone one MJX can run.

  composer's `Arena` asks for elliptic cones. MJX's JAX solver cannot run
  them on a model without contacts that has other constraints (a joint
  limit: it fails with "Indexer must have integer or boolean type"), nor
  with contacts of dimension 1. Without any contact the cone changes
  nothing, so such a model gets pyramidal cones (logged); with frictionless
  contacts the cone matters and the build is refused with the fix. Called
  on MJX's JAX pipeline only: MuJoCo Warp keeps the model's cone.

  Raises:
    NotImplementedError: elliptic cones with a contact of `condim` 1.
  """
  if mj_model.opt.cone != mujoco.mjtCone.mjCONE_ELLIPTIC:
    return
  dims = internals.contact_dims(mj_model)
  if not np.size(dims):
    logging.info(
        'The model has no contacts: its elliptic friction cone changes '
        'nothing, and MJX cannot run it without contacts; using pyramidal.'
    )
    mj_model.opt.cone = mujoco.mjtCone.mjCONE_PYRAMIDAL
  elif np.any(np.asarray(dims) == 1):
    raise NotImplementedError(
        "The model has elliptic friction cones (composer's Arena default) "
        'and contacts of condim 1 (frictionless), which MJX cannot '
        'simulate together. Set arena.mjcf_model.option.cone = '
        'mujoco.mjtCone.mjCONE_PYRAMIDAL, or give the geoms (or pairs) '
        'condim 3 or more.'
    )
