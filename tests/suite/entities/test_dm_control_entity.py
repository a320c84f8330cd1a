"""dm_control's own walkers, arenas and props, used unchanged.

Five of them (`Floor`, `Ant`, `TargetSphere` and composer's `Primitive` and
`PositionDetector`) compose into one environment that steps batched;
`EmptyCorridor` with `RollingBallWithHead`, `Bowl`, the `Rat` and the CMU
humanoid compose and compile. The reference is dm_control's own composition
of the same classes (PyMJCF's `attach`, compiled by `mjcf.Physics`).
"""

from dm_control import mjcf
from dm_control.entities import props
from dm_control.locomotion.arenas import bowl
from dm_control.locomotion.arenas import corridors
from dm_control.locomotion.arenas import floors
from dm_control.locomotion.props import target_sphere
from dm_control.locomotion.walkers import ant
from dm_control.locomotion.walkers import cmu_humanoid
from dm_control.locomotion.walkers import jumping_ball
from dm_control.locomotion.walkers import rodent
import jax
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.suite.entities.dm_control_entity import DmControlEntity

_BATCH = 2


def _stepped_parts():
  """The five classes the batched environment steps."""
  return dict(
      arena=floors.Floor(size=(4, 4)),
      ant=ant.Ant(name='ant'),
      target=target_sphere.TargetSphere(name='target'),
      ball=props.Primitive(geom_type='sphere', size=[0.1], name='ball'),
      detector=props.PositionDetector(
          pos=(0, 0, 0.5), size=(1, 1, 1), name='detector'
      ),
  )


def _compose(parts, entity):
  """`parts` composed as the batched environment composes them, by
  `entity(part)` (a `DmControlEntity`, or the part itself for dm_control's
  own composition); returns the arena and the walker."""
  arena = entity(parts['arena'])
  walker = entity(parts['ant'])
  arena.add_free_entity(walker)
  arena.add_free_entity(entity(parts['ball']))
  arena.attach(entity(parts['target']))
  arena.attach(entity(parts['detector']))
  return arena, walker


class _Task(composer.NullTask):
  """Drives the walker's actuators with the action."""

  def __init__(self, arena, actuators):
    super().__init__(arena)
    self._actuators = actuators

  def before_step(self, physics, action, key):
    return physics.bind(self._actuators).set(ctrl=action)


@pytest.fixture(scope='module')
def scene():
  parts = _stepped_parts()
  arena, walker = _compose(parts, DmControlEntity)
  env = composer.Environment(_Task(arena, list(parts['ant'].actuators)))
  return env, parts, walker


def _assert_same_model(mine, theirs):
  for size in ('nq', 'nv', 'nu', 'nbody', 'ngeom', 'nsite', 'nsensor'):
    assert getattr(mine, size) == getattr(theirs, size), size
  for i in range(mine.nbody):
    assert mine.body(i).name == theirs.body(i).name
  np.testing.assert_allclose(mine.body_mass, theirs.body_mass, rtol=1e-6)
  np.testing.assert_allclose(mine.body_pos, theirs.body_pos, atol=1e-7)
  np.testing.assert_allclose(mine.geom_size, theirs.geom_size, rtol=1e-6)
  np.testing.assert_allclose(mine.qpos0, theirs.qpos0, atol=1e-7)


def test_five_dm_control_classes_step_batched(scene):
  env, parts, walker = scene
  reset = jax.jit(jax.vmap(env.reset))
  step = jax.jit(jax.vmap(env.step))
  state = reset(jax.random.split(jax.random.key(0), _BATCH))
  action = np.full((_BATCH, env.mj_model.nu), 0.5, np.float32)
  for _ in range(3):
    state = step(state, action)
  physics = env.physics(state)
  assert np.all(np.asarray(state.data.time) > 0)
  np.testing.assert_allclose(
      np.asarray(physics.bind(parts['ant'].actuators).ctrl), 0.5
  )
  torso = np.asarray(physics.bind(parts['ant'].root_body).xpos)
  assert torso.shape == (_BATCH, 3) and np.all(np.isfinite(torso))
  np.testing.assert_array_equal(
      torso, np.asarray(state.data.xpos)[:, env.mj_model.body('ant/torso').id]
  )
  # The MJCFFeature observables of the walker came along.
  assert 'joints_pos' in walker.observables.as_dict(fully_qualified=False)


def test_the_composed_model_is_dm_controls(scene):
  env, *_ = scene
  dm_arena, _ = _compose(_stepped_parts(), lambda part: part)
  _assert_same_model(
      env.mj_model, mjcf.Physics.from_mjcf_model(dm_arena.mjcf_model).model.ptr
  )


def test_a_corridor_with_a_rolling_ball_composes_as_dm_controls():
  def compose(entity):
    arena = entity(corridors.EmptyCorridor())
    arena.add_free_entity(entity(jumping_ball.RollingBallWithHead(name='ball')))
    return arena

  spec, _ = compose(DmControlEntity).compose()
  dm_root = compose(lambda part: part).mjcf_model
  _assert_same_model(
      spec.compile(), mjcf.Physics.from_mjcf_model(dm_root).model.ptr
  )


@pytest.mark.parametrize(
    'make_arena, make_walker',
    [
        (floors.Floor, rodent.Rat),
        (bowl.Bowl, cmu_humanoid.CMUHumanoidPositionControlledV2020),
    ],
)
def test_more_arenas_and_walkers_compose(make_arena, make_walker):
  arena = DmControlEntity(make_arena())
  arena.add_free_entity(DmControlEntity(make_walker()))
  spec, _ = arena.compose()
  mine = spec.compile()
  dm_arena = make_arena()
  dm_arena.add_free_entity(make_walker())
  theirs = mjcf.Physics.from_mjcf_model(dm_arena.mjcf_model).model.ptr
  for size in ('nq', 'nu', 'nbody', 'ngeom', 'nmesh', 'nhfield', 'nsensor'):
    assert getattr(mine, size) == getattr(theirs, size), size
  np.testing.assert_allclose(mine.body_mass, theirs.body_mass, rtol=1e-6)
