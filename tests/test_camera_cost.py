"""benchmarks/camera_cost.py builds what it measures (traced, not compiled)."""

import os
import sys

import jax

sys.path.insert(
    0, os.path.join(os.path.dirname(os.path.dirname(__file__)), 'benchmarks')
)
import camera_cost  # pylint: disable=g-import-not-at-top,wrong-import-position


def test_the_camera_is_observed_at_the_asked_size():
  for size, kind, shape in (
      (0, 'depth', None),
      (8, 'depth', (1, 8, 8)),
      (6, 'rgb', (1, 6, 6, 3)),
  ):
    env = camera_cost.make_env(size, kind)
    state = jax.eval_shape(env.reset, jax.random.key(0))
    if shape is None:
      assert 'camera' not in state.observation
    else:
      assert state.observation['camera'].shape == shape
    assert 'arm/joint_positions' in state.observation
