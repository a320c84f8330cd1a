"""The control step with auto-reset: one program, chosen when it is built.

An `Environment`'s `step` advances one world and, where its episode ended,
starts the next. Which program does that depends on facts known on the host
before anything is traced:

* the auto-reset mode (`ExecutionOptions.auto_reset`): 'next_step'
  (composer's: a LAST state's next step is the new episode's reset) or
  'same_step' (the step that ends an episode returns the restarted world);
* whether the restart runs as one more iteration of the sub-step loop
  (`ExecutionOptions.share_reset_forward`, where the model allows it:
  `Transitions.can_fuse_restart`), or separately, selected per world by
  `control_flow.select_reset` (`ExecutionOptions.auto_reset_batch` worlds
  at a time under `jax.vmap`, or the whole batch);
* whether the work that runs once in a step or not at all (the restart of
  the batch, the fused loop's end of step and restart) is a conditional
  (for a CPU) or a loop run once or never (for a GPU:
  `control_flow.branch_once`);
* whether the restart restores a copy of the world's first state instead
  (`ExecutionOptions.stored_restart`, where `Transitions.stored_restart`
  allows it: an analysis of the reset's jaxpr, run when the step is first
  traced).

`step_program` makes that choice once; every program it returns is a pure
function `(state, action) -> State` of one world with the same results, to
float rounding where XLA arranges the arithmetic differently (chunks of
`auto_reset_batch`, the fused restart on a model with contacts, the stored
restart's first state).
"""

from __future__ import annotations

import functools
from typing import Callable

import jax

from mjx_composer.runtime import control_flow
from mjx_composer.runtime import episode as episode_lib
from mjx_composer.runtime import keys as keys_lib
from mjx_composer.runtime import state as state_lib

StepProgram = Callable[[state_lib.State, jax.Array], state_lib.State]


def step_program(
    transitions,
    *,
    auto_reset: str,
    fuse: bool,
    chunk: int | None,
    conditional: bool = False,
) -> StepProgram:
  """The step of one world with `auto_reset`'s restart of ended episodes.

  Args:
    transitions: the environment's `Transitions`.
    auto_reset: 'next_step' or 'same_step'.
    fuse: whether the restart runs in the sub-step loop
      (`Transitions.reset_or_step`, `Transitions.step_and_restart`); the
      caller checks `Transitions.can_fuse_restart`.
    chunk: for the separate restart, how many ended worlds reset together
      under `jax.vmap` (`control_flow.select_reset`); None for the whole
      batch.
    conditional: whether what runs once or never is a `lax.cond`
      (`control_flow.run_if`, for a program compiled for a CPU) rather
      than a loop (`control_flow.once_or_never`, for a GPU).

  Returns:
    `(state, action) -> State`, pure; the action already checked.
  """
  running = _running_reset(transitions, auto_reset, fuse, chunk, conditional)
  if transitions.stored_restart_mode == 'never':
    return running
  return functools.partial(_restoring, transitions, auto_reset, running)


def _running_reset(transitions, auto_reset, fuse, chunk, conditional):
  """The step whose restart runs the reset."""
  if auto_reset == 'next_step':
    if fuse:
      return functools.partial(
          transitions.reset_or_step, conditional=conditional
      )
    return functools.partial(_step_or_reset, transitions, chunk, conditional)
  if fuse:
    return functools.partial(
        transitions.step_and_restart, conditional=conditional
    )
  return functools.partial(_step_then_restart, transitions, chunk, conditional)


def _restoring(transitions, auto_reset, running, state, action):
  """The step whose restart restores a copy of the world's first state,
  where `Transitions.stored_restart` allows it; else `running`.

  The keys are `running`'s: next-step's split by `_next_step`, same-step's
  restart takes the stepped state's key.
  """
  plan = transitions.stored_restart
  if plan is None:
    return running(state, action)
  if auto_reset == 'next_step':
    reset_key, stepped = _next_step(transitions, state, action)
    return control_flow.tree_select(
        state.last(), plan.restore(reset_key, state), stepped
    )
  stepped = transitions.step(state, action)
  restarted = episode_lib.reporting(plan.restore(stepped.key, stepped), stepped)
  return control_flow.tree_select(stepped.last(), restarted, stepped)


def _step_or_reset(transitions, chunk, conditional, state, action):
  """Next-step auto-reset: a LAST state's world resets instead of stepping.

  The step is computed for every world and discarded where the state is
  LAST (a select, not a branch); the reset is computed only when some world
  needs it.
  """
  reset_key, stepped = _next_step(transitions, state, action)
  return control_flow.select_reset(
      state.last(),
      transitions.reset,
      (reset_key, state),
      stepped,
      chunk=chunk,
      conditional=conditional,
  )


def _next_step(transitions, state, action):
  """`(reset_key, stepped)`: a next-step auto-reset's keys split from the
  state's (`keys.next_step_keys`) and the step of the world, which a LAST
  state's restart replaces."""
  reset_key, step_key = keys_lib.next_step_keys(state.key)
  return reset_key, transitions.step(state.replace(key=step_key), action)


def _step_then_restart(transitions, chunk, conditional, state, action):
  """Same-step auto-reset: a world whose episode just ended restarts."""
  stepped = transitions.step(state, action)
  return control_flow.select_reset(
      stepped.last(),
      transitions.restart,
      (stepped,),
      stepped,
      chunk=chunk,
      conditional=conditional,
  )
