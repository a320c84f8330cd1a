"""PositionDetector: membership per world, 2D/3D, inverted, moved, retained."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.suite.entities import position_detector
from mjx_composer.suite.entities import props

_WORLDS = 200
_CUBE_SIZE = np.array([0.3, 0.3, 0.3])
_FLAT_POS, _FLAT_SIZE = np.array([0.4, 0.4]), np.array([0.3, 0.2])
_SUBSTEPS = 5


def _sphere(name):
  return props.Sphere(radius=0.02, name=name, contype=0, conaffinity=0)


class DetectorTask(composer.Task):
  """Spheres scattered per world; a cube zone moved per world; a flat,
  inverted zone; and a runner crossing two thin zones within one step."""

  def __init__(self):
    self.arena = composer.Arena()
    self.arena.mjcf_model.option.gravity = [0, 0, 0]
    self.spheres = [_sphere(f'sphere_{i}') for i in range(3)]
    self.runner = _sphere('runner')
    for entity in self.spheres + [self.runner]:
      self.arena.add_free_entity(entity)
    self.cube = position_detector.PositionDetector(
        pos=(0.0, 0.0, 0.5), size=_CUBE_SIZE, name='cube'
    )
    self.flat = position_detector.PositionDetector(
        pos=_FLAT_POS, size=_FLAT_SIZE, inverted=True, visible=True, name='flat'
    )
    thin = dict(pos=(0.0, 0.0, 1.0), size=(0.003, 0.5, 0.5))
    self.thin = position_detector.PositionDetector(name='thin', **thin)
    self.thin_retained = position_detector.PositionDetector(
        name='thin_retained', retain_substep_detections=True, **thin
    )
    for detector in (self.cube, self.flat, self.thin, self.thin_retained):
      self.arena.attach(detector)
      detector.observables.enable_all()
    self.cube.register_entities(*self.spheres)
    self.flat.register_entities(*self.spheres)
    self.thin.register_entities(self.runner)
    self.thin_retained.register_entities(self.runner)
    self.set_timesteps(
        control_timestep=0.004 * _SUBSTEPS, physics_timestep=0.004
    )

  @property
  def root_entity(self):
    return self.arena

  def initial_task_state(self):
    return {'centre': jnp.zeros(3)}

  def initialize_episode(self, physics, key):
    centre_key, *keys = jax.random.split(key, 4)
    centre = jax.random.uniform(centre_key, (3,), minval=-0.3, maxval=0.3)
    centre = centre.at[2].add(0.5)
    physics = self.cube.set_position(physics, centre)
    for sphere, sphere_key in zip(self.spheres, keys):
      physics = sphere.set_pose(
          physics,
          jax.random.uniform(
              sphere_key,
              (3,),
              minval=jnp.array([-0.8, -0.8, 0.0]),
              maxval=jnp.array([0.8, 0.8, 1.0]),
          ),
      )
    # The runner crosses x = 0 at 1 m/s: inside the thin zones during the
    # middle sub-steps of the first control step only.
    physics = self.runner.set_pose(physics, jnp.array([-0.006, 0.0, 1.0]))
    physics = self.runner.set_velocity(physics, jnp.array([1.0, 0.0, 0.0]))
    return physics.update_task_state(centre=centre)

  def get_reward(self, physics):
    return 0.0


@pytest.fixture(scope='module')
def detection():
  task = DetectorTask()
  env = composer.Environment(task, strip_singleton_obs_buffer_dim=True)
  keys = jax.random.split(jax.random.key(0), _WORLDS)
  states = jax.jit(jax.vmap(env.reset))(keys)
  stepped = jax.jit(jax.vmap(env.step))(states, jnp.zeros((_WORLDS, 0)))
  return task, env, states, stepped


def _positions(env, states, entities):
  model = env.mj_model
  qpos = np.asarray(states.data.qpos)
  return np.stack(
      [
          qpos[:, model.jnt_qposadr[model.body(f'{e.name}/').jntadr[0]] :][
              :, :3
          ]
          for e in entities
      ],
      axis=1,
  )


def test_membership_matches_hand_computed_values(detection):
  task, env, states, _ = detection
  positions = _positions(env, states, task.spheres)  # (worlds, 3, 3)
  centre = np.asarray(states.task_state['centre'])[:, None]
  inside_cube = np.all(np.abs(positions - centre) < _CUBE_SIZE, axis=-1)
  outside_flat = ~np.all(
      np.abs(positions[..., :2] - _FLAT_POS) < _FLAT_SIZE, axis=-1
  )
  np.testing.assert_array_equal(
      states.observation['cube/detected'], inside_cube
  )
  np.testing.assert_array_equal(
      states.observation['flat/detected'], outside_flat
  )
  # Both outcomes happen often enough to mean something.
  assert 0.05 < inside_cube.mean() < 0.5
  assert 0.5 < outside_flat.mean() < 0.95
  # The same answer from the functional API, in one world.
  physics = env.physics(jax.tree.map(lambda x: x[7], states))
  np.testing.assert_array_equal(
      task.cube.detected_entities(physics), inside_cube[7]
  )
  assert bool(task.cube.activated(physics)) == inside_cube[7].any()


def test_sensors_report_the_region(detection):
  task, env, states, _ = detection
  centre = np.asarray(states.task_state['centre'])
  np.testing.assert_allclose(
      states.observation['cube/lower'], centre - _CUBE_SIZE, atol=1e-6
  )
  np.testing.assert_allclose(states.observation['cube/mid'], centre, atol=1e-6)
  np.testing.assert_allclose(
      states.observation['cube/upper'], centre + _CUBE_SIZE, atol=1e-6
  )
  # A 2D detector's corners lie at z = 0.
  np.testing.assert_allclose(
      states.observation['flat/lower'][0],
      np.append(_FLAT_POS - _FLAT_SIZE, 0.0),
      atol=1e-6,
  )
  np.testing.assert_allclose(task.flat.mid, _FLAT_POS)
  # Where the region was moved per world, the model field is per world.
  assert 'site_pos' in states.model_fields


def test_substep_detections_are_retained_when_asked(detection):
  task, env, states, stepped = detection
  assert not np.any(states.observation['thin/detected'])
  assert not np.any(states.observation['thin_retained/detected'])
  # After one control step the runner has crossed the zone and left it.
  runner_x = _positions(env, stepped, [task.runner])[:, 0, 0]
  assert np.all(runner_x > 0.01)
  assert not np.any(stepped.observation['thin/detected'])
  assert np.all(stepped.observation['thin_retained/detected'])


def test_spec_and_validation():
  detector = position_detector.PositionDetector(
      pos=(1.0, 2.0), size=(0.5, 0.5), name='zone'
  )
  assert detector.zone_site.group == composer.SENSOR_SITES_GROUP
  np.testing.assert_allclose(detector.zone_site.size, [0.5, 0.5, 0.01])
  np.testing.assert_allclose(detector.lower, [0.5, 1.5])
  detector.resize(pos=(0.0, 0.0), size=(1.0, 1.0))
  np.testing.assert_allclose(detector.upper_site.pos, [1.0, 1.0, 0.0])
  with pytest.raises(ValueError, match='same length'):
    position_detector.PositionDetector(pos=(0.0, 0.0, 0.0), size=(1.0, 1.0))
  with pytest.raises(ValueError, match='same length'):
    detector.resize(pos=(0.0, 0.0, 0.0), size=(1.0, 1.0, 1.0))
  assert mujoco.mjtGeom(detector.zone_site.type) == mujoco.mjtGeom.mjGEOM_BOX
