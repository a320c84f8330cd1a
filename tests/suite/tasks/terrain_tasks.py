"""Helpers of the tests of the tasks on generated terrain.

`rollout` runs a few batched steps of a task's environment and returns the
states on the host; `assert_spawned_on_its_level` checks that every world
started on the spawn platform of a tile of its curriculum level. Used by
`test_locomotion_joystick_terrain.py` and `test_tasks_walk_terrain.py`.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_composer import environment


def rollout(task, *, worlds, steps, time_limit, action_scale=0.3, seed=2):
  """`(env, states, step)`: `steps` batched steps of random actions.

  The actions are U(-action_scale, action_scale), drawn from seed 0; the
  worlds reset from `seed`. `states` (the reset's first) stay on the device
  (`jax.device_get` them to read): `step`, the jitted `vmap(env.step)`,
  takes them back without tracing again, for tests that go on.
  """
  env = environment.Environment(task, time_limit=time_limit)
  keys = jax.random.split(jax.random.key(seed), worlds)
  states = [jax.jit(jax.vmap(env.reset))(keys)]
  step = jax.jit(jax.vmap(env.step))
  size = env.action_spec().shape
  actions = np.random.default_rng(0).uniform(
      -action_scale, action_scale, (steps, worlds) + size
  )
  for action in actions:
    states.append(step(states[-1], jnp.asarray(action, jnp.float32)))
  return env, states, step


def assert_spawned_on_its_level(env, state, height, spread):
  """Every world of `state` starts on a tile of its curriculum level.

  Its free joint's position lies within `spread` metres (per axis) of the
  spawn point of a tile of the level the `terrain_level` metric reports,
  `height` metres above it.
  """
  levels = state.metrics['terrain_level']
  points = env.task.terrain.spawn_points
  assert set(levels) <= set(range(env.task.terrain.levels))
  for world in range(len(levels)):
    level = int(levels[world])
    xy = state.data.qpos[world, :2]
    gaps = np.max(np.abs(points[level, :, :2] - xy), axis=-1)
    assert gaps.min() <= spread + 1e-5  # On a platform of its level.
    kind = int(np.argmin(gaps))
    above = state.data.qpos[world, 2] - points[level, kind, 2]
    assert above == pytest.approx(height, abs=1e-5)
