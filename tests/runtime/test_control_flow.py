"""Control flow: tracing a reset once, the reset select, and the
shared-condition loops of the fused restart (`batch_any`, `once_or_never`)
and its conditional (`run_unless`).
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_composer.runtime import control_flow
from tests import jaxprs


def test_trace_once_runs_the_python_once():
  calls = []

  def reset(x):
    calls.append(1)
    return {'y': jnp.sin(x) * 2.0, 'n': jnp.zeros((), jnp.int32)}

  traced = control_flow.trace_once(reset, jnp.ones(3))
  x = jnp.arange(3.0)
  np.testing.assert_array_equal(traced(x)['y'], reset(x)['y'])
  batched = jax.vmap(traced)(jnp.stack([x, x + 1]))
  assert batched['y'].shape == (2, 3) and batched['n'].shape == (2,)
  # Two uses plus the direct reference call: fn's Python ran twice in all.
  assert len(calls) == 2


def _select_reset_fn(counter):
  def reset(key):
    counter.append(1)
    return jax.random.uniform(key, (2,))

  def step(done, key, stepped):
    return control_flow.select_reset(done, reset, (key,), stepped)

  return step


def test_select_reset_batched_equals_the_per_world_select():
  counter = []
  step = _select_reset_fn(counter)
  keys = jax.random.split(jax.random.key(0), 4)
  stepped = jnp.full((4, 2), -1.0)
  for done in ([False, True, False, True], [False] * 4, [True] * 4):
    done = jnp.asarray(done)
    batched = jax.jit(jax.vmap(step))(done, keys, stepped)
    for i in range(4):
      single = step(done[i], keys[i], stepped[i])
      np.testing.assert_array_equal(batched[i], single)


def test_select_reset_traces_the_reset_once_under_vmap():
  counter = []
  step = _select_reset_fn(counter)
  keys = jax.random.split(jax.random.key(0), 4)
  jax.jit(jax.vmap(step)).lower(jnp.zeros(4, bool), keys, jnp.zeros((4, 2)))
  assert len(counter) == 1


def test_select_reset_computes_the_batch_reset_only_when_a_world_is_done():
  """Batched, the reset runs in a loop of at most one iteration, not a cond.

  A `lax.cond` would make a GPU copy the state into the conditional's
  output at every step without resets; a loop that does not run does not.
  """
  runs = []

  def reset(key):
    jax.debug.callback(lambda: runs.append(1))
    return jax.random.uniform(key, (2,))

  def step(done, key, stepped):
    return control_flow.select_reset(done, reset, (key,), stepped)

  keys = jax.random.split(jax.random.key(0), 4)
  stepped = jnp.full((4, 2), -1.0)
  batched = jax.jit(jax.vmap(step))
  jaxpr = str(jax.make_jaxpr(jax.vmap(step))(jnp.zeros(4, bool), keys, stepped))
  assert 'while' in jaxpr and 'cond[' not in jaxpr
  out = jax.block_until_ready(batched(jnp.zeros(4, bool), keys, stepped))
  jax.effects_barrier()
  assert not runs
  np.testing.assert_array_equal(out, stepped)
  done = jnp.asarray([False, True, False, False])
  out = jax.block_until_ready(batched(done, keys, stepped))
  jax.effects_barrier()
  assert runs
  np.testing.assert_array_equal(out[0], stepped[0])
  np.testing.assert_array_equal(out[1], reset(keys[1]))


def test_select_reset_of_the_stepped_state_equals_the_per_world_select():
  """A restart (the reset's operand is the stepped state) reads its carry."""

  def restart(state):
    return {'x': state['x'] * 2.0 + 1.0, 'n': state['n'] + 1}

  def step(done, stepped):
    return control_flow.select_reset(done, restart, (stepped,), stepped)

  stepped = {'x': jnp.arange(8.0).reshape(4, 2), 'n': jnp.arange(4)}
  batched = jax.jit(jax.vmap(step))
  for done in ([False, True, False, True], [False] * 4, [True] * 4):
    done = jnp.asarray(done)
    got = batched(done, stepped)
    for i in range(4):
      single = step(done[i], jax.tree.map(lambda x: x[i], stepped))
      np.testing.assert_array_equal(got['x'][i], single['x'])
      np.testing.assert_array_equal(got['n'][i], single['n'])


def _mixed_reset(key):
  """A reset whose output has every kind of leaf a `State` has."""
  a, b = jax.random.split(key)
  return {
      'x': jax.random.uniform(a, (3, 2)),
      'n': jax.random.randint(b, (), 0, 100),
      'flag': jax.random.bernoulli(b),
      'key': jax.random.fold_in(key, 1),
      'empty': jnp.zeros((0, 4)),
  }


@pytest.mark.parametrize('chunk', [1, 3, 5, 7, 8, None])
def test_select_reset_in_chunks_equals_the_per_world_select(chunk):
  """Done worlds gathered `chunk` at a time: the same as selecting each.

  Seven worlds: chunks of 3 slide the last one back over worlds already
  reset (masked); 7 and more take the whole-batch path.
  """
  n = 7
  keys = jax.random.split(jax.random.key(0), n)
  stepped = jax.vmap(_mixed_reset)(jax.random.split(jax.random.key(1), n))

  def step(done, key, stepped):
    return control_flow.select_reset(done, _mixed_reset, (key,), stepped, chunk)

  batched_step = jax.jit(jax.vmap(step))
  patterns = [
      [False] * n,
      [True] * n,
      [False, True, False, False, True, True, False],
      [True, False, False, False, False, False, True],
      [False] * (n - 1) + [True],
  ]
  for done in patterns:
    done = jnp.asarray(done)
    batched = batched_step(done, keys, stepped)
    for i in range(n):
      single = step(done[i], keys[i], jax.tree.map(lambda x: x[i], stepped))
      got = jax.tree.map(lambda x: x[i], batched)
      for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(single)):
        if jnp.issubdtype(a.dtype, jax.dtypes.prng_key):
          a, b = jax.random.key_data(a), jax.random.key_data(b)
        np.testing.assert_array_equal(a, b)


