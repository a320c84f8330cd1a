"""Contact queries, `ContactFeature` and `ContactSensor` against MuJoCo's C library.

A ball and a box dropped on a floor. The queries read MJX's contact list and
constraint forces; each is checked against MuJoCo C's `mjData.contact` and
`mj_contactForce` at the same states (`mjx.put_data` of C's data), for both
friction cones. The sensor runs inside an environment on a scripted
trajectory (the ball's height set every step, the box falling freely) and is
checked against the same trajectory stepped by `mujoco.mj_step`, with the
air and contact times counted from C's contact flags.
"""

from dm_env import specs
import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.observation import contact_sensor
from mjx_composer.observation import contacts
from mjx_composer.observation.observable import contact as contact_obs
from mjx_composer.suite.entities import arenas
from mjx_composer.suite.entities import props

_DT = 0.01
_BALL_RADIUS = 0.1
_MASSES = {'ball': 1.0, 'box': 2.0}
_BALL_Z = 0.3
# The drop's box falls tilted; the script's lands flat at its fifth update.
_BOX_POSE = (0.5, 0.0, 0.5, 0.96, 0.2, 0.1, 0.0)
_SCRIPT_BOX_POSE = (0.5, 0.0, 0.11, 1.0, 0.0, 0.0, 0.0)
# Scripted ball heights per world and control step (radius 0.1: touching
# below 0.1).
_HEIGHTS = np.array(
    [
        [0.099, 0.099, 0.3, 0.3, 0.3, 0.099, 0.3, 0.099, 0.099, 0.099],
        [0.3, 0.3, 0.099, 0.2, 0.099, 0.099, 0.099, 0.3, 0.3, 0.099],
        [0.5, 0.4, 0.3, 0.2, 0.1005, 0.0995, 0.099, 0.099, 0.5, 0.5],
    ],
    np.float32,
)


class DropTask(composer.Task):
  """A ball and a box over a floor; the action sets the ball's height."""

  def __init__(self, cone=None, sensor=False, box_pose=_BOX_POSE):
    self._box_pose = box_pose
    self.arena = arenas.Floor()
    if cone is not None:
      self.arena.mjcf_model.option.cone = cone
    self.ball = props.Sphere(
        radius=_BALL_RADIUS, name='ball', mass=_MASSES['ball']
    )
    self.box = props.Box(
        half_lengths=(0.1, 0.1, 0.1), name='box', mass=_MASSES['box']
    )
    for entity in (self.ball, self.box):
      self.arena.add_free_entity(entity)
    self.set_timesteps(control_timestep=_DT, physics_timestep=_DT)
    ground = self.arena.ground_geoms
    self.sensor = contact_sensor.ContactSensor(
        [self.ball, self.box], ground, name='feet'
    )
    self._observables = {}
    if sensor:
      self._observables = {
          f'sensor_{k}': v for k, v in self.sensor.observables().items()
      }
      self._observables['ball_normal_force'] = contact_obs.ContactFeature(
          'normal_force', self.ball, ground
      )
      for obs in self._observables.values():
        obs.enabled = True

  @property
  def root_entity(self):
    return self.arena

  @property
  def task_observables(self):
    return self._observables

  def action_spec(self, physics):
    del physics
    return specs.BoundedArray(
        (1,), np.float32, [0.0], [1.0], name='ball_height'
    )

  def initial_task_state(self):
    return self.sensor.initial_state()

  def initialize_episode(self, physics, key):
    del key
    physics = self.ball.set_pose(physics, [0.0, 0.0, _BALL_Z], [1, 0, 0, 0])
    pose = self._box_pose
    return self.box.set_pose(physics, pose[:3], pose[3:])

  def before_step(self, physics, action, key):
    del key
    position = jnp.zeros(3).at[2].set(action[0])
    physics = self.ball.set_pose(physics, position, [1.0, 0.0, 0.0, 0.0])
    return self.ball.set_velocity(physics, jnp.zeros(3), jnp.zeros(3))

  def after_step(self, physics, key):
    del key
    return self.sensor.update(physics, self.control_timestep)

  def get_reward(self, physics):
    return jnp.sum(self.sensor.landing_air_time(physics))


