"""Bindings as composer binds: dm_control's shapes, fields MJX computes only on
demand, empty bindings, a `Variation` as a corruptor, and the errors a port
meets (stale reads, dropped writes, `random_state=`).

References: `dm_control.mjcf.Physics.bind` on the same MJCF, and MuJoCo's C
library (`mj_forward`, `mj_rnePostConstraint`, `mj_subtreeVel`) on the same
state.
"""

import zlib

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer import physics as physics_lib
from mjx_composer.model import element_index
from mjx_composer.observation.observable import mjcf as mjcf_observable
from mjx_composer.physics import bindings
from mjx_composer.platform import internals
from mjx_composer.variation import distributions
from mjx_composer.variation import noises
from tests import conftest

_XML = """
<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 .1"/>
    <camera name="cam" pos="0 -2 1" xyaxes="1 0 0 0 .5 1"/>
    <body name="torso" pos="0 0 0.5">
      <freejoint name="root"/>
      <geom name="torso_geom" type="box" size=".1 .08 .05"/>
      <site name="imu" size=".01"/>
      <site name="touch_site" type="box" size=".12 .1 .07"/>
      <body name="leg" pos=".1 0 0">
        <joint name="hip" type="hinge" axis="0 1 0" range="-1 1"/>
        <geom name="leg_geom" type="capsule" fromto="0 0 0 0 0 -.3"
              size=".03"/>
        <site name="foot" pos="0 0 -.3"/>
      </body>
    </body>
  </worldbody>
  <actuator><motor name="hip_motor" joint="hip" gear="10"/></actuator>
  <sensor>
    <accelerometer name="acc" site="imu"/>
    <touch name="touch" site="touch_site"/>
    <subtreelinvel name="com_vel" body="torso"/>
    <framezaxis name="zaxis" objtype="site" objname="imu"/>
  </sensor>
</mujoco>
"""

# (kind, names): what the shapes test binds, one element and a list.
_ELEMENTS = {
    'body': ['torso', 'leg'],
    'geom': ['torso_geom', 'leg_geom'],
    'site': ['imu', 'foot'],
    'camera': ['cam'],
}
_MATRICES = {
    'body': ('xmat', 'ximat'),
    'geom': ('xmat',),
    'site': ('xmat',),
    'camera': ('xmat',),
}


class _Scene:
  """The MJCF compiled twice, by dm_control's PyMJCF and by MjSpec, at one
  state after `mj_forward`."""

  def __init__(self):
    from dm_control import mjcf  # pylint: disable=g-import-not-at-top

    self.mjcf_model = mjcf.from_xml_string(_XML)
    self.dm_physics = mjcf.Physics.from_mjcf_model(self.mjcf_model)
    self.spec = mujoco.MjSpec.from_string(_XML)
    self.model = self.spec.compile()
    self.data = mujoco.MjData(self.model)
    quat = np.array([0.9, 0.1, -0.2, 0.3])
    qpos = np.concatenate(
        [[0.1, -0.2, 0.4], quat / np.linalg.norm(quat), [0.4]]
    )
    qvel = np.array([0.3, -0.1, 0.2, 1.0, -0.5, 0.7, 2.0])
    for data in (self.data, self.dm_physics.data):
      data.qpos[:] = qpos
      data.qvel[:] = qvel
      data.ctrl[:] = 0.3
    mujoco.mj_forward(self.model, self.data)
    self.dm_physics.forward()
    handles = [
        (kind, element)
        for kind, element in element_index.iter_elements(self.spec)
        if element.name
    ]
    self.index = element_index.ElementIndex(
        self.model, {id(h): (h, kind, h.name) for kind, h in handles}
    )
    self.mjx_model = mjx.put_model(self.model)

  def physics(self, data=None) -> physics_lib.Physics:
    if data is None:
      data = mjx.put_data(self.model, self.data)
    return physics_lib.Physics(
        model=self.mjx_model, data=data, index=self.index
    )

  def handle(self, kind, names):
    """The MjSpec handle(s) of `kind` named `names` (a name or a list)."""
    find = getattr(self.spec, kind)
    return [find(n) for n in names] if isinstance(names, list) else find(names)

  def dm_element(self, kind, name):
    namespace = {'joint': 'joint', 'camera': 'camera'}.get(kind, kind)
    return self.mjcf_model.find(namespace, name)


