"""Tests for `mjx_composer.observation.updater` (ports composer's updater_test).

Timing is checked against composer itself: dm_control's
`composer.observation.updater.Updater`, driving dm_control observables on
dm_control's `FakePhysics` (whose time is the number of sub-steps taken) as
composer's environment drives them (`reset`, then per control step
`prepare_for_next_control_step` and one `update` after each sub-step), with
the same update intervals, delays and buffer sizes, and variable ones
replayed draw by draw.
"""

import collections
import contextlib
import itertools
import zlib
from unittest import mock

from dm_control.composer.observation import fake_physics as dm_fake_physics
from dm_control.composer.observation import obs_buffer as dm_obs_buffer
from dm_control.composer.observation import observable as dm_observable
from dm_control.composer.observation import updater as dm_updater
from dm_env import specs
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_composer.observation import fake_physics
from mjx_composer.observation import updater as updater_lib
from mjx_composer.observation.observable import base
from mjx_composer.variation import base as variation_base
from tests import jaxprs

N_SUB_STEPS = 5
NUM_CONTROL_STEPS = 200


# ---------------------------------------------------------------------------
# Helpers.
# ---------------------------------------------------------------------------


class _Sequence(variation_base.Variation):
  """Cycles through `values`; its position is carried as variation state."""

  def __init__(self, values):
    self._values = np.asarray(values)

  def initial_state(self, initial_value=None):
    del initial_value
    return jnp.zeros((), jnp.int32)

  def _sample(self, state, key, initial_value, current_value):
    value = jnp.asarray(self._values)[state]
    return value, (state + 1) % len(self._values)

  def static_bounds(self):
    return self._values.min(), self._values.max()


class _UniformInteger(variation_base.Variation):
  """Uniform integers in [low, high], inclusive."""

  def __init__(self, low, high):
    self._low, self._high = low, high

  def _sample(self, state, key, initial_value, current_value):
    self._require_key(key)
    return jax.random.randint(key, (), self._low, self._high + 1), state

  def static_bounds(self):
    return np.asarray(self._low), np.asarray(self._high)


class _Unbounded(variation_base.Variation):

  def _sample(self, state, key, initial_value, current_value):
    return jnp.asarray(3), state


class _BoundedGeneric(base.Generic):

  def __init__(self, fn, shape, **kwargs):
    super().__init__(fn, **kwargs)
    self._spec = specs.BoundedArray(
        shape, np.float32, minimum=-1.0, maximum=1.0
    )

  @property
  def array_spec(self):
    return self._spec


class _CustomSpec(specs.Array):
  """A spec subclass that must survive `observation_spec`."""


class _CustomSpecGeneric(base.Generic):

  @property
  def array_spec(self):
    return _CustomSpec((2,), np.float32)


def _enabled(**observables):
  out = collections.OrderedDict()
  for name, obs in observables.items():
    obs.enabled = True
    out[name] = obs
  return out


def _composer_run(configs, n, num_steps, pad_initial=False, plan=True):
  """Observations of composer's own updater, one per control step.

  Args:
    configs: name -> `(fn, update_interval, delay, buffer_size)`, where `fn`
      maps dm_control's `FakePhysics` to a value, and the interval and the
      delay are ints or zero-argument callables (composer calls those once
      per sample, in the order of the samples: the delay of sample 0 at
      reset, then the interval and the delay of each following sample).
    n: sub-steps per control step.
    num_steps: control steps after the reset.
    pad_initial: composer's `pad_with_initial_value`.
    plan: keep composer's planner, which drops planned samples that no read
      will see (`Buffer.drop_unobserved_upcoming_items`). Where it drops the
      last planned sample, composer plans that sub-step again with fresh
      draws of the interval and the delay: the same distribution for random
      draws, but a replayed sequence of draws then lands on other samples.
      False runs composer's schedule and buffers without that step, every
      draw used once, by the samples in the order they are taken.

  Returns:
    name -> array stacked over control steps, the reset's observation first.
  """
  physics = dm_fake_physics.FakePhysics()
  observables = collections.OrderedDict()
  for name, (fn, interval, delay, size) in configs.items():
    observables[name] = dm_observable.Generic(
        fn, update_interval=interval, delay=delay, buffer_size=size
    )
    observables[name].enabled = True
  updater = dm_updater.Updater(
      observables, n, pad_with_initial_value=pad_initial
  )
  with contextlib.ExitStack() as stack:
    if not plan:
      stack.enter_context(
          mock.patch.object(
              dm_obs_buffer.Buffer,
              'drop_unobserved_upcoming_items',
              lambda *_: None,
          )
      )
    updater.reset(physics, np.random.RandomState(0))
    outputs = [updater.get_observation()]
    for _ in range(num_steps):
      updater.prepare_for_next_control_step()
      for _ in range(n):
        physics.step()
        updater.update()
      outputs.append(updater.get_observation())
  return {
      name: np.stack([np.array(o[name]) for o in outputs])
      for name in observables
  }