def _build(task):
  return composer.Environment(
      task, options=composer.ExecutionOptions(impl='jax')
  )


def _geom(m, name):
  return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name)


def _reference(m, d, first, second):
  """Count, normal force, net force on `first`, the deepest penetration and
  the contact positions of C's active contacts between two geom sets."""
  count, normal, force, depth, positions = 0, 0.0, np.zeros(3), 0.0, []
  out = np.zeros(6)
  for i in range(d.ncon):
    c = d.contact[i]
    if c.exclude or c.efc_address < 0:
      continue
    g1, g2 = c.geom
    if g1 in first and g2 in second:
      sign = -1.0
    elif g2 in first and g1 in second:
      sign = 1.0
    else:
      continue
    mujoco.mj_contactForce(m, d, i, out)
    count += 1
    normal += out[0]
    force += sign * (out[:3] @ c.frame.reshape(3, 3))
    depth = max(depth, -c.dist)
    positions.append(c.pos.copy())
  return count, normal, force, depth, positions


@pytest.fixture(
    scope='module',
    params=[mujoco.mjtCone.mjCONE_PYRAMIDAL, mujoco.mjtCone.mjCONE_ELLIPTIC],
    ids=['pyramidal', 'elliptic'],
)
def drop(request):
  """C's trajectory of the drop (every 10th step's data) and the queries of
  MJX's copy of those states (`mjx.put_data`), batched."""
  task = DropTask(cone=request.param)
  env = _build(task)
  m = env.mj_model
  assert m.opt.cone == request.param
  d = mujoco.MjData(m)
  d.qpos[:] = [0, 0, _BALL_Z, 1, 0, 0, 0, *_BOX_POSE]
  host, device = [], []
  for i in range(150):
    mujoco.mj_step(m, d)
    if i % 10 == 0:
      mujoco.mj_forward(m, d)
      host.append(mujoco.MjData(m))
      mujoco.mj_copyData(host[-1], m, d)
      device.append(mjx.put_data(m, d))
  batch = jax.tree.map(lambda *x: jnp.stack(x), *device)
  physics = env.initial_physics()
  ground = task.arena.ground_geoms

  def query(data):
    p = physics.replace(data=data)
    return dict(
        ball=contacts.between(p, task.ball, ground),
        box=contacts.between(p, task.box, ground),
        box_any=contacts.between(p, task.box, max_contacts=2),
        rows=contacts.summarize(p, [task.ball, task.box], ground),
        pairs=contacts.touching_pairs(p, 'box/geom'),
    )

  return task, m, host, jax.jit(jax.vmap(query))(batch)


def test_between_matches_mujoco_contacts_and_forces(drop):
  task, m, host, out = drop
  ground = [_geom(m, 'ground')]
  ball, box = [_geom(m, 'ball/geom')], [_geom(m, 'box/geom')]
  everything_else = [g for g in range(m.ngeom) if g not in box]
  scale = 9.81 * sum(_MASSES.values())
  counts = []
  for k, d in enumerate(host):
    for name, first, second in (
        ('ball', ball, ground),
        ('box', box, ground),
        ('box_any', box, everything_else),
    ):
      count, normal, force, depth, positions = _reference(m, d, first, second)
      got = jax.tree.map(lambda x, k=k: np.asarray(x[k]), out[name])
      counts.append(count)
      assert got.count == count, (name, k)
      assert got.touching == (count > 0)
      np.testing.assert_allclose(got.normal_force, normal, atol=2e-3 * scale)
      np.testing.assert_allclose(got.force, force, atol=2e-3 * scale)
      np.testing.assert_allclose(got.penetration, depth, atol=1e-5)
      listed = got.position[got.valid]
      assert len(listed) == min(count, len(got.valid))
      for p in listed:  # Each listed contact is one of C's.
        assert min(np.linalg.norm(p - q) for q in positions) < 1e-4
      assert np.all(got.geoms[got.valid][:, 0] == first[0])
      assert np.all(got.geoms[~got.valid] == -1)
      # The normal points from the first set to the second: down to the floor.
      if name != 'box_any' and count:
        assert np.all(got.normal[got.valid][:, 2] < -0.99)
    rows = jax.tree.map(lambda x, k=k: np.asarray(x[k]), out['rows'])
    for row, name in enumerate(('ball', 'box')):
      single = jax.tree.map(lambda x, k=k: np.asarray(x[k]), out[name])
      assert rows.count[row] == single.count
      np.testing.assert_allclose(rows.force[row], single.force, rtol=1e-6)
    pairs, valid = (np.asarray(x[k]) for x in out['pairs'])
    touching = out['box_any'].count[k] > 0
    assert valid.sum() == int(touching)
    if touching:
      assert pairs[valid].tolist() == [[box[0], ground[0]]]
  # The drop passes through no contact, one, two and four box corners.
  assert {0, 1, 2, 4} <= set(counts)


