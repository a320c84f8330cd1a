"""Tests for observation groups and flattening."""

import collections

from dm_env import specs
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_composer.observation import fake_physics
from mjx_composer.observation import flatten
from mjx_composer.observation import groups as groups_lib
from mjx_composer.observation import updater as updater_lib
from mjx_composer.observation.observable import base

ObservationGroup = groups_lib.ObservationGroup


class _Counting:
  """Counts how often an observable function is traced."""

  def __init__(self, fn):
    self.fn, self.calls = fn, 0

  def __call__(self, physics):
    self.calls += 1
    return self.fn(physics)


class _Bounded(base.Generic):

  @property
  def array_spec(self):
    return specs.BoundedArray(
        (2,), np.float32, minimum=[-1.0, -2.0], maximum=[1.0, 2.0]
    )


def _shift(value, key):
  del key
  return value + 100.0


def _observables():
  fns = {
      'joints': _Counting(
          lambda p: jnp.stack([p.time(), -p.time()]).astype(jnp.float32)
      ),
      'touch': _Counting(lambda p: p.time().astype(jnp.float32)),
      'target': _Counting(lambda p: jnp.full((2,), 0.5, jnp.float32)),
      'unused': _Counting(lambda p: p.time()),
  }
  observables = collections.OrderedDict(
      joints=base.Generic(fns['joints'], corruptor=_shift, buffer_size=2),
      touch=base.Generic(
          fns['touch'], corruptor=_shift, buffer_size=2, aggregator='sum'
      ),
      target=_Bounded(fns['target']),
      unused=base.Generic(fns['unused']),
      disabled=base.Generic(lambda p: p.time()),
  )
  for key, obs in observables.items():
    obs.enabled = key != 'disabled'
  return observables, fns


_GROUPS = {
    'policy': ObservationGroup(keys=['joints', 'touch']),
    'critic': ObservationGroup(
        keys=['target', 'joints', 'touch'], corrupted=False
    ),
}


def _step(updater, n=2, steps=2):
  physics = fake_physics.FakePhysics.create()
  state = updater.reset(physics, jax.random.key(0))
  for _ in range(steps):
    for j in range(1, n + 1):
      physics = physics.step()
      state = updater.update(state, physics, jax.random.key(j), j)
  return state


def test_policy_sees_corrupted_and_critic_clean_values():
  observables, fns = _observables()
  updater = updater_lib.Updater(observables, 2, groups=_GROUPS)
  observation = updater.get_observation(_step(updater))
  assert list(observation) == ['policy', 'critic']
  assert type(observation['policy']) is collections.OrderedDict
  assert list(observation['policy']) == ['joints', 'touch']
  assert list(observation['critic']) == ['target', 'joints', 'touch']
  # t = 4: buffers hold samples 3 and 4.
  clean_joints = np.array([[3.0, -3.0], [4.0, -4.0]])
  np.testing.assert_allclose(observation['critic']['joints'], clean_joints)
  np.testing.assert_allclose(
      observation['policy']['joints'], clean_joints + 100.0
  )
  np.testing.assert_allclose(observation['critic']['touch'], 7.0)
  np.testing.assert_allclose(observation['policy']['touch'], 207.0)
  np.testing.assert_allclose(observation['critic']['target'], [[0.5, 0.5]])
  assert fns['unused'].calls == 0  # In no group: never evaluated.


def test_raw_value_evaluated_once_per_sample_for_both_groups():
  observables, fns = _observables()
  updater = updater_lib.Updater(observables, 2, groups=_GROUPS)
  physics = fake_physics.FakePhysics.create()
  state = updater.reset(physics, jax.random.key(0))
  for fn in fns.values():
    fn.calls = 0
  jax.make_jaxpr(lambda s: updater.update(s, physics, jax.random.key(0), 2))(
      state
  )
  assert fns['joints'].calls == 1 and fns['touch'].calls == 1


def test_clean_values_buffered_only_when_needed():
  observables, _ = _observables()
  both = updater_lib.Updater(observables, 2, groups=_GROUPS)
  state = both.reset(fake_physics.FakePhysics.create(), jax.random.key(0))
  streams = {k: sorted(b.values) for k, b in zip(both.keys, state.buffers)}
  assert streams == {
      'joints': ['clean', 'value'],
      'touch': ['clean', 'value'],
      'target': ['value'],
  }  # target has no corruptor.
  only_policy = updater_lib.Updater(
      observables, 2, groups={'policy': ObservationGroup(keys=['joints'])}
  )
  state = only_policy.reset(
      fake_physics.FakePhysics.create(), jax.random.key(0)
  )
  assert only_policy.keys == ('joints',)
  assert sorted(state.buffers[0].values) == ['value']
  only_critic = updater_lib.Updater(
      observables,
      2,
      groups={'critic': ObservationGroup(keys=['joints'], corrupted=False)},
  )
  state = only_critic.reset(fake_physics.FakePhysics.create())  # No key.
  assert sorted(state.buffers[0].values) == ['clean']


