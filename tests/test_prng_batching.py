"""prng_batching: independent draws hashed together, bit for bit the same."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_composer import prng_batching


def _draws(key, scale):
  """Draws of every kind jax.random offers, at two levels of keys."""
  k1, k2, k3 = jax.random.split(key, 3)
  with jax.named_scope('scaled'):
    uniform = jax.random.uniform(k1, (3,)) * scale
  return {
      'uniform': uniform,
      'normal': jax.random.normal(jax.random.fold_in(k2, 7), (2, 2)),
      'randint': jax.random.randint(k3, (4,), 0, 10),
      'bits8': jax.random.bits(jax.random.fold_in(k3, 2), (5,), jnp.uint8),
      'bits16': jax.random.bits(k1, (3,), jnp.uint16),
      'choice': jax.random.choice(k2, 5, (3,)),
      'split': jax.random.key_data(jax.random.split(k1, (2, 3))),
      'folded': jax.random.key_data(
          jax.vmap(jax.random.fold_in, (None, 0))(k2, jnp.arange(4))
      ),
      'bernoulli': jax.random.bernoulli(k1, 0.3, (7,)),
      'scalar': jax.random.uniform(k2),
      'scale': scale,
  }


def _hashes(jaxpr):
  """Threefry applications in a jaxpr: random primitives and the hash."""
  names = ('random_bits', 'random_split', 'random_fold_in', 'threefry2x32')
  jaxpr = getattr(jaxpr, 'jaxpr', jaxpr)  # a closed jaxpr's
  count = 0
  for eqn in jaxpr.eqns:
    count += eqn.primitive.name in names
    for sub in jax.extend.core.jaxprs_in_params(eqn.params):
      count += _hashes(sub)
  return count


def _assert_same(a, b):
  jax.tree.map(np.testing.assert_array_equal, a, b)


@pytest.mark.parametrize('legacy', [False, True])
def test_values_are_bit_for_bit_those_of_the_function(legacy):
  seeds = jnp.arange(4)
  make = jax.random.PRNGKey if legacy else jax.random.key
  keys = jax.vmap(make)(seeds)
  plain = jax.jit(jax.vmap(_draws, (0, None)))(keys, 2.0)
  batched = jax.jit(jax.vmap(prng_batching.batched(_draws), (0, None)))(
      keys, 2.0
  )
  _assert_same(plain, batched)
  # One world, no vmap.
  _assert_same(
      jax.jit(_draws)(keys[1], 3.0),
      jax.jit(prng_batching.batched(_draws))(keys[1], 3.0),
  )


def test_64_bit_draws_are_the_same():
  with jax.enable_x64(True):
    key = jax.random.key(5)
    draw = lambda k: (
        jax.random.bits(k, (3,), jnp.uint64),
        jax.random.uniform(jax.random.fold_in(k, 1), (2,), jnp.float64),
    )
    _assert_same(jax.jit(draw)(key), jax.jit(prng_batching.batched(draw))(key))


def test_independent_draws_share_one_hash_per_level():
  key = jax.random.key(0)
  plain = jax.make_jaxpr(_draws)(key, 1.0)
  batched = jax.make_jaxpr(prng_batching.batched(_draws))(key, 1.0)
  # The split, then every draw from its keys and fold-ins, then the draws
  # from the folded keys and randint's own split: levels, not calls.
  assert _hashes(plain) >= 14
  assert _hashes(batched) <= 4


def test_switched_off_it_traces_the_function_as_it_is():
  key = jax.random.key(0)
  with prng_batching.enabled(False):
    off = jax.make_jaxpr(prng_batching.batched(_draws))(key, 1.0)
  assert str(off) == str(jax.make_jaxpr(_draws)(key, 1.0))


def test_environment_variable_switches_it_off(monkeypatch):
  monkeypatch.setenv(prng_batching.SWITCH_ENV, '0')
  assert not prng_batching.is_enabled()
  with prng_batching.enabled(True):
    assert prng_batching.is_enabled()
  monkeypatch.setenv(prng_batching.SWITCH_ENV, '1')
  assert prng_batching.is_enabled()


def test_untraced_values_pass_through_unchanged():
  static = np.arange(3.0)
  seen = {}

  def fn(key, table):
    return {'table': table, 'draw': jax.random.uniform(key) + table.sum()}

  def outer(key):
    out = prng_batching.batched(fn)(key, static)
    seen['same'] = out['table'] is static
    return out['draw']

  jax.jit(outer)(jax.random.key(1))
  assert seen['same']
  # Outside a trace the function simply runs.
  out = prng_batching.batched(fn)(jax.random.key(1), static)
  assert out['table'] is static


def test_named_scopes_survive():
  lowered = jax.jit(prng_batching.batched(_draws)).lower(jax.random.key(0), 1.0)
  assert 'scaled' in lowered.as_text(debug_info=True)


def test_draws_in_control_flow_and_effects_keep_their_values():
  def fn(key, flag):
    a = jax.random.uniform(key, (2,))
    b = jax.lax.cond(
        flag,
        lambda k: jax.random.normal(k, (2,)),
        lambda k: jax.random.uniform(k, (2,)),
        jax.random.fold_in(key, 1),
    )
    return a, b

  def printing(key):
    jax.debug.print('draw {}', jax.random.uniform(key))
    return jax.random.uniform(jax.random.fold_in(key, 3))

  key = jax.random.key(2)
  for flag in (True, False):
    _assert_same(
        jax.jit(fn)(key, flag), jax.jit(prng_batching.batched(fn))(key, flag)
    )
  _assert_same(
      jax.jit(printing)(key), jax.jit(prng_batching.batched(printing))(key)
  )


def test_other_prng_implementations_are_left_alone():
  key = jax.random.key(0, impl='rbg')
  plain = jax.make_jaxpr(_draws)(key, 1.0)
  batched = jax.make_jaxpr(prng_batching.batched(_draws))(key, 1.0)
  assert 'threefry2x32' not in str(batched)
  assert _hashes(batched) == _hashes(plain)
  _assert_same(
      jax.jit(_draws)(key, 1.0),
      jax.jit(prng_batching.batched(_draws))(key, 1.0),
  )


def test_draws_inside_loop_bodies_are_batched_there():
  def fn(key):
    def body(i, carry):
      k = jax.random.fold_in(key, i)
      return (
          carry
          + jax.random.uniform(k, (2,))
          + jax.random.normal(jax.random.fold_in(k, 1), (2,))
      )

    return jax.lax.fori_loop(0, 3, body, jnp.zeros(2))

  key = jax.random.key(4)
  _assert_same(jax.jit(fn)(key), jax.jit(prng_batching.batched(fn))(key))
  plain = jax.make_jaxpr(fn)(key)
  batched = jax.make_jaxpr(prng_batching.batched(fn))(key)
  assert _hashes(plain) == 4  # 2 fold-ins, 2 draws
  assert _hashes(batched) == 3  # the fold-in, the second with a draw, a draw


def test_unchanged_containers_keep_their_identity():
  seen = {}

  def fn(state, key):
    return {**state, 'draw': jax.random.uniform(key)}

  def outer(x, key):
    state = {'a': {'x': x, 'table': np.ones(2)}, 'b': (x, x + 1)}
    out = prng_batching.batched(fn)(state, key)
    seen['a'] = out['a'] is state['a']
    seen['b'] = out['b'] is state['b']
    return out['draw']

  jax.jit(outer)(1.0, jax.random.key(0))
  assert seen == {'a': True, 'b': True}