def test_resting_contact_force_is_the_weight(drop):
  """At rest the floor carries each body's weight: +m g, up (physics, not C)."""
  _, _, _, out = drop
  for name in ('ball', 'box'):
    force = np.asarray(out[name].force[-1])
    np.testing.assert_allclose(
        force, [0.0, 0.0, 9.81 * _MASSES[name]], atol=5e-3 * _MASSES[name]
    )


def _times(flags, dt):
  """Air and contact times per update, counted from the flags' runs."""
  n = len(flags)
  out = {
      k: np.zeros(n)
      for k in (
          'air_time',
          'contact_time',
          'last_air_time',
          'last_contact_time',
          'first_contact',
      )
  }
  last_air = last_contact = 0.0
  for k in range(n):
    run = 1
    while k - run >= 0 and flags[k - run] == flags[k]:
      run += 1
    # The run before this one, ended by update k (none at an episode's start).
    before = 0
    if run <= k:
      while k - run - before >= 0 and flags[k - run - before] != flags[k]:
        before += 1
    landing = flags[k] and run == 1 and before > 0
    lifting = not flags[k] and run == 1 and before > 0
    if landing:
      last_air = (before + 1) * dt
    if lifting:
      last_contact = (before + 1) * dt
    out['air_time'][k] = 0.0 if flags[k] else run * dt
    out['contact_time'][k] = run * dt if flags[k] else 0.0
    out['last_air_time'][k] = last_air
    out['last_contact_time'][k] = last_contact
    out['first_contact'][k] = landing
  return out


@pytest.fixture(scope='module')
def scripted():
  """The environment's sensor state and observations over the script."""
  task = DropTask(sensor=True, box_pose=_SCRIPT_BOX_POSE)
  env = _build(task)
  worlds, steps = _HEIGHTS.shape
  state = jax.jit(jax.vmap(env.reset))(
      jax.random.split(jax.random.key(0), worlds)
  )
  step = jax.jit(jax.vmap(env.step))
  states = []
  for k in range(steps):
    state = step(state, jnp.asarray(_HEIGHTS[:, k : k + 1]))
    states.append(jax.device_get(state))
  return task, env, states


def _host_script(m, heights):
  """C's flags and the ball's normal force per update for one world."""
  d = mujoco.MjData(m)
  d.qpos[:] = [0, 0, _BALL_Z, 1, 0, 0, 0, *_SCRIPT_BOX_POSE]
  mujoco.mj_forward(m, d)
  ground = [_geom(m, 'ground')]
  rows = ([_geom(m, 'ball/geom')], [_geom(m, 'box/geom')])
  flags, forces = [], []
  for z in heights:
    d.qpos[:7] = [0, 0, z, 1, 0, 0, 0]
    d.qvel[:6] = 0
    mujoco.mj_step(m, d)  # Its contacts are those of the positions set.
    refs = [_reference(m, d, row, ground) for row in rows]
    flags.append([r[0] > 0 for r in refs])
    forces.append(refs[0][1])
  return np.array(flags), np.array(forces)