def test_auto_chunks_are_an_eighth_of_a_large_batch():
  assert control_flow.chunk_size('auto', 1023) is None
  assert control_flow.chunk_size('auto', 1024) == 128
  assert control_flow.chunk_size('auto', 8193) == 1025
  assert control_flow.chunk_size(5, 7) == 5
  assert control_flow.chunk_size(7, 7) is None
  assert control_flow.chunk_size(None, 4096) is None


@pytest.mark.parametrize('n, gathers', [(1024, True), (1023, False)])
def test_auto_chunk_gathers_the_done_worlds_of_a_large_batch(n, gathers):
  """'auto' scatters chunks of a batch of 1,024 worlds into the state and
  selects the whole batch's resets below it, with the same results."""
  keys = jax.random.split(jax.random.key(0), n)
  stepped = jax.vmap(_mixed_reset)(jax.random.split(jax.random.key(1), n))
  done = jnp.arange(n) % 3 == 1

  def step(chunk, done, key, stepped):
    return control_flow.select_reset(done, _mixed_reset, (key,), stepped, chunk)

  auto = jax.vmap(functools.partial(step, 'auto'))
  jaxpr = str(jax.make_jaxpr(auto)(done, keys, stepped))
  assert ('scatter' in jaxpr) == gathers
  whole = jax.jit(jax.vmap(functools.partial(step, None)))(done, keys, stepped)
  for a, b in zip(
      jax.tree.leaves(jax.jit(auto)(done, keys, stepped)),
      jax.tree.leaves(whole),
  ):
    if jnp.issubdtype(a.dtype, jax.dtypes.prng_key):
      a, b = jax.random.key_data(a), jax.random.key_data(b)
    np.testing.assert_array_equal(a, b)


