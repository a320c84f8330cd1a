"""Entities built on PyMJCF (`dm_control.mjcf`) compose with MjSpec entities.

The reference is dm_control itself: the same PyMJCF entities attached with
PyMJCF's own `attach` and compiled by `mjcf.Physics`, whose `bind` reads
MuJoCo's C library on the host.
"""

from dm_control import mjcf
from dm_control.entities import props as dm_props
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer import initializers
from mjx_composer import variation
from mjx_composer.observation import observable
from mjx_composer.variation import distributions

_NO_CONTACT = dict(contype=0, conaffinity=0)


class Ball(composer.Entity):
  """A PyMJCF entity: a body with a sphere, a site, a hinge and a sensor."""

  def _build(self, name='ball'):
    self._root = mjcf.RootElement(model=name)
    body = self._root.worldbody.add('body', name='body', pos=[0.1, 0, 0])
    self.hinge = body.add('joint', name='hinge', type='hinge', axis=[0, 1, 0])
    self.geom = body.add('geom', type='sphere', size=[0.1], **_NO_CONTACT)
    self.site = body.add('site', name='top', pos=[0, 0, 0.1])
    self.sensor = self._root.sensor.add(
        'framepos', objtype='site', objname=self.site
    )
    self.motor = self._root.actuator.add('motor', joint=self.hinge)

  @property
  def mjcf_model(self):
    return self._root


class Box(composer.Entity):
  """An MjSpec entity with a site to attach at."""

  def _build(self, name='box'):
    self._spec = mujoco.MjSpec()
    self._spec.modelname = name
    body = self._spec.worldbody.add_body(name='b', pos=[0, 0.2, 0])
    self.geom = body.add_geom(
        type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.05] * 3, **_NO_CONTACT
    )
    self.site = body.add_site(name='s', pos=[0, 0, 0.05])

  @property
  def mjcf_model(self):
    return self._spec


class Floor(composer.Arena):
  """An arena written as dm_control's are, against `self._mjcf_root`."""

  def _build(self, name='floor'):
    super()._build(name=name)
    self.ground = self._mjcf_root.worldbody.add(
        'geom', type='plane', size=[2, 2, 0.1], **_NO_CONTACT
    )


def _scene():
  """Floor <- Ball (free) <- Box at the ball's PyMJCF site <- Ball at the
  box's MjsSite: attachments both ways."""
  arena, ball, box, inner = Floor(), Ball(), Box(), Ball('inner')
  arena.add_free_entity(ball)
  ball.attach(box, ball.site)
  box.attach(inner, box.site)
  return arena, ball, box, inner


def _dm_tree():
  """The scene composed by dm_control: PyMJCF's own attach."""
  root = Floor()._mjcf_root
  dm_ball, dm_inner = Ball(), Ball('inner')
  root.attach(dm_ball.mjcf_model).add('freejoint')
  # PyMJCF attaches PyMJCF models only: the MjSpec box, written in PyMJCF.
  box_model = mjcf.RootElement(model='box')
  body = box_model.worldbody.add('body', name='b', pos=[0, 0.2, 0])
  body.add('geom', type='box', size=[0.05] * 3, **_NO_CONTACT)
  body.add('site', name='s', pos=[0, 0, 0.05])
  dm_ball.site.attach(box_model)
  box_model.find('site', 's').attach(dm_inner.mjcf_model)
  return root, dm_ball, dm_inner


@pytest.fixture(scope='module')
def scene():
  arena, ball, box, inner = _scene()
  env = composer.Environment(composer.NullTask(arena))
  state = jax.jit(env.reset)(jax.random.key(0))
  return env, env.physics(state), (arena, ball, box, inner)


def test_names_are_composers(scene):
  env, _, _ = scene
  model = env.mj_model
  bodies = {model.body(i).name for i in range(model.nbody)}
  assert {
      'ball/',
      'ball/body',
      'ball/box/',
      'ball/box/b',
      'ball/box/inner/',
      'ball/box/inner/body',
  } <= bodies
  assert model.joint('ball/box/inner/hinge').id >= 0
  assert model.site('ball/box/s').id >= 0
  assert model.nu == 2 and model.nsensor == 2