def _composer_timestamps(configs, n, num_steps, plan=True):
  """Each buffered sample's timestamp in composer's updater, -1 for padding.

  The observables of `configs` (name -> `(interval, delay, buffer_size)`,
  as `_composer_run`'s) read `time + 1` under zero padding, so a buffered
  value minus one is its sample's timestamp, and padding reads -1.
  """
  time_plus_one = lambda physics: physics.time() + 1
  observations = _composer_run(
      {name: (time_plus_one,) + tuple(c) for name, c in configs.items()},
      n,
      num_steps,
      plan=plan,
  )
  return {name: value - 1 for name, value in observations.items()}


def _cycle(values):
  """A zero-argument callable cycling through `values`."""
  return itertools.cycle(values).__next__


def _replay(values, then):
  """A zero-argument callable returning `values` in turn, then `then`.

  composer plans samples up to two control steps ahead, so it draws past
  the last sample a run takes.
  """
  values = iter(values)
  return lambda: next(values, then)


def _timing_observables():
  observables = fake_physics.FakePhysics.observables()
  observables['repeated'].buffer_size = 5
  observables['matrix'].delay = 1
  observables['matrix'].buffer_size = 4
  observables['sqrt_plus_one'] = base.Generic(
      fake_physics.FakePhysics.sqrt_plus_one,
      update_interval=7,
      buffer_size=3,
      delay=2,
  )
  for obs in observables.values():
    obs.enabled = True
  return observables


def _run(updater, num_steps, key=jax.random.key(0), style='static'):
  """Runs `num_steps` control steps on a FakePhysics under one jit.

  Styles: 'static' calls update with Python-int sub-steps; 'scan' calls it
  inside a `lax.scan` over sub-steps 1..n-1 with a traced counter (like the
  environment), then with n.

  Returns:
    `(observations, buffer_timestamps)`, stacked over control steps, with
    the reset observation first.
  """
  n = updater.physics_steps_per_control_step

  def control_step(carry, step_key):
    physics, state = carry
    if style == 'static':
      for j in range(1, n + 1):
        physics = physics.step()
        state = updater.update(
            state, physics, jax.random.fold_in(step_key, j), j
        )
    else:

      def substep(carry, i):
        physics, state = carry
        physics = physics.step()
        state = jax.lax.cond(
            i < n - 1,
            lambda s: updater.update(
                s, physics, jax.random.fold_in(step_key, i + 1), i + 1
            ),
            lambda s: s,
            state,
        )
        return (physics, state), None

      (physics, state), _ = jax.lax.scan(
          substep, (physics, state), jnp.arange(n - 1, dtype=jnp.int32)
      )
      physics = physics.step()
      state = updater.update(state, physics, jax.random.fold_in(step_key, n), n)
    return (physics, state), (
        updater.get_observation(state),
        updater.buffer_timestamps(state),
    )

  def run(key):
    physics = fake_physics.FakePhysics.create()
    reset_key, key = jax.random.split(key)
    state = updater.reset(physics, reset_key)
    first = (updater.get_observation(state), updater.buffer_timestamps(state))
    _, rest = jax.lax.scan(
        control_step, (physics, state), jax.random.split(key, num_steps)
    )
    return jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), first, rest)

  cache_key = (id(updater), num_steps, style)
  if cache_key not in _COMPILED:
    _COMPILED[cache_key] = (updater, jax.jit(run))
  return jax.device_get(_COMPILED[cache_key][1](key))


# Jitted runs per (updater, steps, style); holding the updater keeps its id.
_COMPILED = {}


# ---------------------------------------------------------------------------
# Structure and specs.
# ---------------------------------------------------------------------------


def _nested_observables():
  physics_fn = lambda p: jnp.zeros((2,), jnp.float32)
  make = lambda **kw: base.Generic(physics_fn, **kw)
  bounded = lambda **kw: _BoundedGeneric(physics_fn, (2,), **kw)
  first = {'a': make(), 'b': make(aggregator='sum'), 'disabled': make()}
  second = collections.OrderedDict(
      [('c', bounded()), ('d', bounded(aggregator='sum'))]
  )
  for d in (first, second):
    for key, obs in d.items():
      obs.enabled = key != 'disabled'
  return first, second


