"""PropPlacer: batched rejection sampling, settling, failures and retries.

Placements are checked against MuJoCo itself: a world's state (and its
per-world model fields) is copied into a host `MjData`, `mj_forward` runs,
and no contact involving a placed prop may penetrate.
"""

import copy

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer import initializers
from mjx_composer.platform import backend
from mjx_composer.suite.entities import props
from mjx_composer.variation import deterministic
from mjx_composer.variation import distributions
from mjx_composer.variation import rotations
from tests import conftest

_RADIUS = 0.05
_CRATE = 0.1  # the crate's half-size
_SPHERE_LOW = np.array([-0.3, -0.3, 0.0])
_SPHERE_HIGH = np.array([0.3, 0.3, 0.15])
_CRATE_LOW = np.array([-0.2, -0.2, _CRATE + 0.001])
_CRATE_HIGH = np.array([0.2, 0.2, _CRATE + 0.001])
# Host (float64) and MJX (float32) distances agree to about this much.
_TOLERANCE = 1e-6


def _floor_arena():
  arena = composer.Arena()
  arena.mjcf_model.worldbody.add_geom(
      name='floor', type=mujoco.mjtGeom.mjGEOM_PLANE, size=[1, 1, 0.1]
  )
  return arena


class PlacementTask(composer.Task):
  """A fixed crate placed first, then four free spheres around it."""

  def __init__(self, sphere_kwargs=None):
    self.arena = _floor_arena()
    self.crate = props.Box(half_lengths=(_CRATE,) * 3, name='crate')
    self.arena.attach(self.crate)
    self.spheres = [
        props.Sphere(radius=_RADIUS, name=f'sphere_{i}') for i in range(4)
    ]
    for sphere in self.spheres:
      self.arena.add_free_entity(sphere)
    self.crate_placer = initializers.PropPlacer(
        [self.crate],
        position=distributions.Uniform(_CRATE_LOW, _CRATE_HIGH),
        quaternion=rotations.QuaternionFromAxisAngle(
            axis=(0.0, 0.0, 1.0), angle=distributions.Uniform(-np.pi, np.pi)
        ),
    )
    self.sphere_kwargs = dict(
        position=distributions.Uniform(_SPHERE_LOW, _SPHERE_HIGH),
        max_attempts_per_prop=30,
        **(sphere_kwargs or {}),
    )
    self.sphere_placer = initializers.PropPlacer(
        self.spheres, **self.sphere_kwargs
    )

  @property
  def root_entity(self):
    return self.arena

  def initialize_episode(self, physics, key):
    crate_key, sphere_key = jax.random.split(key)
    # The spheres still sit where they were built: composer's documented use
    # of `ignore_contacts_with_entities`.
    physics = self.crate_placer(
        physics, crate_key, ignore_contacts_with_entities=self.spheres
    )
    return self.sphere_placer(physics, sphere_key)

  def get_reward(self, physics):
    return 0.0


def _world(states, i):
  return jax.tree.map(lambda x: x[i], states)


def _physics(env, states, i):
  """The Physics of world `i` (on the device)."""
  return env.physics(jax.tree.map(jnp.asarray, _world(states, i)))


def _on_host(states):
  """The states as numpy arrays: indexing worlds is then cheap."""
  return jax.tree.map(
      np.asarray, states.replace(key=jax.random.key_data(states.key))
  )


def _host_data(env, state):
  """A host MjData with one (unbatched) world's state, after mj_forward."""
  model = copy.deepcopy(env.mj_model)
  for field, value in state.model_fields.items():
    getattr(model, field)[...] = np.asarray(value)
  data = mujoco.MjData(model)
  data.qpos[:] = np.asarray(state.data.qpos)
  mujoco.mj_forward(model, data)
  return model, data


def _penetrating(model, data, geom_ids):
  """Host contacts with dist < -tolerance that involve one of `geom_ids`."""
  return [
      (model.geom(c.geom1).name, model.geom(c.geom2).name, c.dist)
      for c in data.contact[: data.ncon]
      if (c.geom1 in geom_ids or c.geom2 in geom_ids) and c.dist < -_TOLERANCE
  ]


