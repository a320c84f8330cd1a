"""Tests for `mjx_composer.observation.obs_buffer` (ports obs_buffer_test)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_composer.observation import obs_buffer


def _arrival_buffer(buffer_size, max_delay, shape=()):
  capacity = obs_buffer.arrival_capacity(buffer_size, max_delay, 1)
  return capacity, jax.tree.map(
      jnp.zeros_like,
      obs_buffer.arrival_init(
          capacity, {'value': jnp.zeros(shape)}, 0, 0, None, None, False
      ),
  )


def _empty(buffer):
  """An arrival buffer with no samples at all (not even timestamp 0)."""
  return buffer.replace(timestamps=jnp.full_like(buffer.timestamps, -1))


def test_out_of_order_arrival():
  # composer: insert (0, delay 4, 1), (1, delay 2, 2), (2, delay 3, 3).
  _, buffer = _arrival_buffer(buffer_size=3, max_delay=4)
  buffer = _empty(buffer)
  for timestamp, delay, value in [(0, 4, 1.0), (1, 2, 2.0), (2, 3, 3.0)]:
    buffer = obs_buffer.arrival_insert(
        buffer, {'value': jnp.float32(value)}, timestamp, delay, True
    )
  expected = {
      2: [0, 0, 0],
      3: [0, 0, 2],
      4: [0, 2, 1],
      5: [2, 1, 3],
      6: [2, 1, 3],
  }
  for t, values in expected.items():
    read, _ = obs_buffer.arrival_read(buffer, t, 3, 'value')
    np.testing.assert_array_equal(read, values, err_msg=f't={t}')


def test_arrival_ties_are_ordered_by_timestamp():
  _, buffer = _arrival_buffer(buffer_size=2, max_delay=3)
  buffer = _empty(buffer)
  # Both arrive at 3; the older sample comes first, as with composer's insort.
  buffer = obs_buffer.arrival_insert(
      buffer, {'value': jnp.float32(1.0)}, 0, 3, True
  )
  buffer = obs_buffer.arrival_insert(
      buffer, {'value': jnp.float32(2.0)}, 1, 2, True
  )
  read, timestamps = obs_buffer.arrival_read(buffer, 3, 2, 'value')
  np.testing.assert_array_equal(read, [1.0, 2.0])
  np.testing.assert_array_equal(timestamps, [0, 1])


def test_arrival_insert_respects_mask():
  _, buffer = _arrival_buffer(buffer_size=1, max_delay=0)
  buffer = _empty(buffer)
  buffer = obs_buffer.arrival_insert(
      buffer, {'value': jnp.float32(5.0)}, 0, 0, False
  )
  read, timestamps = obs_buffer.arrival_read(buffer, 10, 1, 'value')
  np.testing.assert_array_equal(read, [0.0])
  np.testing.assert_array_equal(timestamps, [-1])


@pytest.mark.parametrize('shape', [(), (3, 3)])
def test_strip_singleton_buffer_dim(shape):
  values = jnp.ones((1,) + shape)
  stripped = obs_buffer.strip_or_aggregate(values, None, True)
  assert stripped.shape == shape
  kept = obs_buffer.strip_or_aggregate(values, None, False)
  assert kept.shape == (1,) + shape
  several = obs_buffer.strip_or_aggregate(jnp.ones((2,) + shape), None, True)
  assert several.shape == (2,) + shape


def test_planner_every_substep_buffer_one():
  # composer's planner: buffer 1, interval 1, delay 0, 20 sub-steps per
  # control step schedules only sub-step 20.
  schedule = obs_buffer.ConstantSchedule.plan(
      update_interval=1, delay=0, buffer_size=1, n=20
  )
  assert schedule.substeps == frozenset({20})
  assert schedule.capacity == 1
  assert schedule.static_slots and not schedule.masked


def test_planner_delayed_interval():
  # composer plans (2,3), (6,3), (10,3) for interval 2, delay 3, buffer 1 and
  # 5 sub-steps per control step over 2 steps. The reads at 5 and 10 see 2 and
  # 6; the read at 15 sees 12, so 10 is never seen and we never take it.
  schedule = obs_buffer.ConstantSchedule.plan(
      update_interval=2, delay=3, buffer_size=1, n=5
  )
  assert schedule.substeps == frozenset({1, 2})  # 6 = 5 + 1, 2, 12 = 10 + 2.
  assert schedule.masked  # 2 does not divide 5: taken only where t is even.
  for t, newest in [(5, 2), (10, 6), (15, 12)]:
    _, indices = schedule.read_indices(jnp.int32(t))
    np.testing.assert_array_equal(indices * 2, [newest])


def test_planner_static_slots_for_averaging():
  # buffer_size = n, interval 1: a sample every sub-step, slot = sub-step.
  schedule = obs_buffer.ConstantSchedule.plan(
      update_interval=1, delay=0, buffer_size=4, n=4
  )
  assert schedule.static_slots and schedule.capacity == 4
  assert schedule.substeps == frozenset({1, 2, 3, 4})
  slots, _ = schedule.read_indices(jnp.int32(8))
  assert isinstance(slots, np.ndarray)
  np.testing.assert_array_equal(slots, [1, 2, 3, 0])
  assert [schedule.write_slot(None, j) for j in (1, 2, 3, 4)] == [1, 2, 3, 0]


def test_planner_rejects_invalid_options():
  with pytest.raises(ValueError, match='Invalid schedule'):
    obs_buffer.ConstantSchedule.plan(
        update_interval=0, delay=0, buffer_size=1, n=1
    )


def test_ring_read_pads_with_initial_value():
  schedule = obs_buffer.ConstantSchedule.plan(
      update_interval=1, delay=2, buffer_size=3, n=1
  )
  ring = obs_buffer.ring_init(schedule, {'value': jnp.float32(7.0)}, True)
  values, timestamps = obs_buffer.ring_read(
      schedule, ring, jnp.int32(0), 'value'
  )
  np.testing.assert_array_equal(values, [7.0, 7.0, 7.0])
  np.testing.assert_array_equal(timestamps, [-1, -1, -1])
  ring = obs_buffer.ring_write(
      schedule, ring, {'value': jnp.float32(8.0)}, jnp.int32(1), 1
  )
  ring = obs_buffer.ring_write(
      schedule, ring, {'value': jnp.float32(9.0)}, jnp.int32(2), 1
  )
  values, timestamps = obs_buffer.ring_read(
      schedule, ring, jnp.int32(2), 'value'
  )
  np.testing.assert_array_equal(values, [7.0, 7.0, 7.0])  # sample 0 is real.
  np.testing.assert_array_equal(timestamps, [-1, -1, 0])
  zero = obs_buffer.ring_init(schedule, {'value': jnp.float32(7.0)}, False)
  values, _ = obs_buffer.ring_read(schedule, zero, jnp.int32(2), 'value')
  np.testing.assert_array_equal(values, [0.0, 0.0, 7.0])