@pytest.mark.parametrize('container', [list, tuple])
def test_nested_structures_keep_container_types(container):
  first, second = _nested_observables()
  updater = updater_lib.Updater(container([first, second]))
  physics = fake_physics.FakePhysics.create()
  spec = updater.observation_spec(physics)
  observation = updater.get_observation(updater.reset(physics))
  for structure in (spec, observation):
    assert type(structure) is container
    assert type(structure[0]) is dict
    assert type(structure[1]) is collections.OrderedDict
    assert list(structure[0]) == ['a', 'b']
    assert list(structure[1]) == ['c', 'd']
  assert spec[0]['a'].shape == (1, 2)
  assert spec[0]['b'].shape == (2,)
  assert type(spec[0]['a']) is specs.Array
  assert type(spec[1]['c']) is specs.BoundedArray
  assert spec[1]['c'].shape == (1, 2)
  assert type(spec[1]['d']) is specs.Array  # sum does not keep bounds
  jax.tree.map(
      lambda s, o: s.validate(np.asarray(o)),
      spec,
      observation,
      is_leaf=lambda x: isinstance(x, specs.Array),
  )


def test_observables_must_be_dicts():
  with pytest.raises(ValueError, match='must be a dict'):
    updater_lib.Updater(base.Generic(lambda p: 0))
  with pytest.raises(ValueError, match='must be a dict'):
    updater_lib.Updater([{'a': base.Generic(lambda p: 0)}, 3])


def test_spec_inference_by_tracing():
  observables = fake_physics.FakePhysics.observables()
  observables['repeated'].buffer_size = 5
  observables['matrix'].buffer_size = 4
  observables['sqrt'] = base.Generic(
      fake_physics.FakePhysics.sqrt, buffer_size=3
  )
  for obs in observables.values():
    obs.enabled = True
  updater = updater_lib.Updater(observables, N_SUB_STEPS)
  with pytest.raises(RuntimeError, match='not known yet'):
    updater.observation_spec()
  abstract = jax.eval_shape(fake_physics.FakePhysics.create)
  spec = updater.observation_spec(abstract)
  assert spec['repeated'].shape == (5, 2)
  assert spec['matrix'].shape == (4, 2, 3)
  assert spec['sqrt'].shape == (3,)
  assert np.issubdtype(spec['repeated'].dtype, np.integer)
  assert np.issubdtype(spec['matrix'].dtype, np.integer)
  assert np.issubdtype(spec['sqrt'].dtype, np.floating)
  for key, value in spec.items():
    assert value.name == key
  # A fresh updater learns the shapes from a traced reset, too.
  other = updater_lib.Updater(observables, N_SUB_STEPS)
  jax.eval_shape(other.reset, abstract)
  assert other.observation_spec() == spec


def test_custom_spec_type_passed_through():
  obs = _CustomSpecGeneric(lambda p: jnp.zeros(2), buffer_size=3)
  updater = updater_lib.Updater(_enabled(custom=obs))
  spec = updater.observation_spec()  # No physics needed: array_spec given.
  assert type(spec['custom']) is _CustomSpec
  assert spec['custom'].shape == (3, 2)
  assert spec['custom'].name == 'custom'


@pytest.mark.parametrize('aggregator', ['min', 'max', 'mean', 'median'])
def test_bounds_kept_by_bounds_preserving_aggregators(aggregator):
  # composer's `bounds_reserving` typo drops these bounds; we keep them.
  obs = _BoundedGeneric(
      lambda p: jnp.zeros(2), (2,), buffer_size=4, aggregator=aggregator
  )
  spec = updater_lib.Updater(_enabled(x=obs)).observation_spec()['x']
  assert type(spec) is specs.BoundedArray
  assert spec.shape == (2,)
  np.testing.assert_array_equal(spec.minimum, -1.0)
  np.testing.assert_array_equal(spec.maximum, 1.0)


def test_custom_aggregator_shape_and_unknown_bounds():
  obs = _BoundedGeneric(
      lambda p: jnp.zeros(2),
      (2,),
      buffer_size=4,
      aggregator=lambda x: x[-1:] - x[:1],
  )
  spec = updater_lib.Updater(_enabled(x=obs)).observation_spec()['x']
  assert type(spec) is specs.Array
  assert spec.shape == (1, 2)