def _geom_ids(model, names):
  return {mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, n) for n in names}


@pytest.fixture(scope='module')
def placement():
  """1,000 worlds of the placement scene, reset in one jitted call."""
  task = PlacementTask()
  env = composer.Environment(task)
  states = jax.jit(jax.vmap(env.reset))(
      jax.random.split(jax.random.key(0), 1000)
  )
  return task, env, _on_host(states)


def _sphere_positions(env, task, states):
  """(worlds, spheres, 3) freejoint positions."""
  model = env.mj_model
  adrs = [
      model.jnt_qposadr[model.body(f'{s.name}/').jntadr[0]]
      for s in task.spheres
  ]
  qpos = np.asarray(states.data.qpos)
  return np.stack([qpos[:, a : a + 3] for a in adrs], axis=1)


def test_every_world_is_placed_without_interpenetration(placement):
  task, env, states = placement
  assert not np.any(np.asarray(states.metrics['init_failed']))
  assert not np.any(np.asarray(states.metrics['init_failures']))
  names = ['crate/geom'] + [f'{s.name}/geom' for s in task.spheres]
  for world in range(0, 1000, 20):  # 50 worlds, checked by MuJoCo
    model, data = _host_data(env, _world(states, world))
    assert not _penetrating(model, data, _geom_ids(model, names)), world


def test_positions_cover_the_requested_distribution(placement):
  task, env, states = placement
  positions = _sphere_positions(env, task, states).reshape(-1, 3)
  assert np.all(positions >= _SPHERE_LOW - 1e-6)
  assert np.all(positions <= _SPHERE_HIGH + 1e-6)
  # Rejection removed every candidate that sank into the floor ...
  assert positions[:, 2].min() > _RADIUS
  # ... and otherwise left the distribution uniform: every quarter of x and
  # y holds a fair share of the 4,000 spheres, and z spans its free range.
  for axis in (0, 1):
    counts, _ = np.histogram(
        positions[:, axis],
        bins=4,
        range=(_SPHERE_LOW[axis], _SPHERE_HIGH[axis]),
    )
    assert counts.min() > 0.15 * len(positions), counts
  counts, _ = np.histogram(positions[:, 2], bins=4, range=(_RADIUS, 0.15))
  assert counts.min() > 0.15 * len(positions), counts
  # Spheres never overlap each other.
  gaps = np.linalg.norm(
      positions.reshape(1000, 4, 1, 3) - positions.reshape(1000, 1, 4, 3),
      axis=-1,
  )
  gaps += np.eye(4) * 10
  assert gaps.min() > 2 * _RADIUS


def test_fixed_props_are_placed_through_per_world_model_fields(placement):
  task, env, states = placement
  frame = env.mj_model.body('crate/').id
  pos = np.asarray(states.model_fields['body_pos'])[:, frame]
  quat = np.asarray(states.model_fields['body_quat'])[:, frame]
  assert np.all(pos >= _CRATE_LOW - 1e-6) and np.all(pos <= _CRATE_HIGH + 1e-6)
  assert np.std(pos[:, 0]) > 0.05  # differs per world
  np.testing.assert_allclose(np.linalg.norm(quat, axis=-1), 1.0, atol=1e-5)
  np.testing.assert_allclose(quat[:, 1:3], 0.0, atol=1e-6)  # a yaw
  # The compiled model is untouched.
  np.testing.assert_allclose(env.mj_model.body_pos[frame], 0.0)


def test_pairs_checked_follow_composer(placement):
  task, env, _ = placement
  physics = _physics(env, placement[2], 0)
  model = env.mj_model

  def partners(placer, i, ignore=()):
    names = set()
    for _, pairs in placer.pair_groups(physics, i, ignore):
      for g1, g2 in pairs:
        names |= {model.geom(int(g1)).name, model.geom(int(g2)).name}
    return names

  # Sphere 1 sees the floor, the crate and sphere 0, not spheres 2 and 3
  # (not placed yet).
  assert partners(task.sphere_placer, 1) == {
      'floor',
      'crate/geom',
      'sphere_0/geom',
      'sphere_1/geom',
  }
  # Ignored entities do not count. (The crate is fixed to the world, so,
  # as in MuJoCo, it never collides with the floor.)
  assert not partners(task.crate_placer, 0, task.spheres)
  assert partners(task.crate_placer, 0) == {'crate/geom'} | {
      f'{s.name}/geom' for s in task.spheres
  }


