"""The bundled reach task: per-episode domain randomization, per world."""

import jax
import numpy as np
import pytest

from mjx_composer import environment
from mjx_composer.tasks import reach


@pytest.fixture(scope='module')
def reach_env():
  return environment.Environment(reach.Reach(), time_limit=0.1)


def test_every_world_draws_its_own_colours_masses_sizes_friction_and_gears(
    reach_env,
):
  worlds = 8
  states = jax.jit(jax.vmap(reach_env.reset))(
      jax.random.split(jax.random.key(0), worlds)
  )
  model = reach_env.mj_model
  fields = states.model_fields
  ball = model.geom('ball/geom').id
  ground = model.geom('ground').id
  links = [model.body(name).id for name in ('arm/upper', 'arm/lower')]
  gears = fields['actuator_gear'][:, :, 0]
  varied = {
      'ball colour': fields['geom_rgba'][:, ball, :3],
      'ball radius': fields['geom_size'][:, ball, 0],
      'ball friction': fields['geom_friction'][:, ball, 0],
      'floor friction': fields['geom_friction'][:, ground, 0],
      'link masses': fields['body_mass'][:, links],
      'motor gears': gears,
  }
  for name, values in varied.items():
    values = np.asarray(values).reshape(worlds, -1)
    assert len(np.unique(values[:, 0])) == worlds, name
  # Multiplicative ranges around the compiled values.
  np.testing.assert_array_less(
      np.abs(gears / model.actuator_gear[:, 0] - 1), 0.2 + 1e-6
  )
  radius = np.asarray(fields['geom_size'][:, ball, 0])
  assert np.all(
      (radius > 0.7 * model.geom_size[ball, 0] - 1e-6)
      & (radius < 1.3 * model.geom_size[ball, 0] + 1e-6)
  )
  # The ball is placed resting on the floor at its own (varied) radius.
  ball_body = model.body('ball/').id
  z = np.asarray(states.data.xpos[:, ball_body, 2])
  np.testing.assert_allclose(z, radius, rtol=1e-5)
  # Masses follow the varied densities through the compiler's geom inertia.
  upper_mass = np.asarray(fields['body_mass'][:, links[0]])
  assert np.all(
      np.abs(upper_mass / model.body_mass[links[0]] - 1) <= 0.3 + 1e-5
  )


def test_without_randomization_nothing_model_related_is_per_world():
  env = environment.Environment(reach.Reach(randomize=False), time_limit=0.1)
  state = jax.eval_shape(env.reset, jax.random.key(0))
  assert not state.model_fields