def test_strip_singleton_buffer_dim():
  observables = _enabled(
      single=base.Generic(lambda p: jnp.ones((3, 3))),
      scalar=base.Generic(lambda p: jnp.float32(2.0)),
      several=base.Generic(lambda p: jnp.ones(2), buffer_size=2),
      mean=base.Generic(lambda p: jnp.arange(3.0), aggregator='mean'),
  )
  updater = updater_lib.Updater(observables, strip_singleton_buffer_dim=True)
  physics = fake_physics.FakePhysics.create()
  observation = updater.get_observation(updater.reset(physics))
  spec = updater.observation_spec()
  assert observation['single'].shape == spec['single'].shape == (3, 3)
  assert observation['scalar'].shape == spec['scalar'].shape == ()
  assert observation['several'].shape == spec['several'].shape == (2, 2)
  # Deviation from composer: the aggregator reduces the buffer axis, not the
  # observation's own first axis.
  assert observation['mean'].shape == spec['mean'].shape == (3,)
  np.testing.assert_array_equal(observation['mean'], [0.0, 1.0, 2.0])


# ---------------------------------------------------------------------------
# Timing.
# ---------------------------------------------------------------------------


@pytest.mark.parametrize('pad_initial', [False, True])
@pytest.mark.parametrize('style', ['static', 'scan'])
def test_observation_timing_matches_composer(pad_initial, style):
  """composer's testObservation: dm_control's FakePhysics observables
  (`twice`, `repeated`, `matrix`, `sqrt_plus_one`) with the same intervals,
  delays and buffers, in composer's updater and ours."""
  observables = _timing_observables()
  updater = updater_lib.Updater(
      observables, N_SUB_STEPS, pad_with_initial_value=pad_initial
  )
  observations, timestamps = _run(updater, NUM_CONTROL_STEPS, style=style)
  schedules = {
      key: (obs.update_interval, obs.delay or 0, obs.buffer_size or 1)
      for key, obs in observables.items()
  }
  expected = _composer_run(
      {
          key: (getattr(dm_fake_physics.FakePhysics, key),) + schedule
          for key, schedule in schedules.items()
      },
      N_SUB_STEPS,
      NUM_CONTROL_STEPS,
      pad_initial=pad_initial,
  )
  expected_timestamps = _composer_timestamps(
      schedules, N_SUB_STEPS, NUM_CONTROL_STEPS
  )
  for key, (u, d, b) in schedules.items():
    for step in range(NUM_CONTROL_STEPS + 1):
      t = step * N_SUB_STEPS
      # composer's closed form: newest visible u*floor((t-d)/u), B oldest
      # first, negative timestamps are padding.
      end = u * ((t - d) // u)
      formula = end + u * np.arange(-(b - 1), 1)
      np.testing.assert_array_equal(
          expected_timestamps[key][step], np.where(formula < 0, -1, formula)
      )
    np.testing.assert_array_equal(
        timestamps[key], expected_timestamps[key], err_msg=key
    )
    # float32 (ours) against float64 sqrt: rtol of a few float32 ulps.
    np.testing.assert_allclose(
        observations[key], expected[key], rtol=1e-6, err_msg=key
    )


@pytest.mark.parametrize('n', [1, 3, 4, 6])
def test_constant_schedules_match_composer(n):
  configs = {
      f'u{u}_d{d}_b{b}': (u, d, b)
      for u in (1, 2, 3, 7)
      for d in (0, 1, 5)
      for b in (1, 3)
  }
  observables = collections.OrderedDict(
      (
          key,
          base.Generic(
              lambda p: p.time(), update_interval=u, delay=d, buffer_size=b
          ),
      )
      for key, (u, d, b) in configs.items()
  )
  for obs in observables.values():
    obs.enabled = True
  updater = updater_lib.Updater(observables, n)
  num_steps = 30
  _, timestamps = _run(updater, num_steps)
  expected = _composer_timestamps(configs, n, num_steps)
  for key in configs:
    np.testing.assert_array_equal(timestamps[key], expected[key], err_msg=key)


def _library_sequence(values):
  from mjx_composer.variation import deterministic  # pylint: disable=g-import-not-at-top

  return deterministic.Sequence(values)


@pytest.mark.parametrize(
    'sequence', [_Sequence, _library_sequence], ids=['local', 'library']
)
def test_variable_rates_and_delays(sequence):
  # composer's testVariableRatesAndDelays: sample #11 is pushed out by #8's
  # later arrival, so buffers follow arrival order.
  obs = base.Generic(
      lambda p: p.time(),
      buffer_size=3,
      update_interval=sequence([3, 2, 3, 3, 4, 1, 4]),
      delay=sequence([3, 5, 2, 5, 1, 2, 4]),
  )
  updater = updater_lib.Updater(_enabled(time=obs), 10)
  assert updater.capacity('time') == 3 + 5  # B + ceil(max delay / min int)
  observations, timestamps = _run(updater, 10)
  expected = _composer_timestamps(
      {
          'time': (
              _cycle([3, 2, 3, 3, 4, 1, 4]),
              _cycle([3, 5, 2, 5, 1, 2, 4]),
              3,
          )
      },
      10,
      10,
  )
  np.testing.assert_array_equal(timestamps['time'], expected['time'])
  # composer's test's own expectations.
  for i in range(5):
    np.testing.assert_array_equal(
        observations['time'][2 * i + 1], 20 * i + np.array([0, 5, 3])
    )
    np.testing.assert_array_equal(
        observations['time'][2 * i + 2], 20 * i + np.array([8, 15, 16])
    )


def _variable_run(updater, key, n, num_steps):
  """Runs the updater; returns, per observable, its sample times, each
  sample's delay and the buffers' timestamps after each control step."""
  entry_keys = updater.keys

  def control_step(carry, step_key):
    physics, state = carry
    inserted = []
    for j in range(1, n + 1):
      physics = physics.step()
      state = updater.update(state, physics, jax.random.fold_in(step_key, j), j)
      # The sample taken now (if any) is the slot stamped with t.
      row = {}
      for index, buffer in enumerate(state.buffers):
        hit = buffer.timestamps == state.t
        row[entry_keys[index]] = (
            jnp.any(hit),
            jnp.sum(jnp.where(hit, buffer.arrivals, 0)),
        )
      inserted.append(row)
    return (physics, state), (updater.buffer_timestamps(state), inserted)

  @jax.jit
  def run(key):
    physics = fake_physics.FakePhysics.create()
    state = updater.reset(physics, key)
    first = {k: b.arrivals[0] for k, b in zip(entry_keys, state.buffers)}
    _, rest = jax.lax.scan(
        control_step, (physics, state), jax.random.split(key, num_steps)
    )
    return first, rest

  first, (timestamps, inserted) = jax.device_get(run(key))
  results = {}
  for name in entry_keys:
    draws = {0: int(first[name])}
    for step in range(num_steps):
      for j in range(n):
        taken, arrival = inserted[j][name]
        if taken[step]:
          s = step * n + j + 1
          draws[s] = int(arrival[step]) - s
    results[name] = (sorted(draws), draws, timestamps[name])
  return results


def test_variable_rates_random_against_composer():
  n, num_steps = 3, 80
  configs = {
      'interval': (_UniformInteger(1, 4), 0, 3),
      'delay': (2, _UniformInteger(0, 6), 2),
      'both': (_UniformInteger(1, 2), _UniformInteger(0, 9), 1),
  }
  observables = collections.OrderedDict()
  for name, (u, d, b) in configs.items():
    observables[name] = base.Generic(
        lambda p: p.time(), update_interval=u, delay=d, buffer_size=b
    )
    observables[name].enabled = True
  updater = updater_lib.Updater(observables, n)
  results = _variable_run(updater, jax.random.key(3), n, num_steps)
  for name, (u, d, b) in configs.items():
    times, draws, timestamps = results[name]
    intervals = np.diff(times)
    low_u, high_u = (u, u) if isinstance(u, int) else (1, u._high)
    low_d, high_d = (d, d) if isinstance(d, int) else (0, d._high)
    assert intervals.min() >= low_u and intervals.max() <= high_u
    assert min(draws.values()) >= low_d and max(draws.values()) <= high_d
    # The random draws really vary.
    assert isinstance(u, int) or len(set(intervals)) > 1
    assert isinstance(d, int) or len(set(draws.values())) > 1
    # composer's updater, its intervals and delays replayed from ours (the
    # interval after the run's last sample reaches past the run's end), each
    # draw given to the sample ours gave it (`plan=False`).
    expected = _composer_timestamps(
        {
            name: (
                _replay(intervals, then=n * num_steps),
                _replay([draws[s] for s in times], then=0),
                b,
            )
        },
        n,
        num_steps,
        plan=False,
    )
    np.testing.assert_array_equal(timestamps, expected[name][1:], err_msg=name)


def test_a_sequence_of_delays_is_drawn_once_per_sample_in_order():
  """Each sample takes the next draw, as composer's updater gives them
  without its planner; composer's planner drops sample 3 here (sample 1,
  arriving later, hides it) and, it being the last one planned, plans
  sub-step 4 again with the next draw: sample 4 then has delay 3, not 1,
  and the read at 6 sees sample 5, not 3 (`docs/porting.md`)."""
  delays = [1, 3]
  obs = base.Generic(
      lambda p: p.time(), update_interval=1, delay=_Sequence(delays)
  )
  updater = updater_lib.Updater(_enabled(x=obs), 2)
  _, timestamps = _run(updater, 4)
  config = {'x': (1, _cycle(delays), 1)}
  unplanned = _composer_timestamps(config, 2, 4, plan=False)['x']
  np.testing.assert_array_equal(timestamps['x'], unplanned)
  np.testing.assert_array_equal(unplanned[:, 0], [-1, 0, 1, 3, 5])
  config = {'x': (1, _cycle(delays), 1)}
  planned = _composer_timestamps(config, 2, 4)['x']
  np.testing.assert_array_equal(planned[:, 0], [-1, 0, 1, 5, 7])


def test_adversarial_delays_respect_capacity():
  # A long delay followed by short ones: the old sample is still the newest
  # arrival while many newer samples are in flight. A ring indexed by sample
  # number would need 2*ceil(D/u) + B slots; arrival slots need B + D/u.
  delays = [4, 0, 0, 0, 4, 4, 4, 4, 1, 3, 0, 2]
  obs = base.Generic(
      lambda p: p.time(),
      buffer_size=1,
      update_interval=1,
      delay=_Sequence(delays),
  )
  updater = updater_lib.Updater(_enabled(x=obs), 1)
  assert updater.capacity('x') == 5
  _, timestamps = _run(updater, 40)
  expected = _composer_timestamps({'x': (1, _cycle(delays), 1)}, 1, 40)
  np.testing.assert_array_equal(timestamps['x'], expected['x'])


def test_variation_without_bounds_is_rejected():
  obs = base.Generic(lambda p: p.time(), delay=_Unbounded())
  with pytest.raises(ValueError, match="'noisy'.*static bounds"):
    updater_lib.Updater(_enabled(noisy=obs))


def test_invalid_options_are_rejected():
  with pytest.raises(ValueError, match="'x': delay must be an integer >= 0"):
    updater_lib.Updater(_enabled(x=base.Generic(lambda p: 0, delay=-1)))
  with pytest.raises(ValueError, match="'x': buffer_size must be"):
    updater_lib.Updater(
        _enabled(x=base.Generic(lambda p: 0, buffer_size=_Sequence([1, 2])))
    )
  updater = updater_lib.Updater(_enabled(x=base.Generic(lambda p: 0)), 2)
  state = updater.reset(fake_physics.FakePhysics.create())
  with pytest.raises(ValueError, match='substep must be in 1..2'):
    updater.update(state, fake_physics.FakePhysics.create(), None, 3)


# ---------------------------------------------------------------------------
# Aggregators and corruptors.
# ---------------------------------------------------------------------------


def test_aggregators_reduce_the_buffer_axis():
  fn = lambda p: jnp.stack([p.time(), -p.time()]).astype(jnp.float32)
  observables = _enabled(
      **{
          name: base.Generic(fn, buffer_size=N_SUB_STEPS, aggregator=name)
          for name in base.AGGREGATORS
      }
  )
  observables['custom'] = base.Generic(
      fn, buffer_size=N_SUB_STEPS, aggregator=lambda x: x[-1] - x[0]
  )
  observables['custom'].enabled = True
  updater = updater_lib.Updater(observables, N_SUB_STEPS)
  observations, _ = _run(updater, 3)
  window = np.arange(6, 11, dtype=np.float32)  # t = 10: samples 6..10
  buffered = np.stack([window, -window], axis=1)
  expected = {
      'min': buffered.min(0),
      'max': buffered.max(0),
      'mean': buffered.mean(0),
      'median': np.median(buffered, 0),
      'sum': buffered.sum(0),
      'custom': buffered[-1] - buffered[0],
  }
  for name, value in expected.items():
    np.testing.assert_allclose(observations[name][2], value, err_msg=name)


def _noisy_observables():
  return _enabled(
      noisy=base.Generic(
          lambda p: jnp.zeros(3),
          buffer_size=2,
          corruptor=lambda v, key: v + jax.random.normal(key, v.shape),
      ),
      clean=base.Generic(lambda p: p.time()),
  )


def test_corruptor_applied_per_sample_before_buffering():
  observables = _enabled(
      x=base.Generic(
          lambda p: p.time().astype(jnp.float32),
          buffer_size=3,
          aggregator='sum',
          corruptor=lambda v, key: v + 12.0,
      )
  )
  updater = updater_lib.Updater(observables, 1)
  observations, _ = _run(updater, 4)
  # Three samples, each shifted by 12, summed (zero padding uncorrupted).
  np.testing.assert_allclose(observations['x'][4], (2 + 3 + 4) + 3 * 12.0)
  np.testing.assert_allclose(observations['x'][0], 0 + 12.0)


def test_corruption_noise_per_world_step_and_key():
  updater = updater_lib.Updater(_noisy_observables(), 1)
  num_steps = 5
  single = _run(updater, num_steps, key=jax.random.key(7))[0]['noisy']
  again = _run(updater, num_steps, key=jax.random.key(7))[0]['noisy']
  np.testing.assert_array_equal(single, again)  # Reproducible from the key.
  # Noise differs across steps and across the two buffered samples.
  assert len(np.unique(single[1:, -1, 0])) == num_steps
  assert not np.allclose(single[3, 0], single[3, 1])
  # The sample seen newest at step k is seen oldest at step k + 1.
  np.testing.assert_array_equal(single[3, 1], single[4, 0])

  keys = jax.random.split(jax.random.key(11), 3)
  keys = keys.at[1].set(jax.random.key(7))

  def run_world(key):
    physics = fake_physics.FakePhysics.create()
    reset_key, key = jax.random.split(key)
    state = updater.reset(physics, reset_key)
    outputs = [updater.get_observation(state)['noisy']]
    for step_key in jax.random.split(key, num_steps):
      physics = physics.step()
      state = updater.update(state, physics, jax.random.fold_in(step_key, 1), 1)
      outputs.append(updater.get_observation(state)['noisy'])
    return jnp.stack(outputs)

  batched = jax.device_get(jax.jit(jax.vmap(run_world))(keys))
  np.testing.assert_array_equal(batched[1], single)  # Same key, same world.
  assert not np.allclose(batched[0], batched[2])  # Worlds differ.


def test_noise_independent_of_other_observables():
  observables = _noisy_observables()
  reference = _run(updater_lib.Updater(observables, 2), 3)[0]['noisy']
  observables['extra'] = base.Generic(
      lambda p: jnp.ones(2), corruptor=lambda v, key: v * 2
  )
  observables['extra'].enabled = True
  observables.move_to_end('extra', last=False)
  del observables['clean']
  with_extra = _run(updater_lib.Updater(observables, 2), 3)[0]['noisy']
  np.testing.assert_array_equal(reference, with_extra)


def test_corruptor_keys_are_the_documented_folds_from_one_hash():
  # The sample at timestamp t of observable `name` is corrupted with
  # fold_in(fold_in(key, t), stable_id(f'{name}#0')) (0: the corruptor's
  # purpose), the keys of every observable from one PRNG call.
  names = ('a', 'b', 'c')
  observables = _enabled(
      **{
          name: base.Generic(
              lambda p: jnp.zeros(2),
              corruptor=lambda v, key: v + jax.random.uniform(key, v.shape),
          )
          for name in names
      }
  )
  updater = updater_lib.Updater(observables, 1)
  physics = fake_physics.FakePhysics.create()
  key = jax.random.key(4)
  observation = updater.get_observation(updater.reset(physics, key))
  for name in names:
    uid = zlib.crc32(f'{name}#0'.encode()) & 0x7FFFFFFF
    expected = jax.random.uniform(
        jax.random.fold_in(jax.random.fold_in(key, 0), uid), (2,)
    )
    # One buffered sample (buffer_size 1).
    np.testing.assert_array_equal(observation[name], [expected], err_msg=name)
  jaxpr = jax.make_jaxpr(lambda k: updater.reset(physics, k))(key)
  # One fold for the timestamp, one for the three observables.
  assert jaxprs.count(jaxpr.jaxpr, 'random_fold_in') == 2


def test_same_observations_in_a_batch_as_in_one_world():
  observables = _timing_observables()
  observables['delayed'] = base.Generic(
      lambda p: p.time(),
      buffer_size=2,
      delay=_Sequence([1, 4, 2]),
      update_interval=_Sequence([2, 1, 3]),
  )
  observables['delayed'].enabled = True
  updater = updater_lib.Updater(
      observables, N_SUB_STEPS, pad_with_initial_value=True
  )
  num_steps = 3
  single = _run(updater, num_steps, key=jax.random.key(5))[0]

  batched = jax.jit(jax.vmap(lambda k: _run_traced(updater, num_steps, k)))(
      jnp.stack([jax.random.key(5)] * 3)
  )
  for key in observables:
    for world in range(3):
      np.testing.assert_allclose(batched[key][world], single[key], err_msg=key)


def _run_traced(updater, num_steps, key):
  """Like `_run` (static style) but traceable, for use under vmap."""
  n = updater.physics_steps_per_control_step

  def control_step(carry, step_key):
    physics, state = carry
    for j in range(1, n + 1):
      physics = physics.step()
      state = updater.update(state, physics, jax.random.fold_in(step_key, j), j)
    return (physics, state), updater.get_observation(state)

  physics = fake_physics.FakePhysics.create()
  reset_key, key = jax.random.split(key)
  state = updater.reset(physics, reset_key)
  first = updater.get_observation(state)
  _, rest = jax.lax.scan(
      control_step, (physics, state), jax.random.split(key, num_steps)
  )
  return jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), first, rest)