def test_chunks_scatter_the_reset_once_it_is_materialized():
  """Each leaf's scatter takes the chunk's reset from an optimization
  barrier, which keeps walk's step program compiled for a GPU a tenth
  smaller (docs/performance.md)."""
  n = 6
  keys = jax.random.split(jax.random.key(0), n)
  stepped = jax.vmap(_mixed_reset)(keys)

  def step(done, key, stepped):
    return control_flow.select_reset(done, _mixed_reset, (key,), stepped, 2)

  jaxpr = jax.make_jaxpr(jax.vmap(step))(jnp.zeros(n, bool), keys, stepped)
  (loop,) = [
      eqn
      for eqn in jaxprs.equations(jaxpr.jaxpr)
      if eqn.primitive.name == 'while'
      and jaxprs.count(eqn.params['body_jaxpr'].jaxpr, 'scatter')
  ]
  body = loop.params['body_jaxpr'].jaxpr
  barriers = [
      e for e in body.eqns if e.primitive.name == 'optimization_barrier'
  ]
  assert len(barriers) == 1
  materialized = {id(v) for v in barriers[0].outvars}
  scatters = [e for e in body.eqns if e.primitive.name == 'scatter']
  # One per leaf of the state (none for an empty one), each of a barrier's
  # output.
  assert len(scatters) == sum(x.size > 0 for x in jax.tree.leaves(stepped))
  assert all(id(e.invars[2]) in materialized for e in scatters)


def test_select_reset_in_chunks_traces_the_reset_once():
  counter = []

  def reset(key):
    counter.append(1)
    return _mixed_reset(key)

  def step(done, key, stepped):
    return control_flow.select_reset(done, reset, (key,), stepped, chunk=2)

  keys = jax.random.split(jax.random.key(0), 6)
  stepped = jax.vmap(_mixed_reset)(keys)
  jax.jit(jax.vmap(step)).lower(jnp.zeros(6, bool), keys, stepped)
  assert len(counter) == 1


def test_batch_any_is_the_flag_for_one_world_and_any_under_vmap():
  assert bool(control_flow.batch_any(jnp.asarray(True)))
  assert not bool(control_flow.batch_any(jnp.asarray(False)))
  flags = jnp.array([False, True, False])
  out = jax.vmap(control_flow.batch_any)(flags)
  # One value for the batch, broadcast back by vmap.
  np.testing.assert_array_equal(out, [True, True, True])
  np.testing.assert_array_equal(
      jax.vmap(control_flow.batch_any)(jnp.zeros(3, bool)), [False] * 3
  )
  # Nested vmaps: any over both axes.
  nested = jax.vmap(jax.vmap(control_flow.batch_any))(flags.reshape(1, 3))
  np.testing.assert_array_equal(nested, [[True, True, True]])


# `once_or_never` and `run_if` compute the same; each keeps its own branch
# under `vmap`: a loop, or a conditional.
_RUN_ONCE = pytest.mark.parametrize(
    'run_once, kept, dropped',
    [
        (control_flow.once_or_never, 'stablehlo.while', 'stablehlo.case'),
        (control_flow.run_if, 'stablehlo.case', 'stablehlo.while'),
    ],
    ids=['once_or_never', 'run_if'],
)


@_RUN_ONCE
def test_runs_fn_once_where_pred_else_returns_operand(run_once, kept, dropped):
  del kept, dropped
  calls = []

  def double(x):
    calls.append(1)
    return x * 2.0

  x = jnp.arange(3.0)
  np.testing.assert_array_equal(run_once(jnp.asarray(True), double, x), x * 2)
  np.testing.assert_array_equal(run_once(jnp.asarray(False), double, x), x)
  # Traced once per call and run at most once; a conditional on a concrete
  # False traces nothing.
  assert len(calls) == (2 if run_once is control_flow.once_or_never else 1)


@_RUN_ONCE
def test_a_shared_condition_keeps_its_branch_under_vmap(
    run_once, kept, dropped
):
  def world(flag, x):
    return run_once(control_flow.batch_any(flag), lambda v: v + 1.0, x)

  flags = jnp.array([False, True])
  x = jnp.zeros((2, 3))
  # Every world runs it when any wants it: the condition is the batch's.
  np.testing.assert_array_equal(jax.vmap(world)(flags, x), np.ones((2, 3)))
  np.testing.assert_array_equal(
      jax.vmap(world)(jnp.zeros(2, bool), x), np.zeros((2, 3))
  )
  hlo = jax.jit(jax.vmap(world)).lower(flags, x).as_text()
  assert kept in hlo and 'stablehlo.select' not in hlo
  assert dropped not in hlo


@_RUN_ONCE
def test_a_per_world_condition_is_refused_under_vmap(run_once, kept, dropped):
  del kept, dropped

  def world(flag, x):
    return run_once(flag, lambda v: v + 1.0, x)

  name = run_once.__name__
  with pytest.raises(ValueError, match=f'{name} needs a condition shared'):
    jax.vmap(world)(jnp.array([False, True]), jnp.zeros((2, 3)))


