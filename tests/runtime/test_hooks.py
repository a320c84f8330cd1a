"""EnvironmentHooks: composer's order, stable per-owner keys, field writers.

These run the hooks directly on one world's `Physics` (no jit, no compiled
step), so they are cheap; `test_environment.py` checks the same order
through `reset` and `step`.
"""

import warnings
import zlib

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.model import element_index
from mjx_composer.runtime import hooks as hooks_lib
from mjx_composer.runtime import transitions
from mjx_composer.utils import stable_id as stable_id_lib
from tests import conftest


class Box(conftest.SpecEntity):
  """A free box that draws a number into its entity state per episode."""

  def _build(self, name='box', draws=True):
    spec = self._new_spec(name)
    self.geom = spec.worldbody.add_body(name='body').add_geom(
        name='geom', type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.1, 0.1, 0.1]
    )
    self.draws = draws

  def initial_state(self):
    return {'draw': jnp.zeros(()), 'order': jnp.zeros((), jnp.int32)}

  def initialize_episode(self, physics, key):
    if not self.draws:
      return physics
    counter = physics.task_state['calls']
    physics = physics.update_task_state(calls=counter + 1)
    return physics.update_entity_state(
        self, draw=jax.random.uniform(key), order=counter
    )


class Recolour(Box):
  """A box whose hook also writes a model field."""

  def initialize_episode(self, physics, key):
    physics = super().initialize_episode(physics, key)
    return physics.bind(self.geom).set(rgba=jnp.array([1.0, 0, 0, 1]))


class _Task(composer.Task):

  def __init__(self, extra_entity=False):
    self.arena = composer.Arena()
    self.first = Box(name='first', draws=extra_entity)
    self.second = Recolour(name='second')
    self.arena.attach(self.first)
    self.arena.attach(self.second)

  @property
  def root_entity(self):
    return self.arena

  def initial_task_state(self):
    return {'calls': jnp.zeros((), jnp.int32), 'task_draw': jnp.zeros(())}

  def get_reward(self, physics):
    return 0.0


class _DrawingTask(_Task):
  """Overrides one more hook: what used to shift every later owner's key."""

  def initialize_episode(self, physics, key):
    return physics.update_task_state(task_draw=jax.random.uniform(key))


def _initial(task):
  """A fresh world of `task`'s compiled model."""
  spec, handles = task.root_entity.compose()
  model = spec.compile()
  index = element_index.ElementIndex(
      model, {k: (h, kind, c.name) for k, (h, kind, c) in handles.items()}
  )
  mjx_model = mjx.put_model(model)
  return transitions.initial_physics(
      task, mjx_model, mjx.make_data(mjx_model), index
  )


def _run(task, name='initialize_episode'):
  """The hooks' run on a fresh world of `task`'s compiled model."""
  hooks = hooks_lib.EnvironmentHooks(task)
  return hooks, getattr(hooks, name)(_initial(task), jax.random.key(0))


def test_entities_run_after_the_task_in_attachment_order():
  task = _Task(extra_entity=True)
  _, physics = _run(task)
  assert int(physics.entity_state(task.first)['order']) == 0
  assert int(physics.entity_state(task.second)['order']) == 1
  assert int(physics.task_state['calls']) == 2


def test_overriding_another_hook_does_not_change_an_owners_draw():
  draws = []
  for variant in (
      _Task(),
      _DrawingTask(),  # The task overrides one more hook.
      _Task(extra_entity=True),  # An earlier entity overrides it too.
  ):
    _, physics = _run(variant)
    draws.append(float(physics.entity_state(variant.second)['draw']))
    if isinstance(variant, _DrawingTask):
      assert float(physics.task_state['task_draw']) not in (0.0, draws[0])
    if variant.first.draws:
      # Another owner, the same hook key: another draw.
      assert float(physics.entity_state(variant.first)['draw']) != draws[0]
  assert draws[0] == draws[1] == draws[2]


def test_keys_derive_from_stable_identities():
  # The CRC-32 of the UTF-8 text, its top bit cleared (the same in every
  # process and release), computed here by zlib.
  for identity in ('task', 'entity:second/', 'extra:after_step:0', 'arm/ü'):
    crc = zlib.crc32(identity.encode('utf-8'))
    assert stable_id_lib.stable_digest(identity) == crc
    assert stable_id_lib.stable_id(identity) == crc & 0x7FFFFFFF
  assert stable_id_lib.stable_id('task') == 1384045349
  # A hook's key is the reset's key with its owner's id folded in: the
  # task's under 'task', an entity's under 'entity:<full identifier>'.
  task = _DrawingTask()
  _, physics = _run(task)
  key = jax.random.key(0)
  expected = {
      'task': jax.random.uniform(
          jax.random.fold_in(key, zlib.crc32(b'task') & 0x7FFFFFFF)
      ),
      'second': jax.random.uniform(
          jax.random.fold_in(key, zlib.crc32(b'entity:second/') & 0x7FFFFFFF)
      ),
  }
  assert float(physics.task_state['task_draw']) == float(expected['task'])
  assert float(physics.entity_state(task.second)['draw']) == float(
      expected['second']
  )
  assert expected['task'] != expected['second']


