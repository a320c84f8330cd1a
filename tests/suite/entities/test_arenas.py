"""Arenas: Floor, and WalledArena's per-world regeneration."""

import jax
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.suite.entities import arenas
from mjx_composer.suite.entities import props
from mjx_composer.variation import distributions

_LOW, _HIGH = np.array([0.3, 0.4]), np.array([0.6, 0.8])


def _compiled(arena):
  spec, _ = arena.compose()
  model = spec.compile()
  data = mujoco.MjData(model)
  mujoco.mj_forward(model, data)
  return model, data


def test_floor():
  floor = arenas.Floor(size=(3.0, 2.0), reflectance=0.5)
  assert isinstance(floor, composer.Arena)
  assert floor.size == (3.0, 2.0)
  model, _ = _compiled(floor)
  ground = model.geom('ground')
  assert floor.ground_geoms[0].name == 'ground'
  assert ground.type == mujoco.mjtGeom.mjGEOM_PLANE
  np.testing.assert_allclose(ground.size[:2], [3.0, 2.0])
  assert model.camera('top_camera').id >= 0
  # composer's host-side call is a no-op, as locomotion's Floor's.
  assert floor.regenerate(np.random.RandomState(0)) is None
  assert floor.regenerate() is None
  sentinel = object()
  assert floor.regenerate_world(sentinel, jax.random.key(0)) is sentinel


def test_walls_face_inwards_and_contain_props():
  arena = arenas.WalledArena(size=(0.5, 0.3))
  model, data = _compiled(arena)
  expected = {
      'wall_px': ([0.5, 0, 0.05], [-1, 0, 0]),
      'wall_nx': ([-0.5, 0, 0.05], [1, 0, 0]),
      'wall_py': ([0, 0.3, 0.05], [0, -1, 0]),
      'wall_ny': ([0, -0.3, 0.05], [0, 1, 0]),
  }
  for wall, (pos, normal) in expected.items():
    geom = model.geom(wall)
    assert geom.type == mujoco.mjtGeom.mjGEOM_PLANE
    np.testing.assert_allclose(data.geom_xpos[geom.id], pos, atol=1e-9)
    np.testing.assert_allclose(
        data.geom_xmat[geom.id].reshape(3, 3)[:, 2], normal, atol=1e-9
    )
  assert [w.name for w in arena.walls] == list(expected)
  # A ball pushed through a wall is pushed back (a penetrating contact).
  ball = props.Sphere(radius=0.05, name='ball')
  arena.add_free_entity(ball).pos = [0.52, 0.0, 0.2]
  model, data = _compiled(arena)
  walls = {model.geom(w).id for w in expected}
  touching = [
      c for c in data.contact[: data.ncon] if {c.geom1, c.geom2} & walls
  ]
  assert touching and touching[0].dist < 0


@pytest.fixture(scope='module')
def regenerated():
  arena = arenas.WalledArena(
      size=(0.5, 0.5),
      wall_height=0.2,
      size_variation=distributions.Uniform(_LOW, _HIGH),
  )
  # MJX needs a degree of freedom to run.
  arena.add_free_entity(props.Sphere(name='ball')).pos = [0.0, 0.0, 0.2]
  env = composer.Environment(composer.NullTask(arena))
  states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), 16))
  return arena, env, states


def test_regenerate_matches_a_recompiled_arena(regenerated):
  arena, env, states = regenerated
  assert set(states.model_fields) == {'geom_pos', 'geom_size'}
  geom_pos = np.asarray(states.model_fields['geom_pos'])
  geom_size = np.asarray(states.model_fields['geom_size'])
  wall_px = env.mj_model.geom('wall_px').id
  wall_py = env.mj_model.geom('wall_py').id
  sizes = np.stack([geom_pos[:, wall_px, 0], geom_pos[:, wall_py, 1]], -1)
  assert np.all((sizes >= _LOW) & (sizes <= _HIGH))
  assert np.std(sizes[:, 0]) > 0.03
  for world in range(4):
    model, _ = _compiled(arenas.WalledArena(size=sizes[world], wall_height=0.2))
    names = ['ground'] + [w.name for w in arena.walls]
    for name in names:
      geom = model.geom(name)
      np.testing.assert_allclose(
          geom_pos[world, geom.id], geom.pos, atol=1e-6, err_msg=name
      )
      np.testing.assert_allclose(
          geom_size[world, geom.id], geom.size, atol=1e-6, err_msg=name
      )
      # Planes' derived fields do not depend on their size.
      np.testing.assert_allclose(
          env.mj_model.geom_rbound[geom.id], model.geom_rbound[geom.id]
      )
      np.testing.assert_allclose(
          env.mj_model.geom_aabb[geom.id], model.geom_aabb[geom.id]
      )
  physics = env.physics(jax.tree.map(lambda x: x[0], states))
  np.testing.assert_allclose(arena.interior_size(physics), sizes[0], atol=1e-6)


def test_regenerate_without_a_variation_is_a_no_op():
  arena = arenas.WalledArena()
  assert arena.size_variation is None
  assert arena.regenerate(np.random.RandomState(0)) is None
  sentinel = object()
  assert arena.regenerate_world(sentinel, jax.random.key(0)) is sentinel


def test_per_world_fields_are_reported_with_the_hook_that_wrote_them(
    regenerated,
):
  arena, env, _ = regenerated
  writers = env.per_world_model_fields
  assert set(writers) == {'geom_pos', 'geom_size'}
  expected = f'{type(arena).__name__}({arena.name!r}).initialize_episode'
  assert writers['geom_pos'] == writers['geom_size'] == (expected,)
