"""Episode rules: termination, truncation, divergence, metrics, auto-reset.

What ends an episode (`step_type == LAST`), for one world:

* termination (`task.should_terminate_episode`): discount from the task;
* truncation at the time limit: LAST with the task's discount (dm_env's
  convention), `truncated=True`. The limit counts control steps
  (`step_limit`), not float32 time;
* divergence (any non-finite qpos, qvel, qacc or act after the step): LAST
  with reward 0 and discount 0, `metrics['diverged'] = 1`. Only that world is
  affected; its next reset replaces all of its data.

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


def overflowed(data) -> jax.Array:
  """Whether MuJoCo Warp dropped contacts or constraints since the reset."""
  return backend.overflow(data) != 0


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
        for name, value in self._task.get_metrics(physics).items()
    }

  def start(self, physics, init_failures) -> dict:
    """The `State` fields of an episode's FIRST timestep."""
    metrics = {
        'diverged': diverged(physics.data).astype(jnp.float32),
        'overflow': overflowed(physics.data).astype(jnp.float32),
        'episode_return': jnp.zeros((), jnp.float32),
        'episode_length': jnp.zeros((), jnp.int32),
        'init_failures': init_failures.astype(jnp.float32),
        'init_failed': physics.initialization_failed.astype(jnp.float32),
    }
    metrics.update(self._task_metrics(physics))
    return dict(
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

  def end_of_step(self, previous: state_lib.State, physics) -> dict:
    """The `State` fields that say how the step from `previous` ended."""
    is_diverged = diverged(physics.data)
    reward = jnp.asarray(self._task.get_reward(physics), jnp.float32)
    discount = jnp.asarray(self._task.get_discount(physics), jnp.float32)
    reward = jnp.where(is_diverged, jnp.zeros_like(reward), reward)
    discount = jnp.where(is_diverged, jnp.zeros_like(discount), discount)
    length = previous.episode.length + 1
    terminated = jnp.logical_or(
        jnp.asarray(self._task.should_terminate_episode(physics), bool),
        is_diverged,
    )
    truncated = jnp.logical_and(
        jnp.logical_not(terminated), length >= self.step_limit
    )
    last = jnp.logical_or(terminated, truncated)
    total_reward = previous.episode.total_reward + jnp.sum(reward)
    metrics = {
        'diverged': is_diverged.astype(jnp.float32),
        'overflow': overflowed(physics.data).astype(jnp.float32),
        'episode_return': total_reward,
        'episode_length': length,
        'init_failures': previous.metrics['init_failures'],
        'init_failed': previous.metrics['init_failed'],
    }
    # A diverged world's task metrics are NaN-laden: report zeros instead.
    metrics.update(
        {
            k: jnp.where(is_diverged, 0.0, v)
            for k, v in self._task_metrics(physics).items()
        }
    )
    step_type = jnp.where(
        last, state_lib.StepType.LAST, state_lib.StepType.MID
    ).astype(jnp.int32)
    return dict(
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