def test_branch_once_picks_a_conditional_or_a_loop():
  assert control_flow.branch_once(True) is control_flow.run_if
  assert control_flow.branch_once(False) is control_flow.once_or_never


def test_run_unless_runs_fn_unless_skip():
  x = jnp.arange(3.0)
  double = lambda v: v * 2.0
  np.testing.assert_array_equal(
      control_flow.run_unless(jnp.asarray(False), double, x), x * 2
  )
  np.testing.assert_array_equal(
      control_flow.run_unless(jnp.asarray(True), double, x), x
  )


def test_run_unless_on_a_shared_counter_stays_a_conditional_under_vmap():
  def world(i, x):
    return control_flow.run_unless(i == 1, lambda v: v + 1.0, x)

  x = jnp.zeros((2, 3))
  step = jax.vmap(world, in_axes=(None, 0))
  np.testing.assert_array_equal(step(0, x), np.ones((2, 3)))
  np.testing.assert_array_equal(step(1, x), np.zeros((2, 3)))
  hlo = jax.jit(step).lower(0, x).as_text()
  assert 'stablehlo.case' in hlo and 'stablehlo.select' not in hlo
  # A loop run once or never reads its condition twice when it runs.
  assert 'stablehlo.while' not in hlo


def test_run_unless_refuses_a_per_world_condition_under_vmap():
  def world(flag, x):
    return control_flow.run_unless(flag, lambda v: v + 1.0, x)

  with pytest.raises(ValueError, match='shared by the batch'):
    jax.vmap(world)(jnp.array([False, True]), jnp.zeros((2, 3)))


def test_once_or_never_batches_its_function_once_under_vmap():
  # A marker in `fn` whose batching rule counts how often `fn`'s program
  # is batched. JAX's loop batching batches a body twice where part of
  # its carry is not batched (the shared condition, a constant operand).
  batched = []

  @jax.custom_batching.custom_vmap
  def marker(v):
    return v

  @marker.def_vmap
  def _(axis_size, in_batched, v):
    del axis_size
    batched.append(1)
    return v, in_batched[0]

  def world(flag, x):
    constant = jnp.ones(3)  # not batched
    y, c = control_flow.once_or_never(
        control_flow.batch_any(flag),
        lambda operand: (marker(operand[0]) * operand[1], operand[1]),
        (x, constant),
    )
    return y + c

  out = jax.vmap(world)(jnp.array([False, True]), jnp.full((2, 3), 2.0))
  np.testing.assert_array_equal(out, np.full((2, 3), 3.0))
  assert len(batched) == 1


# `loop_with_reset` over a carry `(running, result)`: the body adds
# `(i + 1) * sum(fixed)` to `running`; the step's end writes `10 * running`
# to `result` and wants the reset where the operand is positive; the reset
# restarts `running` at 1000 with `fixed` doubled, and its end writes
# `running` to `result` where the world reset. With `close`, each phase's
# iterations end by adding `max(fixed) / 2` to `running`.
_N, _EXTRA = 3, 2


def _looped(operand, fixed, close=None):
  def body(i, carry, fixed, operand):
    del operand
    running, result = carry
    return running + (i + 1) * jnp.sum(fixed), result

  def end(carry, fixed, operand):
    del fixed
    running, _ = carry
    return (running, 10.0 * running), operand > 0

  def prepare(carry, fixed, operand):
    del operand
    return (jnp.float32(1000.0), carry[1]), 2.0 * fixed

  def finish(carry, fixed, operand):
    del fixed
    running, result = carry
    return running, jnp.where(operand > 0, running, result)

  return control_flow.loop_with_reset(
      _N,
      body,
      end,
      prepare,
      finish,
      (jnp.float32(0.0), jnp.float32(0.0)),
      fixed,
      operand,
      extra=_EXTRA,
      close=close,
  )


def _close(carry, fixed, operand):
  del operand
  running, result = carry
  return running + jnp.max(fixed) / 2, result


