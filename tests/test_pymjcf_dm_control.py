"""dm_control's own walkers, arenas and props, used unchanged.

Five of them (`EmptyCorridor`, `Ant`, `RollingBallWithHead`, `TargetSphere`
and composer's `Primitive`) compose into one environment that steps batched;
`Floor`, `Bowl`, the `Rat` and the CMU humanoid compose and compile. The
reference is dm_control's own composition of the same classes (PyMJCF's
`attach`, compiled by `mjcf.Physics`).
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
from mjx_composer.entities.dm_control_entity import DmControlEntity

_BATCH = 2


def _parts():
  return dict(
      arena=corridors.EmptyCorridor(),
      ant=ant.Ant(name='ant'),
      ball=jumping_ball.RollingBallWithHead(name='ball'),
      target=target_sphere.TargetSphere(name='target'),
      box=props.Primitive(geom_type='sphere', size=[0.1], name='box'),
  )


class _Task(composer.NullTask):
  """Drives the walkers' actuators with the action."""

  def __init__(self, arena, actuators):
    super().__init__(arena)
    self._actuators = actuators

  def before_step(self, physics, action, key):
    return physics.bind(self._actuators).set(ctrl=action)


@pytest.fixture(scope='module')
def scene():
  parts = _parts()
  arena = DmControlEntity(parts['arena'])
  walker = DmControlEntity(parts['ant'])
  arena.add_free_entity(walker)
  arena.add_free_entity(DmControlEntity(parts['ball']))
  arena.attach(DmControlEntity(parts['target']))
  box = DmControlEntity(parts['box'])
  arena.add_free_entity(box)
  actuators = list(parts['ant'].actuators) + list(parts['ball'].actuators)
  task = _Task(arena, actuators)
  env = composer.Environment(task)
  return env, parts, walker, box


def test_five_dm_control_classes_step_batched(scene):
  env, parts, walker, box = scene
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
  # The MJCFFeature observables of the walker came along.
  assert 'joints_pos' in walker.observables.as_dict(fully_qualified=False)


def test_the_composed_model_is_dm_controls(scene):
  env, *_ = scene
  parts = _parts()
  root = parts['arena'].mjcf_model
  parts['arena'].add_free_entity(parts['ant'])
  parts['arena'].add_free_entity(parts['ball'])
  parts['arena'].attach(parts['target'])
  parts['arena'].add_free_entity(parts['box'])
  theirs = mjcf.Physics.from_mjcf_model(root).model.ptr
  mine = env.mj_model
  for size in ('nq', 'nv', 'nu', 'nbody', 'ngeom', 'nsite', 'nsensor'):
    assert getattr(mine, size) == getattr(theirs, size), size
  for i in range(mine.nbody):
    assert mine.body(i).name == theirs.body(i).name
  np.testing.assert_allclose(mine.body_mass, theirs.body_mass, rtol=1e-6)
  np.testing.assert_allclose(mine.body_pos, theirs.body_pos, atol=1e-7)
  np.testing.assert_allclose(mine.geom_size, theirs.geom_size, rtol=1e-6)
  np.testing.assert_allclose(mine.qpos0, theirs.qpos0, atol=1e-7)


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