def test_ignore_collisions_takes_the_first_sample(placement):
  task, env, states = placement
  placer = initializers.PropPlacer(
      task.spheres, ignore_collisions=True, **task.sphere_kwargs
  )
  physics = _physics(env, states, 0)
  qpos = jax.jit(jax.vmap(lambda k: placer(physics, k).data.qpos))(
      jax.random.split(jax.random.key(1), 1000)
  )
  placed = states.replace(data=states.data.replace(qpos=np.asarray(qpos)))
  positions = _sphere_positions(env, task, placed).reshape(-1, 3)
  # Unchecked samples follow the raw distribution, floor included ...
  assert 0.25 < np.mean(positions[:, 2] < _RADIUS) < 0.42
  # ... so MuJoCo finds interpenetrations in many worlds.
  names = [f'{s.name}/geom' for s in task.spheres]
  colliding = 0
  for world in range(0, 1000, 20):
    model, data = _host_data(env, _world(placed, world))
    colliding += bool(_penetrating(model, data, _geom_ids(model, names)))
  assert colliding > 25


def _set_free_pose(physics, entity, position):
  return entity.set_pose(
      physics,
      jnp.asarray(position, jnp.float32),
      jnp.array([1.0, 0.0, 0.0, 0.0]),
  )


def _free_position(physics, entity):
  return physics.bind(entity.attachment_frame.joints[0]).qpos[:3]


def test_ignore_contacts_with_entities_as_composer(placement):
  task, env, states = placement
  physics = _physics(env, states, 0)
  sphere_0, sphere_1 = task.spheres[:2]
  spot = jnp.array([0.5, 0.5, 0.3])
  physics = _set_free_pose(physics, sphere_1, spot)
  physics = _set_free_pose(physics, sphere_0, [-0.5, -0.5, 0.3])
  physics = _set_free_pose(physics, task.spheres[2], [-0.5, 0.5, 0.3])
  physics = _set_free_pose(physics, task.spheres[3], [0.5, -0.5, 0.3])
  place_0 = initializers.PropPlacer(
      [sphere_0], position=spot, max_attempts_per_prop=2
  )
  place_1 = initializers.PropPlacer(
      [sphere_1],
      position=distributions.Uniform((0.3, 0.3, 0.2), (0.7, 0.7, 0.4)),
  )

  @jax.jit
  def run(physics, key):
    blocked = place_0(physics, key)
    ignored = place_0(physics, key, ignore_contacts_with_entities=[sphere_1])
    after = place_1(ignored, key)
    return (
        blocked.initialization_failed,
        ignored.initialization_failed,
        after.initialization_failed,
        _free_position(ignored, sphere_0),
        after,
    )

  blocked, ignored, after_failed, position, after = run(
      physics, jax.random.key(3)
  )
  assert bool(blocked)  # sphere 1 is in the way
  assert not bool(ignored)  # ... unless its contacts are ignored
  np.testing.assert_allclose(position, spot)
  assert not bool(after_failed)  # placing sphere 1 then avoids sphere 0
  state = _world(states, 0).replace(data=after.data)
  model, data = _host_data(env, state)
  assert not _penetrating(
      model, data, _geom_ids(model, ['sphere_0/geom', 'sphere_1/geom'])
  )


def test_props_are_placed_in_order_and_failures_are_flagged(placement):
  task, env, states = placement
  physics = _physics(env, states, 0)
  # Both spheres get the same fixed spot: the first fits, the second cannot.
  spot = jnp.array([0.5, 0.5, 0.3])
  placer = initializers.PropPlacer(
      task.spheres[:2], position=spot, max_attempts_per_prop=2
  )
  result = jax.jit(placer)(physics, jax.random.key(0))
  assert bool(result.initialization_failed)
  np.testing.assert_allclose(_free_position(result, task.spheres[0]), spot)