@pytest.fixture(scope='module')
def scene():
  return _Scene()


def test_matrices_bind_flat_as_in_dm_control(scene):
  physics = scene.physics()
  for kind, names in _ELEMENTS.items():
    for attr in _MATRICES[kind]:
      for selection in ([names[0]], names):
        is_list = len(selection) > 1
        ours_key = selection if is_list else selection[0]
        dm_elements = [scene.dm_element(kind, n) for n in selection]
        expected = np.asarray(
            getattr(
                scene.dm_physics.bind(
                    dm_elements if is_list else dm_elements[0]
                ),
                attr,
            )
        )
        ours = np.asarray(
            getattr(physics.bind(scene.handle(kind, ours_key)), attr)
        )
        assert ours.shape == expected.shape, (kind, attr, selection)
        np.testing.assert_allclose(
            ours, expected, atol=1e-6, err_msg=f'{kind} {attr} {selection}'
        )
  # Named access gives the same shapes as dm_control's.
  np.testing.assert_allclose(
      physics.named.data.xmat['torso'],
      scene.dm_physics.named.data.xmat['torso'],
      atol=1e-6,
  )
  assert np.asarray(physics.named.data.site_xmat).shape == (
      scene.model.nsite,
      9,
  )


def test_flat_matrix_write_round_trips(scene):
  physics = scene.physics()
  flat = jnp.arange(9.0)
  written = physics.named.data.set('xmat', 'leg', flat)
  np.testing.assert_array_equal(written.named.data.xmat['leg'], flat)
  np.testing.assert_array_equal(written.data.xmat[2], flat.reshape(3, 3))


def test_mjcf_feature_last_row_of_xmat_is_world_z(scene):
  """composer's `MJCFFeature('xmat', torso)[6:]`: shape (3,), dm_control's
  values (the world z axis in the torso frame)."""
  physics = scene.physics()
  torso = scene.mjcf_model.find('body', 'torso')
  expected = np.asarray(scene.dm_physics.bind(torso).xmat[6:])
  feature = mjcf_observable.MJCFFeature('xmat', scene.spec.body('torso'))[6:]
  value = feature(physics)
  assert value.shape == (3,)
  np.testing.assert_allclose(value, expected, atol=1e-6)


_ON_DEMAND = (
    'subtree_linvel',
    'subtree_angmom',
    'cacc',
    'cfrc_int',
    'cfrc_ext',
)


def test_fields_mjx_computes_on_demand_read_right(scene):
  """What MuJoCo gives after mj_forward, mj_rnePostConstraint and
  mj_subtreeVel, though MJX's data holds zeros there (as `mjx.forward`
  leaves them where no sensor needs them)."""
  reference = mujoco.MjData(scene.model)
  reference.qpos[:] = scene.data.qpos
  reference.qvel[:] = scene.data.qvel
  reference.ctrl[:] = scene.data.ctrl
  mujoco.mj_forward(scene.model, reference)
  mujoco.mj_rnePostConstraint(scene.model, reference)
  mujoco.mj_subtreeVel(scene.model, reference)
  data = mjx.put_data(scene.model, scene.data)
  impl = internals.data_impl(data)
  data = internals.replace_data_impl(
      data, **{f: jnp.zeros_like(getattr(impl, f)) for f in _ON_DEMAND}
  )
  bodies = scene.handle('body', ['torso', 'leg'])

  @jax.jit
  def read(data):
    physics = scene.physics(data)
    return {
        f: (
            getattr(physics.bind(bodies[0]), f),
            getattr(physics.bind(bodies), f),
            getattr(physics.named.data, f)['leg'],
        )
        for f in _ON_DEMAND
    }

  for field, (one, both, named) in read(data).items():
    expected = getattr(reference, field)
    np.testing.assert_allclose(one, expected[1], atol=2e-4, err_msg=field)
    np.testing.assert_allclose(both, expected[1:3], atol=2e-4, err_msg=field)
    np.testing.assert_allclose(named, expected[2], atol=2e-4, err_msg=field)