# ---------------------------------------------------------------------------
# Cost: what update evaluates.
# ---------------------------------------------------------------------------


class _Counting:
  """An observable function that counts how often it is traced."""

  def __init__(self):
    self.calls = 0

  def __call__(self, physics):
    self.calls += 1
    return physics.time()


def test_update_evaluates_only_samples_that_can_be_seen():
  n = 10
  fns = collections.OrderedDict(
      every=_Counting(),
      slow=_Counting(),
      averaged=_Counting(),
      delayed=_Counting(),
      odd=_Counting(),
      disabled=_Counting(),
  )
  observables = collections.OrderedDict(
      every=base.Generic(fns['every']),
      slow=base.Generic(fns['slow'], update_interval=5),
      averaged=base.Generic(fns['averaged'], buffer_size=3),
      delayed=base.Generic(fns['delayed'], delay=3, update_interval=2),
      odd=base.Generic(fns['odd'], update_interval=3),
      disabled=base.Generic(fns['disabled']),
  )
  for key, obs in observables.items():
    obs.enabled = key != 'disabled'
  updater = updater_lib.Updater(observables, n)
  assert updater.active_substeps('every') == (10,)
  assert updater.active_substeps('slow') == (10,)  # 5 is never seen.
  assert updater.active_substeps('averaged') == (8, 9, 10)
  # Reads at 10k see the sample taken at 10k - 4 only.
  assert updater.active_substeps('delayed') == (6,)
  # 3 does not divide 10: reads see 9, 18, 30, ... (masked per world).
  assert updater.active_substeps('odd') == (8, 9, 10)
  assert updater.capacity('every') == 1

  physics = fake_physics.FakePhysics.create()
  state = updater.reset(physics)
  for fn in fns.values():
    fn.calls = 0
  for j in (1, 2, 3, 4, 5, 7):
    jax.make_jaxpr(lambda s: updater.update(s, physics, None, j))(state)
  assert all(fn.calls == 0 for fn in fns.values())
  jax.make_jaxpr(lambda s: updater.update(s, physics, None, 6))(state)
  assert {k for k, fn in fns.items() if fn.calls} == {'delayed'}

  # With a traced sub-step known to be in 1..n-1 (inside the environment's
  # scan), observables only read at sub-step n are not even traced.
  for fn in fns.values():
    fn.calls = 0
  only_last = updater_lib.Updater(
      collections.OrderedDict(every=observables['every']), n
  )
  jaxpr = jax.make_jaxpr(
      lambda s, j: only_last.update(
          s, physics, None, j, substep_bounds=(1, n - 1)
      )
  )(only_last.reset(physics), jnp.int32(1))
  assert fns['every'].calls == 1  # Only by the reset above.
  assert 'cond' not in str(jaxpr)
  # Without the hint, the last sub-step's branch exists but is the only one
  # evaluating the observable.
  jaxpr = jax.make_jaxpr(lambda s, j: only_last.update(s, physics, None, j))(
      only_last.reset(physics), jnp.int32(1)
  )
  assert 'cond' in str(jaxpr)


def test_traced_substep_stays_a_branch_under_vmap():
  observables = _enabled(x=base.Generic(lambda p: p.time()))
  updater = updater_lib.Updater(observables, 4)
  physics = fake_physics.FakePhysics.create()
  states = jax.vmap(lambda _: updater.reset(physics))(jnp.arange(3))

  def update_all(states, j):
    return jax.vmap(lambda s: updater.update(s, physics, None, j))(states)

  jaxpr = str(jax.make_jaxpr(update_all)(states, jnp.int32(2)))
  # A batched predicate would have turned the cond into a select.
  assert 'cond' in jaxpr