def test_model_field_writers_name_the_hook():
  task = _Task()
  hooks, physics = _run(task)
  writers = hooks.model_field_writers(
      'initialize_episode', _initial(task), jax.random.key(0)
  )
  assert writers == {'geom_rgba': ("Recolour('second').initialize_episode",)}
  np.testing.assert_array_equal(
      physics.bind(task.second.geom).rgba, [1.0, 0, 0, 1]
  )


def test_a_hook_that_returns_no_physics_is_a_clear_error():
  task = _Task()
  task.second.initialize_episode = lambda physics, key: None
  with pytest.raises(TypeError, match=r"Recolour\('second'\).*must return"):
    _run(task)


def test_entity_state_is_declared_and_typed():
  task = _Task(extra_entity=True)
  _, physics = _run(task)
  with pytest.raises(KeyError, match='declare them in'):
    physics.update_entity_state(task.first, unknown=1.0)
  with pytest.raises(KeyError, match='has no per-episode state'):
    physics.entity_state(task.arena)
  # Writes keep the declared dtype and shape.
  physics = physics.update_entity_state(task.first, order=3.7)
  assert physics.entity_state(task.first)['order'].dtype == jnp.int32


def test_extra_hooks_are_validated():
  hooks = hooks_lib.EnvironmentHooks(_Task())
  with pytest.raises(ValueError, match='not a valid hook name'):
    hooks.add_extra_hook('before_episode', lambda p, k: p)
  with pytest.raises(ValueError, match='not a callable'):
    hooks.add_extra_hook('after_step', 3)


class _PlacesTargetAtBuild(_Task):
  """dm_control's way to place a target: an MJCF edit drawn from the
  RandomState in `initialize_episode_mjcf`."""

  def initialize_episode_mjcf(self, random_state):
    self.first.geom.pos = [random_state.uniform(-1, 1), 0.0, 0.0]


class _DrawingBox(Box):

  def initialize_episode_mjcf(self, random_state):
    self.geom.size = [random_state.uniform(0.05, 0.1)] * 3


class _VariesTheComposerWay(_Task):
  """An MJCF variator applied composer's way, and an edit drawn from
  nothing: nothing is drawn at build."""

  def __init__(self):
    super().__init__()
    self.variator = composer.variation.MJCFVariator()
    self.variator.bind_attributes(
        self.first.geom,
        friction=composer.variation.distributions.Uniform(
            [0.5, 0.005, 0.0001], [1.5, 0.005, 0.0001]
        ),
    )

  def initialize_episode_mjcf(self, random_state):
    self.variator.apply_variations(random_state)
    self.second.geom.size = [0.2, 0.2, 0.2]


def test_a_draw_in_initialize_episode_mjcf_is_warned_with_the_fix():
  random_state = np.random.RandomState(0)
  with pytest.warns(
      hooks_lib.BuildTimeDrawWarning,
      match=r'_PlacesTargetAtBuild\.initialize_episode_mjcf drew from '
      r'random_state.*same in every world and every episode.*MJCFVariator',
  ):
    hooks_lib.EnvironmentHooks(_PlacesTargetAtBuild()).initialize_episode_mjcf(
        random_state
    )
  task = _Task()
  task.arena.attach(_DrawingBox(name='third'))
  with pytest.warns(
      hooks_lib.BuildTimeDrawWarning,
      match=r"_DrawingBox\('third'\)\.initialize_episode_mjcf drew",
  ) as record:
    hooks_lib.EnvironmentHooks(task).initialize_episode_mjcf(random_state)
  assert len(record) == 1  # The other owners drew nothing.
  task = _VariesTheComposerWay()
  hooks = hooks_lib.EnvironmentHooks(task)
  with warnings.catch_warnings():
    warnings.simplefilter('error', hooks_lib.BuildTimeDrawWarning)
    hooks.initialize_episode_mjcf(random_state)
  # The variator is recorded, and draws per episode from the reset's key.
  physics = _initial(task)
  writers = {}
  varied = hooks.episode_variations(physics, jax.random.key(1), writers)
  assert list(writers) == ['geom_friction']
  assert not np.allclose(
      varied.model.geom_friction, physics.model.geom_friction
  )