def test_a_batch_of_worlds_binds_each_worlds_values(scene):
  """`Environment.physics` of a batched state: each element's value per
  world, in dm_control's shape behind the batch axis, and writes land in
  each world; a per-world model field is read per world, a shared one as
  is."""
  worlds = []
  for qpos_z in (0.3, 0.5, 0.9):
    data = mujoco.MjData(scene.model)
    data.qpos[:] = scene.data.qpos
    data.qpos[2] = qpos_z
    data.qpos[7] = qpos_z - 0.5  # the hip
    mujoco.mj_forward(scene.model, data)
    worlds.append(data)
  stacked = jax.tree.map(
      lambda *x: jnp.stack(x),
      *[mjx.put_data(scene.model, d) for d in worlds],
  )
  rgba = jnp.stack([jnp.full((scene.model.ngeom, 4), w) for w in range(3)])
  physics = scene.physics(stacked)
  physics = physics.replace(model=physics.model.replace(geom_rgba=rgba))
  assert physics.batch_ndim == 1
  leg, torso = scene.handle('body', 'leg'), scene.handle('body', 'torso')
  geoms = scene.handle('geom', ['torso_geom', 'leg_geom'])
  hip = scene.handle('joint', 'hip')
  expected_xpos = np.stack([d.xpos[2] for d in worlds])
  np.testing.assert_allclose(physics.bind(leg).xpos, expected_xpos, atol=1e-6)
  np.testing.assert_allclose(
      physics.bind([torso, leg]).xmat,
      np.stack([d.xmat[1:3] for d in worlds]),
      atol=1e-6,
  )
  np.testing.assert_allclose(
      physics.named.data.xpos['leg'], expected_xpos, atol=1e-6
  )
  np.testing.assert_array_equal(
      physics.bind(hip).qpos, np.array([[-0.2], [0.0], [0.4]], np.float32)
  )
  np.testing.assert_array_equal(
      physics.bind(geoms).rgba, np.broadcast_to(rgba[:, 1:3], (3, 2, 4))
  )
  assert physics.bind(geoms).size.shape == (2, 3)  # shared by the worlds
  written = physics.bind(hip).set(qpos=jnp.array([[1.0], [2.0], [3.0]]))
  np.testing.assert_array_equal(written.data.qpos[:, 7], [1.0, 2.0, 3.0])
  np.testing.assert_array_equal(written.data.qpos[:, :7], stacked.qpos[:, :7])
  with pytest.raises(NotImplementedError, match='one world at a time'):
    physics.bind(torso).subtree_linvel  # pylint: disable=expression-not-assigned


def test_empty_binding_is_empty(scene):
  physics = scene.physics()
  binding = physics.bind([])
  assert binding.sensordata.shape == (0,)
  assert binding.xpos.shape == (0,)
  assert binding.set(qpos=1.0) is physics
  feature = mjcf_observable.MJCFFeature('sensordata', [])
  assert feature(physics).shape == (0,)


def test_element_id_is_answered_with_its_new_name(scene):
  """dm_control's `element_id` is `element_ids`: the same compiled ids,
  and the old name says which to use."""
  physics = scene.physics()
  for kind, names in _ELEMENTS.items():
    dm_ids = scene.dm_physics.bind(
        [scene.dm_element(kind, n) for n in names]
    ).element_id
    assert physics.bind(scene.handle(kind, names)).element_ids == tuple(
        int(i) for i in dm_ids
    )
    one = scene.dm_physics.bind(scene.dm_element(kind, names[0])).element_id
    assert physics.bind(scene.handle(kind, names[0])).element_ids == (one,)
  for binding in (physics.bind(scene.handle('site', 'foot')), physics.bind([])):
    with pytest.raises(AttributeError, match=r'`binding\.element_ids`'):
      binding.element_id  # pylint: disable=pointless-statement