def test_a_sequence_of_positions_persists_per_world(placement):
  task, env, states = placement
  physics = _physics(env, states, 0)
  spots = np.array(
      [
          [-0.4, -0.4, 0.3],
          [0.4, -0.4, 0.3],
          [-0.4, 0.4, 0.3],
          [0.4, 0.4, 0.3],
          [0.0, 0.5, 0.3],
          [0.5, 0.0, 0.3],
      ]
  )
  placer = initializers.PropPlacer(
      task.spheres[:2], position=deterministic.Sequence(spots)
  )

  @jax.jit
  def three_episodes(physics, key):
    out = []
    for _ in range(3):
      physics = placer(physics, key)
      out.append(
          jnp.stack([_free_position(physics, s) for s in task.spheres[:2]])
      )
    return jnp.stack(out)

  np.testing.assert_allclose(
      three_episodes(physics, jax.random.key(0)),
      spots.reshape(3, 2, 3),
      atol=1e-6,
  )


def test_invalid_arguments():
  sphere = props.Sphere()
  with pytest.raises(ValueError, match='max_settle_physics_attempts'):
    initializers.PropPlacer(
        [sphere], position=(0, 0, 0), max_settle_physics_attempts=0
    )
  with pytest.raises(ValueError, match='max_attempts_per_prop'):
    initializers.PropPlacer(
        [sphere], position=(0, 0, 0), max_attempts_per_prop=0
    )
  with pytest.raises(ValueError, match='at least one prop'):
    initializers.PropPlacer([], position=(0, 0, 0))


# -- settling and environment retries ------------------------------------------


class Hinge(conftest.SpecEntity):
  """A rod on a hinge: a non-prop joint that settling must hold still."""

  def _build(self):
    spec = self._new_spec('hinge')
    body = spec.worldbody.add_body(name='rod', pos=[0.6, 0.0, 0.5])
    self.joint = body.add_joint(
        name='hinge', type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 1, 0]
    )
    body.add_geom(
        type=mujoco.mjtGeom.mjGEOM_CAPSULE,
        size=[0.02, 0, 0],
        fromto=[0, 0, 0, 0.2, 0, 0],
        contype=0,
        conaffinity=0,
    )


class RetryTask(composer.Task):
  """One sphere, placed with a single attempt where a wall blocks 5/8."""

  def __init__(self):
    self.arena = _floor_arena()
    self.arena.mjcf_model.worldbody.add_geom(
        name='block',
        type=mujoco.mjtGeom.mjGEOM_BOX,
        pos=[-0.15, 0, 0.2],
        size=[0.15, 0.3, 0.2],
    )
    self.hinge = Hinge()
    self.arena.attach(self.hinge)
    self.spheres = [
        props.Sphere(radius=_RADIUS, name=f'ball_{i}') for i in range(2)
    ]
    for i, sphere in enumerate(self.spheres):
      self.arena.add_free_entity(sphere).pos = [0.8, -0.5 + i, 0.3]
    self.placer = initializers.PropPlacer(
        self.spheres[:1],
        position=distributions.Uniform((-0.2, 0.0, 0.1), (0.2, 0.0, 0.1)),
        max_attempts_per_prop=1,
    )

  @property
  def root_entity(self):
    return self.arena

  def initialize_episode(self, physics, key):
    return self.placer(physics, key)

  def get_reward(self, physics):
    return 0.0


_ATTEMPTS = 4


@pytest.fixture(scope='module')
def retries():
  task = RetryTask()
  env = composer.Environment(task, max_reset_attempts=_ATTEMPTS)
  states = jax.jit(jax.vmap(env.reset))(
      jax.random.split(jax.random.key(0), 256)
  )
  return task, env, _on_host(states)


