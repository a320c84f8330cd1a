"""EnvironmentHooks: composer's order, stable per-owner keys, field writers.

These run the hooks directly on one world's `Physics` (no jit, no compiled
step), so they are cheap; `test_environment.py` checks the same order
through `reset` and `step`.
"""

import threading
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
from mjx_composer.platform import internals_numpy
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


def test_the_participants_keys_come_from_one_hash():
  # Every participant of a hook gets its key (the test above) from one PRNG
  # call: each call is a kernel of its own on a GPU.
  task = _DrawingTask()
  hooks = hooks_lib.EnvironmentHooks(task)
  assert len(hooks.participants('initialize_episode')) >= 2
  jaxpr = jax.make_jaxpr(
      lambda key: hooks.initialize_episode(_initial(task), key)
  )(jax.random.key(0))
  fold_ins = [
      eqn for eqn in jaxpr.jaxpr.eqns if eqn.primitive.name == 'random_fold_in'
  ]
  assert len(fold_ins) == 1


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


class _HostDraw(composer.NullTask):
  """A pendulum whose hook `hook` sets the hinge from `draw()`, a host draw:
  the habit of composer's hooks, which draw from a NumPy random state."""

  def __init__(self, draw, hook='initialize_episode'):
    arena = composer.Arena()
    self.pendulum = conftest.Pendulum()
    arena.attach(self.pendulum)
    super().__init__(arena)
    self._draw = draw
    if hook == 'before_step':
      self.before_step = self._before_step
    else:
      self.initialize_episode = self._initialize_episode

  def _set(self, physics):
    return physics.bind(self.pendulum.joint).set(qpos=self._draw())

  def _initialize_episode(self, physics, key):
    del key
    return self._set(physics)

  def _before_step(self, physics, action, key):
    physics = super().before_step(physics, action, key)
    return self._set(physics)


def _hook_class(hook):
  """`_HostDraw` with `hook` overridden as a method, as users write it."""
  return type(
      '_HostDraw',
      (_HostDraw,),
      {hook: getattr(_HostDraw, f'_{hook}')},
  )


# Bound when the module is imported, before any hook runs.
_BOUND_UNIFORM = np.random.uniform


@pytest.mark.parametrize(
    'draw, what',
    [
        (lambda: np.random.uniform(-1, 1), r'numpy\.random\.uniform'),
        (lambda: np.random.normal(), r'numpy\.random\.normal'),
        (lambda: np.random.randint(3), r'numpy\.random\.randint'),
        (lambda: np.random.rand(), r'numpy\.random\.rand\)'),
        (lambda: np.random.choice([0.1, 0.2]), r'numpy\.random\.choice'),
        (lambda: np.random.random(), r'numpy\.random\.random\)'),
        (lambda: np.random.seed(0) or 0.0, r'numpy\.random\.seed'),
        (
            lambda: np.random.default_rng(0).uniform(),
            r'numpy\.random\.default_rng',
        ),
        (
            lambda: np.random.RandomState(0).uniform(),
            r'numpy\.random\.RandomState\(\.\.\.\)',
        ),
        (
            lambda: np.random.Generator(np.random.PCG64(0)).uniform(),
            r'numpy\.random\.Generator\(\.\.\.\)',
        ),
    ],
)
def test_host_randomness_in_a_device_hook_is_refused(draw, what):
  """Drawn once at trace time, it would be one value for every world."""
  with pytest.raises(
      hooks_lib.HostRandomnessError,
      match=r'^_HostDraw\.initialize_episode drew host randomness \('
      + what
      + r'.*same in every world and every episode\. Draw from the hook.s '
      r'`key` argument with jax\.random.*build-time hook',
  ):
    _run(_hook_class('initialize_episode')(draw))