def test_mujoco_pointers_are_answered_with_what_to_use(scene):
  """dm_control's `physics.model.ptr` (MuJoCo's C functions on the
  physics) names what to use instead; MJX's other answers are unchanged."""
  physics = scene.physics()
  expected = mujoco.mj_name2id(scene.model, mujoco.mjtObj.mjOBJ_BODY, 'leg')
  # What the message points to answers the C function's question.
  assert (
      mujoco.mj_name2id(physics.mj_model, mujoco.mjtObj.mjOBJ_BODY, 'leg')
      == expected
  )
  for source, kind in ((physics.model, 'Model'), (physics.data, 'Data')):
    with pytest.raises(
        AttributeError, match=rf'mjx\.{kind}`.*physics\.mj_model'
    ):
      source.ptr  # pylint: disable=pointless-statement
    assert not hasattr(source, 'ptr')
    with pytest.raises(
        AttributeError, match=f"'{kind}' object has no attribute 'nope'"
    ):
      source.nope  # pylint: disable=pointless-statement
  # MJX's forwarding of other names to its implementation data still answers.
  with pytest.warns(DeprecationWarning):
    ncon = physics.data.ncon
  assert ncon == internals.data_impl(physics.data).ncon


def test_write_then_derived_read_is_refused(scene):
  """Refused while tracing, where dm_control would run mj_forward first."""
  hip = scene.handle('joint', 'hip')
  foot = scene.handle('site', 'foot')
  torso = scene.handle('body', 'torso')
  data = jax.eval_shape(lambda: mjx.put_data(scene.model, scene.data))

  def trace(read):
    jax.eval_shape(lambda data: read(scene.physics(data)), data)

  with pytest.raises(physics_lib.StaleReadError, match='physics.forward'):
    trace(lambda p: p.bind(hip).set(qpos=0.7).bind(foot).xpos)
  trace(lambda p: p.bind(hip).set(qpos=0.7).bind(hip).qpos)  # an input
  trace(lambda p: p.bind(hip).set(qpos=0.7).kinematics().bind(foot).xpos)
  # A control changes only the acceleration stage: positions and velocities
  # stay fresh, the accelerometer does not.
  push = lambda p: p.set_control(jnp.ones(1))
  trace(lambda p: push(p).bind(foot).xpos)
  trace(lambda p: push(p).bind(torso).subtree_linvel)
  trace(lambda p: push(p).named.data.sensordata['zaxis'])
  with pytest.raises(physics_lib.StaleReadError):
    trace(lambda p: push(p).named.data.sensordata['acc'])
  with pytest.raises(physics_lib.StaleReadError):
    trace(lambda p: push(p).bind(foot).set(pos=jnp.ones(3)).bind(torso).cacc)


def test_a_model_write_makes_derived_reads_stale_but_appearance_does_not(
    scene,
):
  """As dm_control's bindings mark dirty: every model field but colours
  and materials."""
  geom = scene.handle('geom', 'torso_geom')
  data = jax.eval_shape(lambda: mjx.put_data(scene.model, scene.data))

  def trace(read):
    jax.eval_shape(lambda data: read(scene.physics(data)), data)

  with pytest.raises(physics_lib.StaleReadError, match='geom_pos'):
    trace(lambda p: p.bind(geom).set(pos=jnp.ones(3)).bind(geom).xpos)
  trace(lambda p: p.bind(geom).set(rgba=jnp.ones(4)).bind(geom).xpos)
  # Friction is read by the contacts, not the kinematics: positions stay
  # fresh, what the contacts make (the accelerometer) does not.
  friction = lambda p: p.bind(geom).set(friction=jnp.ones(3))
  trace(lambda p: friction(p).bind(geom).xpos)
  with pytest.raises(physics_lib.StaleReadError, match='geom_friction'):
    trace(lambda p: friction(p).named.data.sensordata['acc'])


# Model writes, each a model field of one element of the scene (leg
# elements: their frames differ from their body's, so MuJoCo reads them).
_KINEMATIC_WRITES = {
    'body_pos': 'leg',
    'body_quat': 'leg',
    'body_ipos': 'leg',
    'body_iquat': 'leg',
    'body_mass': 'leg',
    'body_subtreemass': 'torso',
    'body_inertia': 'leg',
    'jnt_pos': 'hip',
    'jnt_axis': 'hip',
    'geom_pos': 'leg_geom',
    'geom_quat': 'leg_geom',
    'site_pos': 'foot',
    'site_quat': 'foot',
}


