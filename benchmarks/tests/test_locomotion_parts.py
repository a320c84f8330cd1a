"""benchmarks/locomotion_parts.py: the programs' environments and the
derived figures (host builds only; nothing is compiled)."""

import mujoco
import numpy as np
import pytest

import locomotion_parts  # benchmarks/locomotion_parts.py


def test_parts_off_switches_off_what_the_constructor_allows():
  envs = locomotion_parts.make_envs(['raw', 'joystick_terrain_off'])
  # raw steps joystick_terrain's model.
  assert set(envs) == {'joystick_terrain', 'joystick_terrain_off'}
  on = envs['joystick_terrain'].task
  off = envs['joystick_terrain_off'].task
  assert on.height_scan is not None and off.height_scan is None
  assert off.terrain.kinds == ('flat',) and off.terrain.levels == 1
  assert not off.terrain.heights.any()
  assert off.curriculum.initial_levels == (0, 0)
  assert off.actuation_delay.delay_range == (0, 0)
  assert on.actuation_delay.delay_range == (0, 2)
  assert on.terrain.heights.any()
  # Every program on terrain: one ground geom, the height field.
  for env in envs.values():
    assert env.mj_model.ngeom == len(env.task.terrain.ground_geoms) + len(
        [g for g in env.task.go1.mjcf_model.geoms]
    )


def test_raw_starts_on_the_first_spawn_platform():
  env = locomotion_parts.make_envs(['joystick_terrain'])['joystick_terrain']
  qpos = locomotion_parts.raw_start(env)
  model = env.mj_model
  (free,) = np.flatnonzero(model.jnt_type == mujoco.mjtJoint.mjJNT_FREE)
  adr = model.jnt_qposadr[free]
  spawn = env.task.terrain.spawn_points[0, 0]
  np.testing.assert_allclose(
      qpos[adr : adr + 3], spawn + [0, 0, env.task.go1.home_height + 0.01]
  )
  np.testing.assert_array_equal(
      np.delete(qpos, range(adr, adr + 3)),
      np.delete(model.qpos0, range(adr, adr + 3)),
  )


def test_derive_divides_and_takes_the_scan_cost():
  measured = lambda per_s, seconds, state, compile_s: {
      'control_steps_per_s': per_s,
      'seconds_per_call': seconds,
      'state_bytes_per_world': state,
      'rollout_compile_s': compile_s,
  }
  row = {
      'worlds': 10,
      'raw': measured(400.0, 0.5, 100, 1.0),
      'joystick_terrain': measured(100.0, 2.0, 900, 9.0),
      'joystick_terrain_no_scan': measured(200.0, 1.0, 500, 6.0),
      'joystick': measured(250.0, 0.8, 400, 5.0),
  }
  locomotion_parts.derive(row, steps=20)
  assert row['joystick_terrain/raw'] == pytest.approx(0.25)
  assert row['joystick_terrain/flat'] == pytest.approx(0.4)
  assert row['joystick_terrain/flat_state'] == pytest.approx(900 / 400)
  assert row['joystick_terrain_no_scan/raw'] == pytest.approx(0.5)
  assert 'joystick/flat' not in row and 'raw/raw' not in row
  scan = row['height_scan']
  # (2.0 s - 1.0 s) over 10 worlds x 20 steps.
  assert scan['seconds_per_world_step'] == pytest.approx(1.0 / 200)
  assert scan['throughput_ratio'] == pytest.approx(0.5)
  assert scan['state_bytes_per_world'] == 400
  assert scan['rollout_compile_s'] == pytest.approx(3.0)