@pytest.mark.parametrize(
    'draw',
    [lambda: _BOUND_UNIFORM(), lambda: np.random.mtrand._rand.normal()],
)
def test_a_draw_through_a_name_bound_before_the_hook_is_refused(
    draw, monkeypatch
):
  """The legacy global RandomState, drawn through a name bound before the
  hook: found when the tracing ends (its state moved), where no other Python
  thread runs, which could have drawn meanwhile. The suite's process runs
  other threads (the test runner's, JAX's), so the test stands in for a
  process that runs none."""
  monkeypatch.setattr(internals_numpy.threading, 'active_count', lambda: 1)
  with pytest.raises(
      hooks_lib.HostRandomnessError,
      match=r'^_HostDraw\.initialize_episode drew host randomness \(numpy\.'
      r"random's global RandomState",
  ):
    _run(_hook_class('initialize_episode')(draw))


def test_host_randomness_is_refused_when_the_reset_is_traced():
  """Before any world runs, naming the hook (a step hook too)."""
  env = composer.Environment(
      _hook_class('initialize_episode')(lambda: np.random.uniform())
  )
  with pytest.raises(
      hooks_lib.HostRandomnessError,
      match=r'_HostDraw\.initialize_episode drew host randomness \(numpy\.'
      r'random\.uniform\)',
  ):
    jax.eval_shape(jax.vmap(env.reset), jax.random.split(jax.random.key(0), 2))
  env = composer.Environment(
      _hook_class('before_step')(lambda: np.random.normal())
  )
  # The reset traces the step hooks too (the model fields they write).
  with pytest.raises(
      hooks_lib.HostRandomnessError,
      match=r'_HostDraw\.before_step drew host randomness \(numpy\.random\.'
      r'normal\)',
  ):
    jax.eval_shape(env.reset, jax.random.key(0))


def test_numpy_random_is_restored_after_the_hooks():
  originals = {
      name: getattr(np.random, name)
      for name in ('uniform', 'seed', 'default_rng', 'RandomState')
  }
  with pytest.raises(hooks_lib.HostRandomnessError):
    _run(_hook_class('initialize_episode')(lambda: np.random.uniform()))
  for name, original in originals.items():
    assert getattr(np.random, name) is original, name
  assert 0 <= np.random.default_rng(0).uniform() < 1


def test_device_hooks_without_host_draws_run_as_before():
  """Checks for NumPy generators, and other threads' draws, still work."""
  keep = np.random.RandomState(0)
  seen = {}

  def draw():
    # isinstance answers as for the real classes.
    seen['is_random_state'] = isinstance(keep, np.random.RandomState)
    seen['is_generator'] = isinstance(keep, np.random.Generator)
    seen['subclass'] = issubclass(np.random.RandomState, np.random.RandomState)
    # Another thread draws as it likes.
    thread = threading.Thread(
        target=lambda: seen.update(other=np.random.default_rng(0).uniform())
    )
    thread.start()
    thread.join()
    return jnp.asarray(0.25)

  _, physics = _run(_hook_class('initialize_episode')(draw))
  assert seen == {
      'is_random_state': True,
      'is_generator': False,
      'subclass': True,
      'other': np.random.default_rng(0).uniform(),
  }
  assert float(physics.data.qpos[0]) == 0.25


def test_a_variation_given_a_numpy_state_in_a_hook_still_names_key():
  """The variation's own check of its key sees the real RandomState."""
  keep = np.random.RandomState(0)
  uniform = composer.variation.distributions.Uniform(0.0, 1.0)
  with pytest.raises(TypeError, match='numpy random state'):
    _run(_hook_class('initialize_episode')(lambda: uniform(key=keep)))


def test_build_time_hooks_keep_host_randomness():
  """initialize_episode_mjcf and after_compile run on the host, once."""
  drawn = []

  class _BuildDraws(_Task):

    def initialize_episode_mjcf(self, random_state):
      drawn.append(np.random.uniform())

    def after_compile(self, physics, random_state):
      drawn.append(np.random.default_rng(0).uniform())

  task = _BuildDraws()
  hooks = hooks_lib.EnvironmentHooks(task)
  hooks.initialize_episode_mjcf(np.random.RandomState(0))
  hooks.after_compile(_initial(task), np.random.RandomState(0))
  assert len(drawn) == 2
