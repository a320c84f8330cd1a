"""Episode rules: termination, truncation, divergence, metrics, auto-reset.

What ends an episode (`step_type == LAST`), for one world:

* termination (`task.should_terminate_episode`): discount from the task;
* truncation at the time limit: LAST with the task's discount (dm_env's
  convention), `truncated=True`. The limit counts control steps
  (`step_limit`), not float32 time;
* a failed step, as composer ends the episode on a `PhysicsError` with
  `raise_exception_on_physics_error=False`: LAST, `terminated=True`, reward
  0 and discount 0, the task's metrics reported as 0, and a flag in the
  metrics saying why (1 at that step, else 0; one cause may raise two: a
  NaN command makes the reward and the observation non-finite):

  - `diverged`: a non-finite qpos, qvel, qacc or act after the step;
  - `nonfinite_action`: the action held a NaN or an infinity. The step runs
    with a zero action instead (`checked_action`), on every backend alike:
    MuJoCo computes no actuator force from a control it finds bad, and
    MuJoCo Warp would clamp a NaN control to its lower bound;
  - `nonfinite_reward`: the task's reward or discount was not finite (with
    finite physics, e.g. a NaN command in the task state);
  - `nonfinite_observation`: the observation held a non-finite entry (with
    finite physics);
  - `init_failed` (set at the reset, kept for the episode): every
    initialization attempt failed, so the world was held at what the reset
    started from (`Transitions.initialize`) and its first step ends the
    episode, which an auto-reset then resamples.

  Only that world is affected; its next reset replaces all of its data.

The reward, discount and observations a world returns are always finite
(its `data` is not: a diverged world keeps its physics until the reset).
A failed step's reward and discount are 0, and every non-finite entry of
an observation is returned as 0 (`zero_nonfinite`), at every step and at
reset, whatever the cause (a diverged world's observation included). Zero,
not the last finite value: it needs no extra state, it exists at reset
too, where there is no previous value, and it is what `ObservationPadding
.ZERO` already returns for an observation not yet sampled; the flag and
LAST (discount 0) tell a learner not to bootstrap from it. A FIRST state
whose observation held a non-finite entry reports `nonfinite_observation
= 1` too (it cannot end; its first step will, if the cause stays).

At reset, an `initialize_episode` hook that leaves a non-finite qpos, qvel,
act, ctrl, mocap_pos or mocap_quat fails that attempt
(`nonfinite_initial_state`), as `physics.fail_initialization()` does: the
attempt is retried and counted in `metrics['init_failures']`. Where the
last attempt fails too (`metrics['init_failed']`), the failed values are
never run: the world keeps what the reset started from and its first step
ends the episode (LAST, reward 0, discount 0).

Reported, not ended: `metrics['overflow'] = 1` from the step at which
MuJoCo Warp first dropped a contact or constraint row of the world (its
fixed buffers, `backend.overflow`) to the end of that episode; always 0 on
'jax', which has no fixed buffers.

Auto-reset, per world (`control_flow.select_reset` selects it, or the fused
restart, `fused_restart`, computes it in the sub-step loop):

* `'next_step'` (composer): the step after a LAST ignores the action and
  returns the FIRST state of a new episode.
* `'same_step'` (training loops): a step that ends an episode returns LAST
  with that transition's reward and discount, the new episode's first
  observation in `observation`, and the ended episode's last observation in
  `final_observation`; the next step continues the new episode.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from mjx_composer import physics as physics_lib
from mjx_composer.platform import backend
from mjx_composer.runtime import state as state_lib

AUTO_RESET_MODES = ('next_step', 'same_step')


def step_limit(time_limit: float, control_timestep: float) -> float:
  """Control steps in an episode: `ceil(time_limit / control_timestep)`.

  `math.inf` for an infinite time limit. The small tolerance keeps a limit
  that is a whole number of control steps from rounding up.
  """
  if math.isinf(time_limit):
    return math.inf
  return max(1, math.ceil(time_limit / control_timestep - 1e-9))


def diverged(data) -> jax.Array:
  """Whether any of qpos, qvel, qacc or act is not finite."""
  fields = [data.qpos, data.qvel, data.qacc, data.act]
  return jnp.logical_not(
      jnp.all(jnp.stack([jnp.all(jnp.isfinite(f)) for f in fields]))
  )


def finite(tree) -> jax.Array:
  """Whether every floating-point entry of `tree` is finite (a bool)."""
  flags = [
      jnp.all(jnp.isfinite(x))
      for x in jax.tree.leaves(tree)
      if jnp.issubdtype(jnp.result_type(x), jnp.inexact)
  ]
  if not flags:
    return jnp.ones((), bool)
  return jnp.all(jnp.stack(flags))


def zero_nonfinite(tree):
  """`tree` with every non-finite floating-point entry replaced by 0.

  Finite entries are returned unchanged, bit for bit.
  """

  def zero(x):
    if not jnp.issubdtype(jnp.result_type(x), jnp.inexact):
      return x
    return jnp.where(jnp.isfinite(x), x, jnp.zeros_like(x))

  return jax.tree.map(zero, tree)


def checked_action(action) -> tuple[jax.Array, jax.Array]:
  """`(action the step runs, whether the given one was not finite)`.

  A non-finite action is replaced by zeros as a whole (MuJoCo computes no
  actuator force at all when one control is bad), so that no hook, no
  physics and no task state sees it, on every backend. It is a flag, not
  an error: inside a jitted step nothing can raise, and composer's
  `Environment` does not check actions against their spec either (its
  physics raises `PhysicsError` on MuJoCo's bad-control warning).
  """
  bad = jnp.logical_not(finite(action))
  return jnp.where(bad, jnp.zeros_like(action), action), bad


def nonfinite_initial_state(data) -> jax.Array:
  """Whether an initialized episode's state is not finite: any of qpos,
  qvel, act, ctrl, mocap_pos or mocap_quat (what the physics starts from)."""
  fields = [
      data.qpos,
      data.qvel,
      data.act,
      data.ctrl,
      data.mocap_pos,
      data.mocap_quat,
  ]
  return jnp.logical_not(finite(fields))


def overflowed(data) -> jax.Array:
  """Whether MuJoCo Warp dropped contacts or constraints since the reset."""
  return backend.overflow(data) != 0


def outcome(task, method: str, physics):
  """`task.<method>(physics)` (an outcome method: `get_reward`,
  `get_discount`, `should_terminate_episode` or `get_metrics`), given a
  read-only physics.

  The outcome methods return values; a physics they wrote would be
  dropped, so a write raises `ReadOnlyPhysicsError` while the step is
  traced, and so does a result that holds a `Physics`: both name the
  method and say to move the write to `after_step`.
  """
  name = f'{type(task).__name__}.{method}'
  result = getattr(task, method)(physics.reading_only(name))
  if any(
      isinstance(leaf, physics_lib.Physics)
      for leaf in jax.tree.leaves(
          result, is_leaf=lambda x: isinstance(x, physics_lib.Physics)
      )
  ):
    raise physics_lib.ReadOnlyPhysicsError(
        f'{name} returned a Physics: it returns only its value, and a '
        "physics it returns is not kept. Move the write to the task's "
        "after_step hook (it runs after the control step's physics and "
        f'before {method}, and returns the physics), and return the value '
        'alone.'
    )
  return result


class EpisodeRules:
  """Decides how each step ends, and keeps the per-world metrics.

  Args:
    task: the `Task` (reward, discount, termination, metrics).
    limit: control steps before truncation (`step_limit`).
    reward_shape: the shape of the reward (`Environment.reward_spec`).
    discount_shape: the shape of the discount.
  """

  def __init__(self, task, limit: float, reward_shape, discount_shape):
    self._task = task
    self.step_limit = limit
    self._reward_shape = tuple(reward_shape)
    self._discount_shape = tuple(discount_shape)

  def _task_metrics(self, physics) -> dict:
    return {
        name: jnp.asarray(value, jnp.float32)
        for name, value in outcome(self._task, 'get_metrics', physics).items()
    }

  def start(self, physics, init_failures, observation) -> dict:
    """The `State` fields of an episode's FIRST timestep.

    `observation`: the first observation (returned with its non-finite
    entries zeroed, `zero_nonfinite`).
    """
    metrics = {
        'diverged': diverged(physics.data).astype(jnp.float32),
        'nonfinite_action': jnp.zeros((), jnp.float32),
        'nonfinite_reward': jnp.zeros((), jnp.float32),
        'nonfinite_observation': jnp.logical_not(finite(observation)).astype(
            jnp.float32
        ),
        'overflow': overflowed(physics.data).astype(jnp.float32),
        'episode_return': jnp.zeros((), jnp.float32),
        'episode_length': jnp.zeros((), jnp.int32),
        'init_failures': init_failures.astype(jnp.float32),
        'init_failed': physics.initialization_failed.astype(jnp.float32),
    }
    metrics.update(self._task_metrics(physics))
    observation = zero_nonfinite(observation)
    return dict(
        observation=observation,
        final_observation=observation,
        reward=jnp.zeros(self._reward_shape, jnp.float32),
        discount=jnp.ones(self._discount_shape, jnp.float32),
        step_type=jnp.asarray(state_lib.StepType.FIRST, jnp.int32),
        terminated=jnp.zeros((), bool),
        truncated=jnp.zeros((), bool),
        metrics=metrics,
        episode=state_lib.Episode(
            length=jnp.zeros((), jnp.int32),
            total_reward=jnp.zeros((), jnp.float32),
        ),
    )

  def end_of_step(
      self, previous: state_lib.State, physics, observation, action_nonfinite
  ) -> dict:
    """The `State` fields that say how the step from `previous` ended.

    Args:
      previous: the state the step started from.
      physics: the stepped `Physics` (after the `after_step` hooks).
      observation: the step's observation.
      action_nonfinite: whether the step's action was not finite
        (`checked_action`).
    """
    is_diverged = diverged(physics.data)
    reward = jnp.asarray(
        outcome(self._task, 'get_reward', physics), jnp.float32
    )
    discount = jnp.asarray(
        outcome(self._task, 'get_discount', physics), jnp.float32
    )
    # One cause per failure: the physics' divergence makes everything
    # computed from it non-finite, so the outputs' flags exclude it.
    finite_physics = jnp.logical_not(is_diverged)
    bad_reward = jnp.logical_and(
        finite_physics, jnp.logical_not(finite((reward, discount)))
    )
    bad_observation = jnp.logical_and(
        finite_physics, jnp.logical_not(finite(observation))
    )
    # A world whose initialization failed runs no episode: it ends here.
    init_failed = previous.metrics['init_failed'] > 0
    failed = jnp.any(
        jnp.stack(
            [
                is_diverged,
                action_nonfinite,
                bad_reward,
                bad_observation,
                init_failed,
            ]
        )
    )
    reward = jnp.where(failed, jnp.zeros_like(reward), reward)
    discount = jnp.where(failed, jnp.zeros_like(discount), discount)
    length = previous.episode.length + 1
    terminated = jnp.logical_or(
        jnp.asarray(
            outcome(self._task, 'should_terminate_episode', physics), bool
        ),
        failed,
    )
    truncated = jnp.logical_and(
        jnp.logical_not(terminated), length >= self.step_limit
    )
    last = jnp.logical_or(terminated, truncated)
    total_reward = previous.episode.total_reward + jnp.sum(reward)
    metrics = {
        'diverged': is_diverged.astype(jnp.float32),
        'nonfinite_action': action_nonfinite.astype(jnp.float32),
        'nonfinite_reward': bad_reward.astype(jnp.float32),
        'nonfinite_observation': bad_observation.astype(jnp.float32),
        'overflow': overflowed(physics.data).astype(jnp.float32),
        'episode_return': total_reward,
        'episode_length': length,
        'init_failures': previous.metrics['init_failures'],
        'init_failed': previous.metrics['init_failed'],
    }
    # A failed world's task metrics may be NaN-laden: report zeros instead.
    metrics.update(
        {
            k: jnp.where(failed, 0.0, v)
            for k, v in self._task_metrics(physics).items()
        }
    )
    step_type = jnp.where(
        last, state_lib.StepType.LAST, state_lib.StepType.MID
    ).astype(jnp.int32)
    observation = zero_nonfinite(observation)
    return dict(
        observation=observation,
        final_observation=observation,
        reward=reward,
        discount=discount,
        step_type=step_type,
        terminated=terminated,
        truncated=truncated,
        metrics=metrics,
        episode=state_lib.Episode(length=length, total_reward=total_reward),
    )


def reporting(restarted: state_lib.State, stepped: state_lib.State):
  """A same-step restart's FIRST state, reporting how the ended episode's
  last step ended (its step type, reward, discount, termination,
  truncation, final observation and metrics)."""
  return restarted.replace(
      step_type=stepped.step_type,
      reward=stepped.reward,
      discount=stepped.discount,
      terminated=stepped.terminated,
      truncated=stepped.truncated,
      final_observation=stepped.final_observation,
      metrics=stepped.metrics,
  )
