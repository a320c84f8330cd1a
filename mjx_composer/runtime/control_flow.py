"""Control flow that stays cheap under `jax.vmap`: loops run once or never.

A step program that holds a reset (auto-reset) must not compute it for every
world at every step, and should not branch with `lax.cond`: on a GPU a
conditional costs a host round trip, and its output needs buffers of its
own, so the branch not taken copies its operand into them. These
combinators keep the work conditional without conditionals:

* `once_or_never`: `fn(x)` if a predicate shared by the batch holds, as a
  `while_loop` that runs once or never (a loop that does not run leaves its
  carry in place);
* `run_unless`: `fn(x)` unless a predicate shared by the batch holds, for
  work that runs almost always: a `lax.cond`, whose predicate is read once
  where a loop that runs reads its condition twice;
* `run_if`: what `once_or_never` computes, as a `lax.cond`: for a program
  compiled for a CPU, where a conditional costs no host round trip and
  XLA compiles it faster than a loop (`branch_once` picks one of the two);
* `batch_any`: a flag that is shared by the batch under `vmap` (whether any
  world's is set), so that loops on it stay loops;
* `select_reset`: a per-world select between a step's result and a reset,
  whose batching rule computes the resets only when some world needs one;
* `loop_with_reset`: the sub-step loop of a fused auto-reset, with more
  iterations (the reset's) only when some world wants them;
* `trace_once`: a function traced once and reused where it is needed twice;
* `tree_select`: a leaf-by-leaf select that keeps MuJoCo Warp's buffers
  shared by the batch.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mjx_composer.platform import shared_buffers


def trace_once(fn, *args, return_shapes=False):
  """`fn` traced once on `args`' shapes; returns a function that reuses it.

  Calling the result emits the traced program again (or batches it, under
  `vmap`) without running `fn`'s Python: what lets a reset that is needed in
  two places (both branches of a batching rule, a first attempt and its
  retries) be traced once. The result is `jax.jit(fn)`, traced here: a call
  with the same shapes binds the cached trace as one nested call (XLA
  inlines it), instead of re-evaluating its equations one by one, which
  cost as much as tracing `fn` again. With `return_shapes`, also returns the
  output's shapes (a pytree of `jax.ShapeDtypeStruct`).
  """
  traced = jax.jit(fn)
  out_shape = jax.eval_shape(traced, *args)
  if return_shapes:
    return traced, out_shape
  return traced


def tree_select(pred, on_true, on_false):
  """`on_true` where `pred`, else `on_false`, leaf by leaf (one world).

  `mjx.Data` is merged by `Data.where` (`shared_buffers.select`): MuJoCo Warp's
  buffers shared by the batch are kept, not selected.
  """
  return shared_buffers.select(pred, on_true, on_false)


def _batch_all(axis_size, args, in_batched):
  """A batching rule's arguments, the unbatched ones broadcast to the batch.

  Except MuJoCo Warp's `Data` buffers shared by the batch
  (`shared_buffers.shared_leaves`), which stay unbatched.
  """
  return jax.tree.map(
      lambda x, b, shared: (
          x if b or shared else jnp.broadcast_to(x, (axis_size,) + jnp.shape(x))
      ),
      args,
      tuple(in_batched),
      shared_buffers.shared_leaves(args),
  )


def _out_batched(out):
  """A batching rule's output flags: all batched but Warp's shared buffers."""
  return jax.tree.map(
      lambda shared: not shared, shared_buffers.shared_leaves(out)
  )


# `select_reset(chunk=AUTO_CHUNK)`: a batch of at least `AUTO_CHUNK_MIN_BATCH`
# worlds resets its done worlds an `AUTO_CHUNK_FRACTION`th of the batch at a
# time; a smaller one, whole. A chunk's reset is what the step program's
# peak memory holds beyond the step's own (its forward pass's buffers, a
# randomized model's derivations): an eighth of the batch's, where most
# steps end few episodes, and a step in which every episode ends (a time
# limit reached together) runs eight chunks. Below about a thousand worlds
# the whole batch's reset is small beside the rest of the process.
AUTO_CHUNK = 'auto'
AUTO_CHUNK_FRACTION = 8
AUTO_CHUNK_MIN_BATCH = 1024


def chunk_size(chunk, batch: int) -> int | None:
  """The worlds `select_reset(chunk=chunk)` resets together in a batch of
  `batch` worlds: `chunk` (an integer, or `AUTO_CHUNK`) as resolved, None
  for the whole batch (`chunk` None, or no smaller than the batch)."""
  if chunk == AUTO_CHUNK:
    if batch < AUTO_CHUNK_MIN_BATCH:
      return None
    chunk = -(-batch // AUTO_CHUNK_FRACTION)
  if chunk is None or chunk >= batch:
    return None
  return int(chunk)


def select_reset(
    done, reset_fn, operands, stepped, chunk=None, conditional=False
):
  """`reset_fn(*operands)` where `done`, else `stepped`.

  For one world this is a select. Under `jax.vmap` a select would compute the
  reset of every world at every step; the batching rule instead computes
  resets only when some world is done. With `chunk=None` (or a chunk no
  smaller than the batch) it computes the whole batch's resets (a loop of
  at most one iteration, run when `any(done)`), then selects per world.
  With a smaller `chunk` (an integer, or `AUTO_CHUNK`: `chunk_size`), it
  gathers the done worlds into batches of `chunk` worlds, resets those and
  scatters them back (`_reset_in_chunks`): a step in which a few of many
  worlds end pays for a reset of `chunk` worlds, not of all, and the
  program holds one chunk's reset. Results are the same either way, to
  float rounding (XLA may order a sum differently for another batch size).
  The reset is traced once and reused by every path. `conditional`: the
  whole batch's reset runs in a `run_if`, not a `once_or_never`
  (`branch_once`).
  """
  reset = trace_once(reset_fn, *operands)
  # A restart resets the stepped state itself: then the loop below reads it
  # from its carry, not as a second copy of the same buffers.
  restarts_stepped = len(operands) == 1 and operands[0] is stepped
  if restarts_stepped:
    operands = ()

  def select(done, operands, stepped):
    operands = (stepped,) if restarts_stepped else operands
    return tree_select(done, reset(*operands), stepped)

  select_or_skip = jax.custom_batching.custom_vmap(select)

  @select_or_skip.def_vmap
  def _batched(axis_size, in_batched, done, operands, stepped):
    done, operands, stepped = _batch_all(
        axis_size, (done, operands, stepped), in_batched
    )
    size = chunk_size(chunk, axis_size)
    if size is not None:
      out = _reset_in_chunks(
          done, reset, None if restarts_stepped else operands, stepped, size
      )
    else:
      out = _reset_at_most_once(
          done, select, operands, stepped, branch_once(conditional)
      )
    return out, _out_batched(out)

  return select_or_skip(done, operands, stepped)


def _reset_at_most_once(done, select, operands, stepped, run_once):
  """`vmap(select)(done, operands, stepped)` where any world is done.

  Else `stepped`. `run_once`: `once_or_never` (a GPU: with a conditional,
  the branch without resets copies the whole state at every step) or
  `run_if` (a CPU).
  """
  with jax.named_scope('auto_reset'):
    return run_once(
        jnp.any(done),
        lambda state: jax.vmap(select)(done, operands, state),
        stepped,
    )


def _reset_in_chunks(done, reset, operands, stepped, chunk):
  """`select(done, vmap(reset)(*operands), stepped)`, `chunk` worlds at a time.

  The done worlds come first in a stable order of the batch; each loop
  iteration gathers the next `chunk` of them, resets them and scatters the
  results into the state it carries, leaf by leaf, in place: the program
  holds the batch's state once, plus one chunk's reset (gathering every
  leaf into rows of one array per dtype would be fewer kernels, but
  copies the whole state at every step, loop or not). Slots past the last
  done world are computed and dropped. The loop runs
  `ceil(done worlds / chunk)` times, none when no world is done.

  Args:
    done: `(batch,)` flags.
    reset: the reset of one world.
    operands: its batched arguments; None where the reset restarts the
      stepped state itself (then each chunk reads its rows from the carried
      state: rows not yet reset are the stepped ones).
    stepped: the batched state the resets replace.
    chunk: worlds reset together.
  """
  n = done.shape[0]
  flags = done.astype(jnp.int32)
  count = jnp.sum(flags)
  # The batch's order with the done worlds first, each part in batch order:
  # a stable argsort, computed by counting instead (XLA's GSPMD partitioner,
  # which compiles `shard_map` programs for several GPUs, fails on a sort
  # inside one).
  rank = jnp.where(done, jnp.cumsum(flags), count + jnp.cumsum(1 - flags)) - 1
  order = jnp.zeros(n, jnp.int32).at[rank].set(jnp.arange(n, dtype=jnp.int32))

  def body(loop):
    start, state = loop
    # The last chunk slides back to stay inside the batch; the worlds it
    # covers again were reset already and are dropped.
    first = jnp.minimum(start, n - chunk)
    index = jax.lax.dynamic_slice(order, (first,), (chunk,))
    position = first + jnp.arange(chunk)
    keep = (position >= start) & (position < count)
    rows = jax.tree.map(
        lambda x: x[index], (state,) if operands is None else operands
    )
    # Materialized before the scatters below: without the barrier, XLA's
    # GPU compilation of the walk task's step program left 11% more
    # instructions (docs/performance.md), whose compile time follows them.
    fresh = jax.lax.optimization_barrier(jax.vmap(reset)(*rows))
    # A dropped slot scatters to row `n`, out of bounds: dropped. The
    # chunk's indices are distinct (a slice of a permutation).
    target = jnp.where(keep, index, n)
    # `select` (traced first, by `custom_vmap`) has checked that the reset
    # returns what the step does, leaf for leaf: the same layout.
    state = jax.tree.map(
        lambda x, new: x.at[target].set(new, mode='drop'), state, fresh
    )
    return start + chunk, state

  _, state = jax.lax.while_loop(
      lambda loop: loop[0] < count,
      body,
      (jnp.zeros((), jnp.int32), stepped),
  )
  return state


def loop_with_reset(
    n,
    body,
    end,
    prepare,
    finish,
    carry,
    fixed,
    operands,
    extra=1,
    conditional=False,
    close=None,
):
  """`n` iterations of `body`, then `end`; where a reset is wanted, then
  `prepare`, `extra` iterations of `body` and `finish`; `close` after the
  iterations of each.

  The sub-step loop of a fused auto-reset, whose last iterations reset the
  episode, so that the reset's forward pass is the sub-steps' (one copy in
  the program). Two nested loops: an outer one over two phases (the
  sub-steps; then, where some world wants it, the reset's iterations), and
  inside it the loop over `i`, which holds `body` once. `fixed` is what
  `body` reads and never changes (the world's model fields that no step
  hook writes): within the inner loop it is invariant, so XLA computes
  what the body derives from it alone (the model's gathers) once a phase,
  not at every iteration. The phases' ends (`end`, `prepare`, `finish`)
  run between the inner loops, in loops run once or never: the inner loop
  is the sub-steps and nothing else. `close` is what both phases' ends
  compute first, of the carry their iterations leave: it runs after the
  inner loop of each phase, one copy in the program for both.

  For one world the reset's phase runs on whether it wants the reset.
  Under `jax.vmap` a batched loop condition would turn every branch on `i`
  in the body into a select, computing the reset at every sub-step: the
  batching rule instead keeps `i` and the phase shared by the batch, runs
  the callbacks batched inside the loops, and runs the reset's phase when
  some world wants it. Results are the same either way. Each callback is
  traced once and reused by both paths.

  Args:
    n: the iterations every world runs.
    body: `(i, carry, fixed, operands) -> carry`, one iteration for one
      world; at `i >= n` it runs for every world of the batch.
    end: `(carry, fixed, operands) -> (carry, wants)` after the first `n`
      iterations: the end of the step, and whether the world wants the
      reset.
    prepare: `(carry, fixed, operands) -> (carry, fixed)`, what the reset's
      iterations start from (computed for every world of the batch where
      some world wants the reset).
    finish: `(carry, fixed, operands) -> carry` after the reset's
      iterations, for every world of the batch: where a world wants no
      reset, what it keeps of `end`'s result is the loop's result (the
      rest of the carry is then the batch's, not the world's).
    carry: the initial carry.
    fixed: the initial invariants.
    operands: per-world inputs the callbacks read.
    extra: the iterations of the reset.
    conditional: the phases' ends run in `run_if`s, not `once_or_never`s
      (`branch_once`: for a program compiled for a CPU).
    close: `(carry, fixed, operands) -> carry` after each phase's
      iterations, before `end` (the first phase) or `finish` (the reset's),
      for every world of the batch; None for none.

  Returns:
    The final carry.
  """
  index = jnp.zeros((), jnp.int32)
  close = close or _carry_as_is
  single = (
      trace_once(body, index, carry, fixed, operands),
      trace_once(close, carry, fixed, operands),
      trace_once(end, carry, fixed, operands),
      trace_once(prepare, carry, fixed, operands),
      trace_once(finish, carry, fixed, operands),
  )
  run_once = branch_once(conditional)

  def run(carry, fixed, operands, callbacks, any_of):
    iterate, closing, ending, preparing, finishing = callbacks

    def phase(loop):
      p, wanted, carry, fixed = loop
      last = jnp.where(p == 0, n, n + extra)

      def iteration(inner):
        i, carry = inner
        return i + 1, iterate(i, carry, fixed, operands)

      _, carry = jax.lax.while_loop(
          lambda inner: inner[0] < last, iteration, (p * n, carry)
      )
      carry = closing(carry, fixed, operands)

      def end_of_steps(loop):
        carry, _ = loop
        carry, wants = ending(carry, fixed, operands)
        return carry, any_of(wants)

      carry, wanted = run_once(p == 0, end_of_steps, (carry, wanted))
      # The restart's preparation in a loop of its own, after the step's
      # end rather than nested in it: XLA copies the carry at the
      # boundaries of each loop run once or never, and the nested loop's
      # copies were the largest share of the step's (walk's fused step on a
      # GPU, docs/performance.md).
      carry, fixed = run_once(
          jnp.logical_and(p == 0, wanted),
          lambda loop: preparing(*loop, operands),
          (carry, fixed),
      )
      carry = run_once(
          p == 1, lambda carry: finishing(carry, fixed, operands), carry
      )
      return p + 1, jnp.logical_and(p == 0, wanted), carry, fixed

    return jax.lax.while_loop(
        lambda loop: jnp.logical_or(loop[0] == 0, loop[1]),
        phase,
        (index, jnp.zeros((), bool), carry, fixed),
    )[2]

  def one_world(carry, fixed, operands):
    return run(carry, fixed, operands, single, lambda wants: wants)

  looped = jax.custom_batching.custom_vmap(one_world)

  @looped.def_vmap
  def _batched(axis_size, in_batched, carry, fixed, operands):
    carry, fixed, operands = _batch_all(
        axis_size, (carry, fixed, operands), in_batched
    )
    iterate, *rest = single
    out = run(
        carry,
        fixed,
        operands,
        (jax.vmap(iterate, in_axes=(None, 0, 0, 0)), *map(jax.vmap, rest)),
        jnp.any,
    )
    return out, _out_batched(out)

  return looped(carry, fixed, operands)


def _carry_as_is(carry, fixed, operands):
  """`loop_with_reset`'s `close` where none is given."""
  del fixed, operands
  return carry


@jax.custom_batching.custom_vmap
def batch_any(flag):
  """`flag` for one world; under `jax.vmap`, whether any world's is set.

  The result is shared by the batch (not batched), so a `lax.while_loop`
  whose condition reads it keeps one trip count for every world, and the
  `lax.cond`s and loops in its body that branch on the loop's own counter
  stay branches and loops: a batched condition would turn them into
  selects that compute every branch for every world.
  """
  return flag


@batch_any.def_vmap
def _batch_any_rule(axis_size, in_batched, flag):
  del axis_size
  (batched,) = in_batched
  return (jnp.any(flag) if batched else flag), False


def once_or_never(pred, fn, operand):
  """`fn(operand)` if `pred`, else `operand`: a loop run once or never.

  For a `pred` shared by the batch (a loop counter, `batch_any`): the loop
  then stays a loop under `jax.vmap`; a per-world `pred` is refused where
  the loop is batched. Not a `lax.cond`: a conditional's output needs
  buffers of its own, so on a GPU the branch not taken copies its operand
  into them, where a loop that does not run leaves its carry in place.
  Under `jax.vmap` the loop's carry is batched whole (`_per_world`), so
  that JAX's batching rule batches `fn`'s program once, not once to find
  which parts of the carry are batched and once more for the result.
  """
  pred, operand = _per_world(pred, operand)

  def body(loop):
    flag, operand = loop
    return jnp.zeros_like(flag), fn(operand)

  return jax.lax.while_loop(
      lambda loop: batch_any(loop[0]), body, (pred, operand)
  )[1]


def run_if(pred, fn, operand):
  """`fn(operand)` if `pred`, else `operand`: a `lax.cond`.

  What `once_or_never` computes, for a `pred` shared by the batch (a loop
  counter, `batch_any`; a per-world one is refused where the conditional
  is batched). For a CPU: there a conditional reads its predicate without
  a host round trip, and XLA compiles it faster than a loop run once or
  never (the walk task's step program is traced, lowered and compiled in
  0.86 of the time: docs/performance.md).
  """
  return jax.lax.cond(_shared(pred, 'run_if'), fn, lambda x: x, operand)


def branch_once(conditional: bool):
  """`run_if` where `conditional` (a program for a CPU), else
  `once_or_never` (for a GPU): `(pred, fn, operand) -> fn(operand) or
  operand`, for a `pred` shared by the batch."""
  return run_if if conditional else once_or_never


def run_unless(skip, fn, operand):
  """`operand` if `skip`, else `fn(operand)`: a `lax.cond`.

  For a `skip` shared by the batch (a loop counter) that seldom holds. Each
  `once_or_never` that runs reads its condition twice (a host round trip
  each on a GPU); this reads it once. Its output does not reuse its
  operand's buffers, so the branch that skips copies `operand` into the
  output: keep in `operand` what `fn` writes, and read the rest outside.
  A per-world `skip` is refused where the conditional is batched (it would
  turn into a select that runs `fn` for every world).
  """
  return jax.lax.cond(_shared(skip, 'run_unless'), lambda x: x, fn, operand)


def _shared(pred, combinator):
  """`pred`; refused under `jax.vmap` where it is batched (in
  `combinator`, named by the error)."""

  @jax.custom_batching.custom_vmap
  def shared(pred):
    return pred

  @shared.def_vmap
  def _rule(axis_size, in_batched, pred):
    del axis_size
    if in_batched[0]:
      _refuse_per_world(combinator, 'a loop counter, or batch_any')
    return pred, False

  return shared(pred)


def _refuse_per_world(combinator, shared):
  """Raises: `combinator` was given a per-world condition under `vmap`."""
  raise ValueError(
      f'{combinator} needs a condition shared by the batch ({shared}), not '
      'a per-world one.'
  )


@jax.custom_batching.custom_vmap
def _per_world(pred, operand):
  """`(pred, operand)` for one world; under `jax.vmap`, every leaf batched.

  The shared `pred` and the leaves of `operand` that are not batched are
  broadcast to the batch (MuJoCo Warp's buffers shared by the batch stay
  as they are).
  """
  return pred, operand


@_per_world.def_vmap
def _per_world_rule(axis_size, in_batched, pred, operand):
  pred_batched, operand_batched = in_batched
  if pred_batched:
    _refuse_per_world(
        'once_or_never',
        'a loop counter, or control_flow.batch_any of a per-world flag',
    )
  pred, operand = _batch_all(
      axis_size, (pred, operand), (pred_batched, operand_batched)
  )
  return (pred, operand), (True, _out_batched(operand))