def test_group_specs_match_observations():
  observables, _ = _observables()
  updater = updater_lib.Updater(observables, 2, groups=_GROUPS)
  observation = updater.get_observation(_step(updater))
  spec = updater.observation_spec()
  assert list(spec) == ['policy', 'critic']
  assert list(spec['critic']) == ['target', 'joints', 'touch']
  assert spec['policy']['joints'].shape == (2, 2)
  assert spec['policy']['touch'].shape == ()
  assert type(spec['critic']['target']) is specs.BoundedArray
  for group, group_spec in spec.items():
    for key, value in group_spec.items():
      value.validate(np.asarray(observation[group][key]))


def test_default_group_holds_every_enabled_observable():
  observables, _ = _observables()
  updater = updater_lib.Updater(
      observables, 1, groups={'all': ObservationGroup()}
  )
  spec = updater.observation_spec(fake_physics.FakePhysics.create())
  assert list(spec['all']) == ['joints', 'touch', 'target', 'unused']


def test_flattened_groups():
  observables, _ = _observables()
  groups = {
      'state': ObservationGroup(keys=['joints', 'touch'], flatten=True),
      'privileged_state': ObservationGroup(
          keys=['touch', 'target'], corrupted=False, flatten=True
      ),
  }
  updater = updater_lib.Updater(observables, 2, groups=groups)
  state = _step(updater)
  observation = jax.jit(updater.get_observation)(state)
  np.testing.assert_allclose(
      observation['state'], [103.0, 97.0, 104.0, 96.0, 207.0]
  )
  np.testing.assert_allclose(observation['privileged_state'], [7.0, 0.5, 0.5])
  assert observation['state'].dtype == jnp.float32
  spec = updater.observation_spec()
  assert type(spec['state']) is specs.Array
  assert spec['state'].shape == (5,) and spec['state'].name == 'state'
  privileged = spec['privileged_state']
  assert type(privileged) is specs.BoundedArray
  np.testing.assert_array_equal(privileged.minimum, [-np.inf, -1.0, -2.0])
  np.testing.assert_array_equal(privileged.maximum, [np.inf, 1.0, 2.0])
  for key, value in observation.items():
    spec[key].validate(np.asarray(value))


def test_group_errors():
  observables, _ = _observables()
  with pytest.raises(KeyError, match="'critic' refers to 'nope'"):
    updater_lib.Updater(
        observables, groups={'critic': ObservationGroup(keys=['nope'])}
    )
  with pytest.raises(ValueError, match="'disabled', which is not enabled"):
    updater_lib.Updater(
        observables, groups={'critic': ObservationGroup(keys=['disabled'])}
    )
  with pytest.raises(ValueError, match='lists a key twice'):
    updater_lib.Updater(
        observables,
        groups={'critic': ObservationGroup(keys=['touch', 'touch'])},
    )
  with pytest.raises(ValueError, match='need a dict of observables'):
    updater_lib.Updater([observables], groups={'a': ObservationGroup()})
  with pytest.raises(TypeError, match='must be an ObservationGroup'):
    updater_lib.Updater(observables, groups={'a': ['touch']})


def test_flattener_round_trip_and_batches():
  spec_dict = collections.OrderedDict(
      b=specs.Array((2, 3), np.float32),
      a=specs.Array((), np.int32),
      c=specs.BoundedArray((2,), np.float32, minimum=0.0, maximum=[1.0, 2.0]),
  )
  flattener = flatten.Flattener(spec_dict, name='flat')
  assert flattener.keys == ('b', 'a', 'c')  # The dict's order, not sorted.
  assert flattener.spec.shape == (9,)
  assert flattener.slices['a'] == slice(6, 7)
  np.testing.assert_array_equal(flattener.spec.minimum[6:], [-np.inf, 0.0, 0.0])
  np.testing.assert_array_equal(flattener.spec.maximum[6:], [np.inf, 1.0, 2.0])
  observation = {
      'a': jnp.int32(7),
      'b': jnp.arange(6.0).reshape(2, 3),
      'c': jnp.array([0.5, 1.5]),
  }
  vector = flattener(observation)
  np.testing.assert_allclose(vector, [0, 1, 2, 3, 4, 5, 7, 0.5, 1.5])
  back = flattener.unflatten(vector)
  for key in spec_dict:
    np.testing.assert_allclose(back[key], observation[key])
  batched = jax.tree.map(lambda x: jnp.stack([x, x + 1]), observation)
  flat = jax.jit(flattener)(batched)
  assert flat.shape == (2, 9)
  np.testing.assert_allclose(flat[1], vector + 1)
  assert flatten.flatten_spec({'x': specs.Array((3,), np.float64)}).shape == (
      3,
  )
  with pytest.raises(ValueError, match="'b' has shape"):
    flattener({**observation, 'b': jnp.zeros(6)})
  with pytest.raises(KeyError, match='missing keys'):
    flattener({'a': 1})
