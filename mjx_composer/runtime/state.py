"""`State`: everything one world carries from one `step` to the next.

A `State` is a pytree (a `flax.struct` dataclass): `Environment.reset` makes
one, `Environment.step` maps one to the next, and `jax.vmap` gives every leaf
a leading world axis. It holds three kinds of per-world state, each with its
own lifetime:

| lifetime | declared by | read and written through | field |
|---|---|---|---|
| one episode | `Task.initial_task_state()`, `Entity.initial_state()` | `physics.task_state`, `physics.update_task_state(...)`, `physics.entity_state(entity)`, `physics.update_entity_state(entity, ...)` | `task_state`, `entity_states` |
| the world's life (across auto-resets) | created in `initialize_episode` | `physics.get_persistent(name)`, `physics.set_persistent(name, value)` | `persistent` |
| the world's model (across auto-resets) | a hook's write to a model field (reported by `Environment.per_world_model_fields`) | `physics.model`, `physics.bind(el).set(...)` | `model_fields` |

`Environment.reset(key)` starts all three afresh; an auto-reset starts the
episode state afresh and keeps the other two, as composer's physics keeps its
model between episodes.
"""

from __future__ import annotations

import enum
from typing import Any

from flax import struct
import jax

from mjx_composer import physics as physics_lib


class StepType(enum.IntEnum):
  """dm_env's step types, as stored in `State.step_type`."""

  FIRST = 0
  MID = 1
  LAST = 2


@struct.dataclass
class Episode:
  """Running counters of the episode that `State.data` belongs to.

  Under `auto_reset='same_step'` a LAST state already holds the next
  episode, so its counters are zero while `State.metrics` reports the
  episode that ended (as `observation` and `final_observation` differ).

  Attributes:
    length: control steps taken in the episode.
    total_reward: the sum of its rewards so far.
  """

  length: jax.Array
  total_reward: jax.Array


@struct.dataclass
class State(physics_lib.WorldFields):
  """One world's state, carried between `step` calls (batched under vmap).

  Its first fields are the world's `physics_lib.WorldFields` (`data`,
  `task_state`, `entity_states`, `model_fields`, `persistent` and the static
  `scheduled_hooks`); `Transitions.physics(state)` is its `Physics`.

  Attributes:
    obs_state: the observation updater's ring buffers and counters.
    observation: the observation of this timestep.
    final_observation: the last observation of the episode that ended at this
      step (equal to `observation` except under same-step auto-reset).
    reward: the reward of the transition into this timestep (0 at FIRST).
    discount: its discount (1 at FIRST).
    step_type: a `StepType` value (int32).
    terminated: the episode ended by termination or a failed step
      (divergence, a non-finite action, reward, discount or observation).
    truncated: the episode ended at the time limit.
    metrics: this timestep's report, per world: `episode_return` and
      `episode_length` of the episode the transition belongs to; the flags
      of a failed step, `diverged`, `nonfinite_action`, `nonfinite_reward`
      and `nonfinite_observation` (`runtime.episode`); `overflow` (MuJoCo
      Warp dropped contacts or constraints this episode); `init_failures`,
      `init_failed`; and the task's `get_metrics`.
    episode: the running `Episode` counters.
    key: the world's PRNG key for what comes next.
    stored_first: the copy of the world's first state that its
      auto-resets restore, where `fixed_initial_state` makes every episode
      start as the first and the reset reads nothing else the world
      carries (`runtime.stored_restart`); else None (no leaves).
  """

  obs_state: Any
  observation: Any
  final_observation: Any
  reward: jax.Array
  discount: jax.Array
  step_type: jax.Array
  terminated: jax.Array
  truncated: jax.Array
  metrics: dict
  episode: Episode
  key: jax.Array
  stored_first: Any = struct.field(default=None, kw_only=True)

  @property
  def steps(self) -> jax.Array:
    """Control steps taken in the episode `data` belongs to."""
    return self.episode.length

  def first(self):
    return self.step_type == StepType.FIRST

  def mid(self):
    return self.step_type == StepType.MID

  def last(self):
    return self.step_type == StepType.LAST