def test_pymjcf_elements_bind_as_dm_control_binds_them(scene):
  env, physics, (arena, ball, box, inner) = scene
  root, dm_ball, dm_inner = _dm_tree()
  dm_physics = mjcf.Physics.from_mjcf_model(root)
  assert dm_physics.model.nq == env.mj_model.nq

  qpos = np.array([0.3, -0.2, 0.5, 0.9, 0.1, -0.3, 0.2, 0.4, -0.7], np.float32)
  qpos[3:7] /= np.linalg.norm(qpos[3:7])

  @jax.jit
  def read(p):
    p = p.bind(ball.freejoint).set(qpos=qpos[:7])
    p = p.bind([ball.hinge, inner.hinge]).set(qpos=qpos[7:]).forward()
    return (
        p.bind([ball.site, inner.site]).xpos,
        p.bind(inner.geom).xpos,
        p.bind(box.site).xpos,
        p.bind([ball.sensor, inner.sensor]).sensordata,
        p.bind(inner.hinge).qpos,
        p.bind(ball.freejoint).qpos,
    )

  sites, geom, box_site, sensors, hinge, free = read(physics)
  dm_physics.data.qpos[:] = qpos
  dm_physics.forward()
  np.testing.assert_allclose(
      sites, dm_physics.bind([dm_ball.site, dm_inner.site]).xpos, atol=1e-6
  )
  np.testing.assert_allclose(
      geom, dm_physics.bind(dm_inner.geom).xpos, atol=1e-6
  )
  np.testing.assert_allclose(
      box_site, dm_physics.named.data.site_xpos['ball/box/s'], atol=1e-6
  )
  np.testing.assert_allclose(
      sensors,
      dm_physics.bind([dm_ball.sensor, dm_inner.sensor]).sensordata,
      atol=1e-6,
  )
  np.testing.assert_allclose(hinge, qpos[8:], atol=1e-7)
  np.testing.assert_allclose(free, qpos[:7], atol=1e-7)


def test_observables_and_variators_take_pymjcf_elements(scene):
  _, physics, (arena, ball, _, inner) = scene
  feature = observable.MJCFFeature('xpos', [ball.site, inner.site])[:, 2]
  variator = variation.PhysicsVariator()
  variator.bind_attributes(
      ball.geom, friction=distributions.Uniform([0.5, 0, 0], [1.5, 0, 0])
  )
  variator.bind_attributes(arena.ground, rgba=jnp.array([1.0, 0, 0, 1]))

  @jax.jit
  def run(p, key):
    p = variator.apply_variations(p, key)
    return (
        feature.observation_callable(p)(),
        p.bind([ball.site, inner.site]).xpos[:, 2],
        p.bind(ball.geom).friction,
        p.model.geom_friction,
        p.model.geom_rgba,
    )

  observed, xpos_z, friction, all_friction, rgba = run(
      physics, jax.random.key(1)
  )
  np.testing.assert_array_equal(observed, xpos_z)
  geom_id = physics.index.element_id(
      physics.index.resolve(ball.geom)[0], ball.geom
  )
  assert 0.5 <= float(friction[0]) <= 1.5
  assert float(all_friction[geom_id, 0]) == float(friction[0])
  ground_id = physics.bind(arena.ground).element_ids[0]
  np.testing.assert_array_equal(rgba[ground_id], [1.0, 0, 0, 1])


def test_an_element_outside_the_model_is_named(scene):
  _, physics, _ = scene
  stray = Ball('stray')
  with pytest.raises(ValueError, match=r"<site> 'top' of PyMJCF model 'stray'"):
    physics.bind(stray.site)
  with pytest.raises(TypeError, match='only PyMJCF body, geom'):
    physics.bind(stray.mjcf_model.compiler)


def test_pymjcf_calls_on_an_mjspec_say_what_to_use():
  class Ported(Box):

    def _build(self):
      super()._build()
      self._spec.find_all('geom')

  with pytest.raises(AttributeError, match=r'spec\.geoms'):
    Ported()


def test_attachment_errors_name_the_fix():
  box, ball = Box(), Ball()
  with pytest.raises(TypeError, match='DmControlEntity'):
    box.attach(dm_props.Primitive(geom_type='sphere', size=[0.1]))
  with pytest.raises(TypeError, match="'box'.s model is an MjSpec"):
    box.attach(Ball('other'), ball.site)
  with pytest.raises(ValueError, match="not an element of 'ball'"):
    ball.attach(Ball('other'), Ball('third').site)
  with pytest.raises(TypeError, match='PyMJCF sites or bodies'):
    ball.attach(Ball('other'), box.site)