def test_a_kinematic_model_write_makes_stale_what_mujoco_changes(scene):
  """A model write makes stale the positions that MuJoCo's kinematics
  (`mj_kinematics`, `mj_comPos`) change after it, and leaves the rest
  fresh: a site's frame moves its site, not its body."""
  base = mujoco.MjData(scene.model)
  base.qpos[:] = scene.data.qpos
  mujoco.mj_kinematics(scene.model, base)
  mujoco.mj_comPos(scene.model, base)
  kind = {'body': 'body', 'jnt': 'joint', 'geom': 'geom', 'site': 'site'}
  for name, element in _KINEMATIC_WRITES.items():
    model = scene.spec.compile()
    index = getattr(model, kind[name.split('_')[0]])(element).id
    prefix = name.split('_')[0]
    if hasattr(model, f'{prefix}_sameframe'):
      # MuJoCo skips a frame equal to its parent's; computed, it is the same.
      getattr(model, f'{prefix}_sameframe')[index] = 0
    field = getattr(model, name)
    value = field[index] + np.linspace(
        0.05, 0.15, np.size(field[index])
    ).reshape(np.shape(field[index]))
    if name.endswith('quat'):
      value /= np.linalg.norm(value)
    field[index] = value
    data = mujoco.MjData(model)
    data.qpos[:] = scene.data.qpos
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    changed = {
        field
        for field in bindings.KINEMATICS_FIELDS
        if not np.allclose(getattr(data, field), getattr(base, field))
    }
    assert changed == bindings.kinematics_written(name) or (
        changed
        <= bindings.kinematics_written(name)
        == bindings.KINEMATICS_FIELDS
    ), name
  # The read the rule lets through, and the one it refuses, while tracing.
  foot = scene.handle('site', 'foot')
  torso = scene.handle('body', 'torso')
  data = jax.eval_shape(lambda: mjx.put_data(scene.model, scene.data))

  def trace(read):
    jax.eval_shape(lambda data: read(scene.physics(data)), data)

  moved = lambda p: p.bind(foot).set(pos=jnp.ones(3))
  trace(lambda p: moved(p).bind(torso).xpos)
  with pytest.raises(physics_lib.StaleReadError, match='site_pos'):
    trace(lambda p: moved(p).bind(foot).xpos)


def test_stale_reads_in_reset_hooks_are_dm_controls(scene):
  """With `forward_stale_reads` (the `initialize_episode` hooks), a read
  after a write sees the written state, as dm_control's lazy forward pass
  gives it: positions, a model write's, velocities and sensors."""
  hip = scene.handle('joint', 'hip')
  foot = scene.handle('site', 'foot')
  geom = scene.handle('geom', 'torso_geom')
  torso = scene.handle('body', 'torso')
  sensors = [scene.handle('sensor', n) for n in ('acc', 'touch', 'zaxis')]
  pos = np.array([0.05, -0.02, 0.3], np.float32)

  @jax.jit
  def reads(data):
    physics = scene.physics(data).replace(forward_stale_reads=True)
    moved = physics.bind(hip).set(qpos=0.7)
    placed = moved.bind(geom).set(pos=pos)
    return dict(
        foot=moved.bind(foot).xpos,
        geom=placed.bind(geom).xpos,
        com_vel=moved.bind(torso).subtree_linvel,
        sensors=moved.bind(sensors).sensordata,
    )

  ours = reads(mjx.put_data(scene.model, scene.data))
  dm = scene.dm_physics.copy(share_model=False)
  bind = lambda kind, name: dm.bind(scene.dm_element(kind, name))
  bind('joint', 'hip').qpos = 0.7
  expected = dict(
      foot=bind('site', 'foot').xpos.copy(),
      com_vel=bind('body', 'torso').subtree_linvel.copy(),
      sensors=np.concatenate(
          [bind('sensor', n).sensordata for n in ('acc', 'touch', 'zaxis')]
      ),
  )
  bind('geom', 'torso_geom').pos = pos
  expected['geom'] = bind('geom', 'torso_geom').xpos.copy()
  assert not np.allclose(expected['foot'], scene.data.site('foot').xpos)
  for name, value in expected.items():
    np.testing.assert_allclose(ours[name], value, rtol=2e-5, atol=2e-5)