def test_sensor_times_follow_mujoco_trajectory(scripted):
  task, env, states = scripted
  m = env.mj_model
  name = task.sensor.name
  for world, heights in enumerate(_HEIGHTS):
    flags, forces = _host_script(m, heights)
    assert flags[:, 0].any() and not flags[:, 0].all()
    assert flags[:, 1].tolist() == [False] * 5 + [True] * 5  # It lands.
    for row in range(2):
      expected = _times(list(flags[:, row]), _DT)
      for k, state in enumerate(states):
        entry = lambda e, s=state: np.asarray(s.task_state[f'{name}_{e}'])
        assert entry('contact')[world, row] == flags[k, row], (world, row, k)
        assert entry('first_contact')[world, row] == bool(
            expected['first_contact'][k]
        ), (world, row, k)
        for e in ('air_time', 'contact_time', 'last_air_time'):
          np.testing.assert_allclose(
              entry(e)[world, row], expected[e][k], atol=1e-6, err_msg=e
          )
        np.testing.assert_allclose(
            entry('last_contact_time')[world, row],
            expected['last_contact_time'][k],
            atol=1e-6,
        )
    for k, state in enumerate(states):
      obs = jax.tree.map(lambda x, w=world: np.asarray(x[w]), state.observation)
      np.testing.assert_allclose(
          obs['ball_normal_force'].reshape(()), forces[k], atol=2e-2
      )
      np.testing.assert_allclose(
          obs['sensor_air_time'].reshape(-1),
          np.asarray(state.task_state[f'{name}_air_time'])[world],
      )
      # The reward: the air time that ended at a landing.
      landing = np.where(
          state.task_state[f'{name}_first_contact'][world],
          state.task_state[f'{name}_last_air_time'][world],
          0.0,
      ).sum()
      np.testing.assert_allclose(state.reward[world], landing, atol=1e-6)


@pytest.fixture(scope='module')
def plain():
  """A task and its environment's initial physics (nothing compiled)."""
  task = DropTask()
  return task, _build(task).initial_physics()


def test_sensor_update_with_given_flags(plain):
  """Flags from elsewhere (contact sensors, under 'warp') drive the times."""
  task, physics = plain
  physics = physics.replace(task_state=task.sensor.initial_state())
  flags = np.array(
      [[1, 0], [1, 0], [0, 0], [0, 1], [1, 1], [0, 1], [0, 0], [1, 0]], bool
  )
  dt = 0.02
  expected = [_times(list(flags[:, row]), dt) for row in range(2)]
  for k, touching in enumerate(flags):
    physics = task.sensor.update(physics, dt, touching=touching)
    for row in range(2):
      for entry, values in expected[row].items():
        got = np.asarray(getattr(task.sensor, entry)(physics))[row]
        np.testing.assert_allclose(got, values[k], atol=1e-6, err_msg=entry)
  with pytest.raises(ValueError, match='one flag per row'):
    task.sensor.update(physics, dt, touching=[True])


def test_bad_sets_raise_early_with_the_fix(plain):
  task, physics = plain
  with pytest.raises(ValueError, match='share geoms'):
    contacts.between(physics, task.box, task.arena)  # The arena holds the box.
  with pytest.raises(KeyError, match="No geom or body named 'nope'"):
    contacts.between(physics, 'nope')
  with pytest.raises(TypeError, match='A set of geoms is'):
    contacts.between(physics, 3.0)
  with pytest.raises(ValueError, match='max_contacts must be'):
    contacts.between(physics, task.ball, max_contacts=-1)
  with pytest.raises(ValueError, match='unknown kind'):
    contact_obs.ContactFeature('speed', task.ball)
  with pytest.raises(TypeError, match='rows must be a list'):
    contact_sensor.ContactSensor(task.ball.geom)
  with pytest.raises(ValueError, match='force_threshold'):
    contact_sensor.ContactSensor([task.ball], force_threshold=-1.0)
  with pytest.raises(KeyError, match='initial_task_state'):
    contact_sensor.ContactSensor([task.ball], name='other').update(
        physics.replace(task_state={}), _DT
    )