def test_failed_initializations_are_resampled_and_counted(retries):
  task, env, states = retries
  failures = np.asarray(states.metrics['init_failures'])
  failed = np.asarray(states.metrics['init_failed'])
  # A world whose last attempt failed failed every attempt; nothing raised.
  np.testing.assert_array_equal(failures[failed == 1], _ATTEMPTS)
  assert 10 < np.sum(failed) < 80  # ~ (5/8)^4 of 256 worlds
  # Others succeeded on some attempt, often after failing.
  recovered = (failed == 0) & (failures > 0)
  assert np.sum(recovered) > 50
  assert set(failures[failed == 0]) <= set(range(_ATTEMPTS))
  names = ['ball_0/geom']
  for world in np.flatnonzero(failed == 0)[:25]:
    model, data = _host_data(env, _world(states, world))
    assert not _penetrating(model, data, _geom_ids(model, names)), world
  # A world whose every attempt failed runs none of their poses: it keeps
  # the pose its reset started from.
  qpos = np.asarray(states.data.qpos)
  for world in np.flatnonzero(failed == 1):
    np.testing.assert_array_equal(
        qpos[world], env.mj_model.qpos0.astype(qpos.dtype)
    )


def test_settling(retries):
  task, env, states = retries
  # A world whose placement succeeded: the ball rests placed at y = 0.
  placed = int(
      np.flatnonzero(np.asarray(states.metrics['init_failed']) == 0)[0]
  )
  physics = _physics(env, states, placed)
  physics = physics.replace(data=physics.data.replace(time=jnp.float32(1337.0)))
  physics = physics.bind(task.hinge.joint).set(qpos=0.4)
  ball, other = task.spheres
  start = jnp.array([0.2, 0.0, 0.3])
  settle = initializers.PropPlacer([ball], position=start, settle_physics=True)
  no_settle = initializers.PropPlacer([ball], position=start)
  # Forced failure: settling cannot finish in 2 steps; every round moves the
  # ball 1 m along y from where it is, as composer's test does.
  retry = initializers.PropPlacer(
      [ball],
      position=deterministic.Identity() + np.array([0.0, 1.0, 0.0]),
      settle_physics=True,
      max_settle_physics_time=0.008,
      max_settle_physics_attempts=3,
      raise_exception_on_settle_failure=True,
  )

  @jax.jit
  def run(physics, key):
    return settle(physics, key), no_settle(physics, key), retry(physics, key)

  settled, unsettled, retried = run(physics, jax.random.key(0))
  ball_joint = ball.attachment_frame.joints[0]
  # The settled ball rests on the floor, still; the other one never moved.
  np.testing.assert_allclose(
      settled.bind(ball_joint).qpos[2], _RADIUS, atol=2e-3
  )
  assert float(jnp.max(jnp.abs(settled.bind(ball_joint).qvel))) < 1e-3
  assert not bool(settled.initialization_failed)
  other_joint = other.attachment_frame.joints[0]
  np.testing.assert_array_equal(
      settled.bind(other_joint).qpos, physics.bind(other_joint).qpos
  )
  np.testing.assert_allclose(settled.bind(task.hinge.joint).qpos, 0.4)
  np.testing.assert_allclose(float(settled.data.time), 1337.0)
  # Without settling the ball stays where it was put.
  np.testing.assert_allclose(unsettled.bind(ball_joint).qpos[:3], start)
  # Every failed round resampled from the current pose, then it gave up.
  assert bool(retried.initialization_failed)
  np.testing.assert_allclose(retried.bind(ball_joint).qpos[1], 3.0, atol=1e-2)
  np.testing.assert_allclose(float(retried.data.time), 1337.0)


def test_settling_is_refused_on_warp():
  """Its loops carry the whole `mjx.Data`, Warp's batch buffer included.

  `backend.WarpUnsupportedError`: `impl=None` then builds on 'jax'.
  """
  task = PlacementTask(sphere_kwargs={'settle_physics': True})
  with pytest.raises(backend.WarpUnsupportedError, match='settle_physics'):
    composer.Environment(task, options=composer.ExecutionOptions(impl='warp'))