def test_variation_as_a_corruptor():
  """composer's idiom: `corruptor=noises.Additive(distributions.Normal(...))`
  builds, and the noise is the variation's draw with the corruptor's key.

  That key, by the documented schedule (`runtime/keys.py`, the updater's
  "Randomness"): the reset splits its key in three and the first
  observation takes the second; the sample at timestamp 0 folds in 0, then
  the CRC-32 (31 bits) of '<observable key>#0' (0: the corruptor's
  purpose). `Additive` passes its key to its one operand, and `Normal`
  with constant parameters draws `scale * normal(key, shape)` from it.
  """
  tip = composer.observation.observable.Generic(
      lambda physics: physics.named.data.site_xpos['pendulum/tip'],
      corruptor=noises.Additive(distributions.Normal(scale=0.01)),
  )
  tip.enabled = True

  class Noisy(conftest.SwingTask):

    @property
    def task_observables(self):
      return {'tip': tip}

  task = Noisy()
  env = composer.Environment(task)
  state = env.reset(jax.random.key(0))
  clean = env.physics(state).bind(task.pendulum.tip).xpos
  observation_key = jax.random.split(jax.random.key(0), 3)[1]
  sample_key = jax.random.fold_in(
      jax.random.fold_in(observation_key, 0),
      zlib.crc32(b'tip#0') & 0x7FFFFFFF,
  )
  noise = 0.01 * jax.random.normal(sample_key, (3,), jnp.float32)
  assert np.all(np.abs(np.asarray(noise)) > 1e-4)  # A draw, not a zero.
  # The same float32 sum as the corruptor's.
  np.testing.assert_array_equal(
      np.asarray(state.observation['tip']).reshape(3),
      np.asarray(clean + noise),
  )


def test_random_state_is_refused_with_key_hint():
  rs = np.random.RandomState(0)
  normal = distributions.Normal(scale=0.01)
  for call in (
      lambda: normal(random_state=rs),
      lambda: composer.variation.evaluate(normal, random_state=rs),
      lambda: normal.sample(None, random_state=rs),
  ):
    with pytest.raises(TypeError, match='pass key='):
      call()

  class DrawsAtBuild(conftest.SwingTask):

    def initialize_episode_mjcf(self, random_state):
      self.pendulum.tip.pos = composer.variation.evaluate(
          distributions.Uniform(-0.1, 0.1), random_state=random_state
      )

  # The build-time hook receives no key: the message says what to do there.
  with pytest.raises(
      TypeError,
      match=r'build-time hooks \(initialize_episode_mjcf.*receive no key.*'
      r'MJCFVariator.*or draw the value in initialize_episode',
  ):
    composer.Environment(DrawsAtBuild())


def test_hook_with_random_state_parameter_is_refused():

  class Ported(conftest.SwingTask):

    def after_step(self, physics, random_state):  # pylint: disable=arguments-renamed
      del random_state
      return physics

  env = composer.Environment(Ported())
  # Found at the first trace of a reset, whose analysis traces the step
  # hooks too (for the model fields they write).
  with pytest.raises(TypeError, match='takes random_state.*key'):
    jax.eval_shape(env.reset, jax.random.key(0))


def test_dropped_write_is_refused():
  """`entity.set_pose(physics, ...)` without keeping its result, returning
  the physics the hook received: the write would be lost."""

  class Forgetful(conftest.SwingTask):

    def after_step(self, physics, key):
      del key
      self.ball.set_pose(physics, position=jnp.array([0.0, 0.0, 1.0]))
      return physics

  env = composer.Environment(Forgetful())
  with pytest.raises(ValueError, match='write is lost'):
    jax.eval_shape(env.reset, jax.random.key(0))