def test_a_model_without_contacts_answers_empty():
  """With contacts disabled MJX's list is empty: no contact, no slot."""
  task = DropTask()
  task.arena.mjcf_model.option.disableflags |= (
      mujoco.mjtDisableBit.mjDSBL_CONTACT
  )
  physics = _build(task).initial_physics()
  touch = contacts.between(physics, task.ball)
  assert not touch.touching and touch.count == 0
  assert touch.position.shape == (0, 3) and touch.valid.shape == (0,)
  np.testing.assert_array_equal(touch.force, np.zeros(3))
  rows = contacts.summarize(physics, [task.ball, task.box])
  np.testing.assert_array_equal(rows.count, [0, 0])
  pairs, valid = contacts.touching_pairs(physics, task.ball)
  assert pairs.shape == (0, 2) and valid.shape == (0,)


class _PyMJCFBall(composer.Entity):
  """A ball written in PyMJCF, as dm_control's entities are."""

  def _build(self):
    from dm_control import mjcf  # pylint: disable=g-import-not-at-top

    self._root = mjcf.RootElement(model='pyball')
    self.body = self._root.worldbody.add('body', name='body')
    self.geom = self.body.add('geom', type='sphere', size=[0.1])

  @property
  def mjcf_model(self):
    return self._root


class _PyMJCFTask(composer.NullTask):

  def __init__(self):
    arena = arenas.Floor()
    self.ball = _PyMJCFBall()
    arena.add_free_entity(self.ball)
    super().__init__(arena)


def test_pymjcf_elements_resolve_as_their_compiled_geoms():
  task = _PyMJCFTask()
  index = _build(task).initial_physics().index
  m = index.mj_model
  body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, 'pyball/body')
  expected = np.flatnonzero(m.geom_bodyid == body)
  assert expected.size == 1
  for elements in (task.ball, task.ball.geom, task.ball.body, 'pyball/body'):
    np.testing.assert_array_equal(contacts.geom_ids(index, elements), expected)


def test_dm_controls_contact_loop_is_answered_by_between():
  """composer's `for c in physics.data.contact[:physics.data.ncon]` on
  dm_control's physics, and `contacts.between` on ours, at the same
  states; the loop on ours is refused, naming `contacts.between`."""
  from dm_control import mujoco as dm_mujoco  # pylint: disable=g-import-not-at-top

  task = _PyMJCFTask()
  env = _build(task)
  m = env.mj_model
  dm_physics = dm_mujoco.Physics.from_model(dm_mujoco.wrapper.MjModel(m))
  ball = contacts.geom_ids(env.initial_physics().index, task.ball)
  ground = contacts.geom_ids(
      env.initial_physics().index, task.root_entity.ground_geoms
  )

  def dm_control_count(physics):  # composer's idiom, unchanged
    count = 0
    for c in physics.data.contact[: physics.data.ncon]:
      if (c.geom1 in ball and c.geom2 in ground) or (
          c.geom2 in ball and c.geom1 in ground
      ):
        count += 1
    return count

  @jax.jit
  def ours(qpos):
    physics = env.initial_physics()
    physics = physics.replace(data=physics.data.replace(qpos=qpos)).forward()
    touch = contacts.between(physics, task.ball, task.root_entity.ground_geoms)
    return touch.touching, touch.count

  counts = []
  for height in (0.09, 0.3):
    with dm_physics.reset_context():
      dm_physics.data.qpos[:3] = [0.0, 0.0, height]
    counts.append(dm_control_count(dm_physics))
    touching, count = ours(jnp.asarray(dm_physics.data.qpos, jnp.float32))
    assert int(count) == counts[-1] and bool(touching) == (counts[-1] > 0)
  assert counts[0] > 0 and counts[1] == 0
  physics = env.initial_physics().forward()
  for loop in (
      dm_control_count,
      lambda p: [c for c in p.data.contact],
      lambda p: p.data.contact[0],
  ):
    with pytest.raises(
        TypeError, match=r'mjx_composer\.observation\.contacts\.between'
    ):
      loop(physics)