def _looped_reference(operand, fixed, closes=False):
  """`result` of `_looped` for one world, in Python."""
  total, top = float(np.sum(fixed)), float(np.max(fixed)) if closes else 0.0
  running = sum((i + 1) * total for i in range(_N)) + top / 2
  if operand <= 0:
    return 10.0 * running
  return (
      1000.0
      + sum((i + 1) * 2.0 * total for i in range(_N, _N + _EXTRA))
      + 2.0 * top / 2
  )


def _fixed(worlds):
  # A shape no other value of the loop has.
  return (
      jnp.arange(worlds * 7 * 11, dtype=jnp.float32).reshape(worlds, 7, 11)
      / 100.0
  )


@pytest.mark.parametrize('operands', [(1.0, -1.0, 2.0), (-1.0, -2.0, 0.0)])
def test_loop_with_reset_runs_the_reset_phase_where_a_world_wants_it(
    operands,
):
  operands = jnp.asarray(operands, jnp.float32)
  fixed = _fixed(len(operands))
  want = [_looped_reference(o, f) for o, f in zip(operands, fixed)]
  for world in range(len(operands)):  # one world
    _, result = jax.jit(_looped)(operands[world], fixed[world])
    np.testing.assert_allclose(result, want[world], rtol=1e-6)
  running, result = jax.jit(jax.vmap(_looped))(operands, fixed)
  np.testing.assert_allclose(result, want, rtol=1e-6)
  # The batch runs the reset's phase for every world where some world
  # wants it, and for none where no world does.
  if bool(jnp.any(operands > 0)):
    assert np.all(np.asarray(running) >= 1000.0)
  else:
    np.testing.assert_allclose(running, np.asarray(want) / 10.0, rtol=1e-6)


@pytest.mark.parametrize('operands', [(1.0, -1.0, 2.0), (-1.0, -2.0, 0.0)])
def test_loop_with_reset_closes_each_phase_with_one_copy(operands):
  # `close` ends each phase that runs, before the step's end and the reset's
  # end, with that phase's `fixed`; the program holds it once.
  operands = jnp.asarray(operands, jnp.float32)
  fixed = _fixed(len(operands))
  want = [_looped_reference(o, f, closes=True) for o, f in zip(operands, fixed)]
  _, result = jax.jit(lambda o, f: _looped(o, f, _close))(operands[0], fixed[0])
  np.testing.assert_allclose(result, want[0], rtol=1e-6)
  traced = []

  def close(*args):
    traced.append(1)
    return _close(*args)

  batched = jax.jit(jax.vmap(lambda o, f: _looped(o, f, close)))
  _, result = batched(operands, fixed)
  np.testing.assert_allclose(result, want, rtol=1e-6)
  assert len(traced) == 1


def test_loop_with_reset_keeps_fixed_out_of_the_inner_loop_carry():
  # Within a phase, `fixed` is a constant of the loop over `i`, not part of
  # what it carries (as it would be where the loop changed it, preparing
  # the reset at its last sub-step): XLA can compute what the body derives
  # from it once.
  operands = jnp.asarray([1.0, -1.0], jnp.float32)
  fixed = _fixed(2)
  jaxpr = jax.make_jaxpr(jax.vmap(_looped))(operands, fixed).jaxpr

  def sums_fixed(eqn):  # the body's `jnp.sum(fixed)`, batched
    return eqn.primitive.name == 'reduce_sum' and any(
        v.aval.shape == fixed.shape for v in eqn.invars
    )

  def loop_summing_fixed(eqn):
    return eqn.primitive.name == 'while' and any(
        map(sums_fixed, jaxprs.equations(eqn.params['body_jaxpr'].jaxpr))
    )

  # The innermost loop that computes the body.
  loops = [
      eqn
      for eqn in jaxprs.equations(jaxpr)
      if loop_summing_fixed(eqn)
      and not any(
          map(
              loop_summing_fixed,
              jaxprs.equations(eqn.params['body_jaxpr'].jaxpr),
          )
      )
  ]
  assert len(loops) == 1  # the body, once, in the loop over `i`
  (loop,) = loops
  consts = loop.params['cond_nconsts'] + loop.params['body_nconsts']
  assert fixed.shape in [v.aval.shape for v in loop.invars[:consts]]
  assert fixed.shape not in [v.aval.shape for v in loop.invars[consts:]]