def test_detach_restores_a_pymjcf_model():
  ball = Ball()
  before = ball.mjcf_model.to_xml_string()
  child = Box()
  ball.attach(child, ball.site)
  assert ball.mjcf_model.to_xml_string() != before
  child.detach()
  assert ball.mjcf_model.to_xml_string() == before
  assert child.parent is None


class Corridor(composer.Arena):
  """A PyMJCF arena whose `regenerate` resizes and moves existing geoms."""

  def _build(self):
    super()._build(name='corridor')
    self.ground = self._mjcf_root.worldbody.add(
        'geom', type='plane', size=[1, 1, 0.1], **_NO_CONTACT
    )
    self.wall = self._mjcf_root.worldbody.add(
        'geom', type='box', size=[1, 0.1, 0.5], **_NO_CONTACT
    )

  def regenerate(self, random_state):
    width = random_state.uniform(1.0, 3.0)
    self.ground.size = [4, width / 2, 0.1]
    self.wall.pos = [0, width / 2, 0.5]
    self.wall.size = [2, 0.1, width / 4]


def test_regenerate_per_episode_gives_each_world_a_compiled_layout():
  arena = Corridor()
  arena.add_free_entity(Ball())
  arena.regenerate_per_episode(3)
  env = composer.Environment(composer.NullTask(arena), random_state=0)
  states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), 6))
  physics = env.physics(states)
  wall = physics.bind(arena.wall).element_ids[0]
  ground = physics.bind(arena.ground).element_ids[0]
  sizes = np.asarray(physics.model.geom_size)
  assert len({tuple(s) for s in sizes[:, wall]}) > 1  # layouts differ
  for world in range(6):
    # Each world's fields are those MuJoCo's compiler gives its layout.
    width = 4 * sizes[world, wall, 2]
    reference = Corridor()
    reference.ground.size = [4, width / 2, 0.1]
    reference.wall.pos = [0, width / 2, 0.5]
    reference.wall.size = [2, 0.1, width / 4]
    compiled = mjcf.Physics.from_mjcf_model(reference.mjcf_model).model
    for field in ('geom_size', 'geom_pos', 'geom_rbound', 'geom_aabb'):
      values = np.asarray(getattr(physics.model, field))[world]
      expected = getattr(compiled, field)
      expected = expected.reshape(expected.shape[:1] + values.shape[1:])
      np.testing.assert_allclose(values[wall], expected[1], rtol=1e-6)
      np.testing.assert_allclose(values[ground], expected[0], rtol=1e-6)


def test_a_regeneration_that_changes_the_structure_is_refused():

  class Growing(Corridor):

    def regenerate(self, random_state):
      self._mjcf_root.worldbody.add('geom', type='sphere', size=[0.1])

  arena = Growing()
  arena.add_free_entity(Ball())
  arena.regenerate_per_episode(2)
  with pytest.raises(ValueError, match='model structure'):
    composer.Environment(composer.NullTask(arena))


def test_mjcf_variator_takes_pymjcf_elements(scene):
  env, physics, (_, ball, _, inner) = scene
  variator = variation.MJCFVariator()
  # MjSpec's shapes: a sphere's size has 3 entries.
  variator.bind_attributes(
      inner.geom, size=distributions.Uniform([0.05, 0, 0], [0.2, 0, 0])
  )

  @jax.jit
  def run(p, key):
    p = variator.apply_variations(p, key)
    return p.bind(inner.geom).size, p.model.body_mass

  size, body_mass = run(physics, jax.random.key(2))
  # The reference: dm_control compiles the tree with that radius.
  root, _, dm_inner = _dm_tree()
  dm_inner.geom.size = [float(size[0])]
  compiled = mjcf.Physics.from_mjcf_model(root).named.model.body_mass
  inner_body = env.mj_model.body('ball/box/inner/body').id
  np.testing.assert_allclose(
      body_mass[inner_body], compiled['ball/box/inner/body'], rtol=1e-5
  )
  assert 0.05 <= float(size[0]) <= 0.2


def test_prop_placer_places_a_pymjcf_prop(scene):
  _, physics, (_, ball, _, _) = scene
  placer = initializers.PropPlacer(
      [ball], position=distributions.Uniform([-1, -1, 1], [1, 1, 2])
  )
  placed = jax.jit(placer)(physics, jax.random.key(3))
  position = np.asarray(placed.bind(ball.freejoint).qpos[:3])
  assert np.all(position >= [-1, -1, 1]) and np.all(position <= [1, 1, 2])
  assert not bool(placed.initialization_failed)
