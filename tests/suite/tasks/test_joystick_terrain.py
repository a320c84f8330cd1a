"""TerrainJoystick: the Go1 joystick composed from the locomotion kit.

One environment (a tiny terrain of 2 levels x 3 kinds of 2 m tiles, 2
worlds, 3 control steps) is built for the module.
"""

import jax
import numpy as np
import pytest

from mjx_composer import environment
from mjx_composer.suite.locomotion.terrain import terrain_part
from mjx_composer.suite.tasks import joystick
from mjx_composer.suite.tasks import joystick_terrain
from mjx_composer.suite.tasks import registry
from tests.suite.tasks import terrain_tasks

_WORLDS = 2
_STEPS = 3


@pytest.fixture(scope='module')
def run():
  task = joystick_terrain.TerrainJoystick(
      kinds=('flat', 'pyramid_stairs', 'random_uniform'),
      levels=2,
      tile_size=2.0,
      initial_levels=(0, 1),
      actuation_delay=(1, 3),
      scan_size=(0.4, 0.2),
      push_interval=0,
  )
  env, states, step = terrain_tasks.rollout(
      task, worlds=_WORLDS, steps=_STEPS, time_limit=1.0
  )

  @jax.jit
  @jax.vmap
  def scan(state):
    return task.height_scan.scan(env.physics(state))[0]

  scans = [scan(state) for state in states[-2:]]
  return env, jax.device_get(states), jax.device_get(scans), step


def test_worlds_spawn_on_a_tile_of_their_level(run):
  env, states, *_ = run
  # Joystick's spread of the initial position: U(-0.5, 0.5) m per axis.
  terrain_tasks.assert_spawned_on_its_level(
      env, states[0], env.task.go1.home_height + 0.01, spread=0.5
  )


def test_policy_sees_the_height_scan_and_the_critic_its_clean_twin(run):
  env, states, (previous, scan), _ = run
  rays = len(env.task.height_scan.points)
  assert rays == 5 * 3
  # The critic's last entries are the clean scan of the step's end.
  np.testing.assert_allclose(
      states[-1].observation['critic'][:, -rays:], scan, atol=1e-5
  )
  # The policy's: the previous step's scan (a sample visible one sub-step
  # after it is taken), with U(-0.1, 0.1) m noise.
  error = np.abs(states[-1].observation['policy'][:, -rays:] - previous)
  assert np.all(error <= 0.1 + 1e-5) and np.any(error > 1e-3)
  # About the trunk's height below it, standing on a platform.
  assert np.all(scan < -0.1) and np.all(scan > -0.6)


def test_delay_is_drawn_per_world_in_its_range(run):
  _, states, *_ = run
  delays = states[0].task_state['actuation_delay_steps']
  assert np.all((delays >= 1) & (delays <= 3))
  for state in states[1:]:
    np.testing.assert_array_equal(
        state.task_state['actuation_delay_steps'], delays
    )
    # ctrl reads the task's targets; the delay acts between them and the
    # motors.
    history = state.task_state['actuation_delay_history']
    np.testing.assert_allclose(history[:, 0], state.data.ctrl, atol=1e-6)


def test_leaving_the_terrain_ends_the_episode_as_a_truncation(run):
  """Near the edge, where the ground ends, an episode ends with discount 1
  (not a fall); a fall's discount is 0."""
  env, states, _, step = run
  state = states[-1]
  qpos = np.array(state.data.qpos)
  edge = env.task.terrain.half_extent[0]
  # World 0 on the flat border, half a metre from its far edge.
  qpos[0, 0] = edge - terrain_part.OUT_OF_BOUNDS_MARGIN / 2
  # World 1 upside down where it stands (half a turn about x).
  qpos[1, 3:7] = [0.0, 1.0, 0.0, 0.0]
  moved = state.replace(data=state.data.replace(qpos=qpos))
  after = jax.device_get(step(moved, np.zeros((_WORLDS, 12), np.float32)))
  np.testing.assert_array_equal(after.step_type, [2, 2])  # LAST, both.
  np.testing.assert_array_equal(after.discount, [1.0, 0.0])
  # A world standing anywhere on the grid is inside.
  physics = env.physics(jax.tree.map(lambda x: x[0], states[-1]))
  assert not env.task.out_of_bounds(physics)


def test_registered():
  assert 'joystick_terrain' in registry.names()
  with pytest.raises(TypeError, match='terrain'):
    joystick_terrain.TerrainJoystick(terrain='rough')


def test_height_scan_off_leaves_joystick_groups():
  off = environment.Environment(
      joystick_terrain.TerrainJoystick(
          kinds=('flat',), levels=1, initial_levels=(0, 0), height_scan=False
      ),
      time_limit=1.0,
  )
  flat = environment.Environment(
      joystick.Joystick(terrain='flat'), time_limit=1.0
  )
  assert off.task.height_scan is None
  assert not {'height_scan', 'privileged_height_scan'} & set(
      off.task.task_observables
  )
  assert {k: v.shape for k, v in off.observation_spec().items()} == {
      k: v.shape for k, v in flat.observation_spec().items()
  }
