"""Threefry hashes of independent draws, computed together.

A reset draws dozens of random values: every variator binding, initializer,
task draw and observation noise asks `jax.random` with a key of its own, and
each call (`random_bits`, `split`, `fold_in`) is one application of the
threefry hash. XLA compiles each application on its own: on a CPU it is a
loop of about a hundred instructions, on a GPU a kernel launch or (without
JAX's kernel lowering) as many elementwise instructions. The draws do not
depend on each other, so the hash can run once on all of their counters.

`batched(fn)` returns `fn` with that rewrite: it traces `fn` to a jaxpr,
then evaluates the jaxpr with its equations in data-flow order, holding back
every threefry-based random primitive until nothing else can run, and then
computing all held-back ones with one `threefry2x32` call. Calls of jitted
functions that draw (`jax.random.uniform` is one) are inlined so their draws
join the batch. Draws inside control flow (the branches of `cond`, the
bodies of `while_loop` and `scan`) stay inside it: each body is rewritten on
its own, its draws batched with each other, never with the code around it.

The values are bit for bit those of `fn`: each held-back primitive gets the
counters JAX's partitionable threefry gives it (`jax_threefry_partitionable`,
the default), and the hash is elementwise. Anything else (other PRNG
implementations, the non-partitionable layout, effects such as
`jax.debug.print`) is evaluated in program order, unchanged.

Switch it off with `MJX_COMPOSER_BATCH_PRNG=0` (read when a function is
traced) or `enabled(False)`.
"""

from __future__ import annotations

import contextlib
import functools
import heapq
import math
import os

import jax
from jax import lax
import jax.extend as jex
import jax.numpy as jnp
import numpy as np

# The name stack and traceback of each equation, restored on evaluation as
# `jax.core.eval_jaxpr` does, so named scopes survive the rewrite.
from jax._src import source_info_util  # pylint: disable=g-bad-import-order

SWITCH_ENV = 'MJX_COMPOSER_BATCH_PRNG'
_OFF_VALUES = ('0', 'false', 'no', 'off')
_RANDOM_PRIMITIVES = ('random_bits', 'random_split', 'random_fold_in')
_CALL_PRIMITIVES = ('jit', 'pjit', 'closed_call', 'core_call')
_override: list[bool] = []


def is_enabled() -> bool:
  """Whether `batched` rewrites (the switch, then the environment)."""
  if _override:
    return _override[-1]
  value = os.environ.get(SWITCH_ENV, '').strip().lower()
  return value not in _OFF_VALUES


@contextlib.contextmanager
def enabled(on: bool):
  """Turns the rewrite on or off for functions traced inside the block."""
  _override.append(bool(on))
  try:
    yield
  finally:
    _override.pop()


def batched(fn):
  """`fn`, with the threefry hashes of its independent draws batched.

  `fn` may take and return any pytrees. What it returns without computing
  (its arguments, numpy arrays, Python objects) comes back as the same
  object, and so does every container whose contents did not change, so
  identity checks on the result (`new.model.field is old.model.field`)
  still hold. Called outside a trace (nothing to compile), `fn` runs
  unchanged.
  """

  @functools.wraps(fn)
  def run(*args, **kwargs):
    leaves, tree = jax.tree.flatten((args, kwargs))
    traced_at = [
        i for i, x in enumerate(leaves) if isinstance(x, jax.core.Tracer)
    ]
    if not is_enabled() or not traced_at:
      return fn(*args, **kwargs)
    captured = {}

    def traced(*inner):
      # The traced leaves come in as arguments, not closed over: a closed-
      # over tracer costs JAX a constant lookup at every use.
      full = list(leaves)
      for i, x in zip(traced_at, inner):
        full[i] = x
      inner_args = jax.tree.unflatten(tree, full)
      out = fn(*inner_args[0], **inner_args[1])
      passed = {id(x) for x in inner}
      computed = {
          id(x): x
          for x in jax.tree.leaves(out)
          if isinstance(x, jax.core.Tracer) and id(x) not in passed
      }
      captured.update(inner_args=inner_args, out=out, computed=computed)
      return list(computed.values())

    outer = [leaves[i] for i in traced_at]
    closed = jax.make_jaxpr(traced)(*outer)
    if closed.jaxpr.effects:
      values = jex.core.jaxpr_as_fun(closed)(*outer)
    else:
      values = _Program(closed, outer).run()
    inner_args = captured['inner_args']
    replaced = dict(zip(captured['computed'], values))
    inner_leaves = jax.tree.leaves(inner_args)
    for i, x in zip(traced_at, outer):
      replaced[id(inner_leaves[i])] = x  # an argument passed through
    origin = {}
    _pair(inner_args, (args, kwargs), origin)
    return _rebuild(captured['out'], replaced, origin)

  return run


def _children(tree):
  """A pytree node's children and definition (one level)."""
  return jax.tree_util.tree_flatten(tree, is_leaf=lambda x: x is not tree)


def _pair(inner, given, origin):
  """Maps the containers `fn` got (rebuilt around tracers) to the given."""
  if inner is given:
    return
  children, node = _children(inner)
  if jax.tree_util.treedef_is_leaf(node):
    return
  origin[id(inner)] = given
  for a, b in zip(children, _children(given)[0]):
    _pair(a, b, origin)


def _rebuild(tree, replaced, origin):
  """`tree` with the leaves whose ids are in `replaced` replaced.

  A container is rebuilt only where something in it changed; one that holds
  what the given container (`origin`) held is that container again, and
  everything else is returned as the very same object.
  """
  if id(tree) in replaced:
    return replaced[id(tree)]
  children, node = _children(tree)
  if jax.tree_util.treedef_is_leaf(node):
    return tree
  new = [_rebuild(child, replaced, origin) for child in children]
  given = origin.get(id(tree))
  if given is not None:
    given_children, given_node = _children(given)
    if given_node == node and all(a is b for a, b in zip(new, given_children)):
      return given
  if all(a is b for a, b in zip(new, children)):
    return tree
  return jax.tree_util.tree_unflatten(node, new)


# -- the program: equations inlined, then scheduled --------------------------


class _Cell:
  """A value of the program: known (`ready`) or computed by a node."""

  __slots__ = ('value', 'ready', 'users')

  def __init__(self, value=None, ready=False):
    self.value, self.ready, self.users = value, ready, []


class _Node:
  """One equation to evaluate, with its inputs and outputs as cells."""

  __slots__ = ('order', 'eqn', 'inputs', 'outputs', 'name_stack', 'waiting')

  def __init__(self, order, eqn, inputs, outputs, name_stack):
    self.order, self.eqn = order, eqn
    self.inputs, self.outputs = inputs, outputs
    self.name_stack = name_stack
    self.waiting = 0

  def __lt__(self, other):
    return self.order < other.order


def _draws(jaxpr, memo) -> bool:
  """Whether `jaxpr` (with the calls it inlines) has a random primitive."""
  key = id(jaxpr)
  if key not in memo:
    memo[key] = any(
        eqn.primitive.name in _RANDOM_PRIMITIVES
        or (_called(eqn) is not None and _draws(_called(eqn).jaxpr, memo))
        for eqn in jaxpr.eqns
    )
  return memo[key]


def _count_draws(jaxpr) -> int:
  """Random primitives in `jaxpr` outside control flow, calls inlined."""
  count = 0
  for eqn in jaxpr.eqns:
    if eqn.primitive.name in _RANDOM_PRIMITIVES:
      count += 1
    elif _called(eqn) is not None:
      count += _count_draws(_called(eqn).jaxpr)
  return count


def _worth_batching(jaxpr) -> bool:
  """Two draws at one level of `jaxpr` or of a control-flow body in it."""
  if _count_draws(jaxpr) >= 2:
    return True
  return any(
      _worth_batching(sub)
      for eqn in jaxpr.eqns
      if _called(eqn) is None
      for sub in jex.core.jaxprs_in_params(eqn.params)
  )


def _called(eqn):
  """The closed jaxpr a call equation evaluates, or None."""
  if eqn.primitive.name not in _CALL_PRIMITIVES:
    return None
  sub = eqn.params.get('jaxpr', eqn.params.get('call_jaxpr'))
  if sub is None:
    return None
  if isinstance(sub, jex.core.Jaxpr):
    if sub.constvars:
      return None
    sub = jex.core.ClosedJaxpr(sub, ())
  return sub


class _Program:
  """A closed jaxpr as a graph of nodes, evaluated level by level."""

  def __init__(self, closed, args=()):
    self.nodes = []
    self._memo = {}
    self.outputs = self._inline(
        closed.jaxpr,
        closed.consts,
        [_Cell(a, ready=True) for a in args],
        source_info_util.new_name_stack(),
    )

  def _inline(self, jaxpr, consts, inputs, name_stack):
    env = {}
    for var, value in zip(jaxpr.constvars, consts):
      env[var] = _Cell(value, ready=True)
    for var, cell in zip(jaxpr.invars, inputs):
      env[var] = cell

    def read(atom):
      if isinstance(atom, jex.core.Literal):
        return _Cell(atom.val, ready=True)
      return env[atom]

    for eqn in jaxpr.eqns:
      inputs = [read(v) for v in eqn.invars]
      sub = _called(eqn)
      if sub is not None and _draws(sub.jaxpr, self._memo):
        outputs = self._inline(
            sub.jaxpr,
            sub.consts,
            inputs,
            name_stack + eqn.source_info.name_stack,
        )
      else:
        outputs = [_Cell() for _ in eqn.outvars]
        eqn = self._with_batched_bodies(eqn)
        node = _Node(len(self.nodes), eqn, inputs, outputs, name_stack)
        self.nodes.append(node)
      for var, cell in zip(eqn.outvars, outputs):
        if not isinstance(var, jex.core.DropVar):
          env[var] = cell
    return [read(v) for v in jaxpr.outvars]

  def _with_batched_bodies(self, eqn):
    """`eqn`, its control-flow bodies that draw rewritten on their own."""
    params = {}
    for name, value in eqn.params.items():
      if isinstance(value, jex.core.ClosedJaxpr):
        params[name] = self._rewritten(value)
      elif (
          isinstance(value, tuple)
          and value
          and all(isinstance(v, jex.core.ClosedJaxpr) for v in value)
      ):
        params[name] = tuple(self._rewritten(v) for v in value)
    if all(params[name] is eqn.params[name] for name in params):
      return eqn
    return eqn.replace(params={**eqn.params, **params})

  def _rewritten(self, closed):
    """A body with two or more draws, batched; else `closed` itself."""
    if not _worth_batching(closed.jaxpr):
      return closed
    args = [
        jax.ShapeDtypeStruct(a.shape, a.dtype, weak_type=a.weak_type)
        for a in closed.in_avals
    ]
    new = jax.make_jaxpr(lambda *a: _Program(closed, a).run())(*args)
    # A body's signature is part of its primitive's contract: keep the old
    # body where the new one would change a type (weak types included).
    if new.in_avals != closed.in_avals or new.out_avals != closed.out_avals:
      return closed
    return new

  def run(self):
    ready = []
    for node in self.nodes:
      pending = {id(c): c for c in node.inputs if not c.ready}
      node.waiting = len(pending)
      for cell in pending.values():
        cell.users.append(node)
      if not node.waiting:
        heapq.heappush(ready, node)
    held = []
    while ready or held:
      while ready:
        node = heapq.heappop(ready)
        if _hashable(node):
          held.append(node)
          continue
        self._finish(node, _evaluate(node), ready)
      if len(held) == 1:
        node, held = held[0], []
        self._finish(node, _evaluate(node), ready)
      elif held:
        batch, held = held, []
        for node, values in zip(batch, _evaluate_hashes(batch)):
          self._finish(node, values, ready)
    return [cell.value for cell in self.outputs]

  @staticmethod
  def _finish(node, values, ready):
    for cell, value in zip(node.outputs, values):
      cell.value, cell.ready = value, True
      for user in cell.users:
        user.waiting -= 1
        if not user.waiting:
          heapq.heappush(ready, user)
      cell.users = []


def _context(node):
  eqn = node.eqn
  name_stack = (
      source_info_util.current_name_stack()
      + node.name_stack
      + eqn.source_info.name_stack
  )
  return source_info_util.user_context(
      eqn.source_info.traceback, name_stack=name_stack
  )


def _evaluate(node):
  """Binds one equation, as `jax.core.eval_jaxpr` does; a list of values."""
  eqn = node.eqn
  params = eqn.primitive.get_bind_params(eqn.params)
  with _context(node), eqn.ctx.manager:
    out = eqn.primitive.bind(*(c.value for c in node.inputs), **params)
  return out if eqn.primitive.multiple_results else [out]


# -- the hash, once for many draws --------------------------------------------

# The name  gives threefry keys (no key is made at import:
# that would start JAX's backend before `jax.distributed.initialize`).
_THREEFRY = 'threefry2x32'


def _hashable(node) -> bool:
  """A random primitive of threefry keys in the partitionable layout."""
  eqn = node.eqn
  if eqn.primitive.name not in _RANDOM_PRIMITIVES:
    return False
  if not eqn.ctx.threefry_partitionable:
    return False
  keys = node.inputs[0].value
  if str(jax.random.key_impl(keys)) != _THREEFRY:
    return False
  return math.prod(eqn.outvars[0].aval.shape) > 0


def _counters(shape):
  """JAX's partitionable counters of a draw of `shape`: (high, low) words."""
  index = np.arange(math.prod(shape), dtype=np.uint64).reshape(shape)
  return (index >> np.uint64(32)).astype(np.uint32), index.astype(np.uint32)


def _hash_inputs(node):
  """(k1, k2, x1, x2) of every hash the node's primitive computes."""
  eqn = node.eqn
  keys = node.inputs[0].value
  words = jax.random.key_data(keys)
  k1, k2 = words[..., 0], words[..., 1]
  if eqn.primitive.name == 'random_fold_in':
    shape = eqn.outvars[0].aval.shape
    msgs = jnp.asarray(node.inputs[1].value).astype(jnp.uint32)
    x1 = jnp.zeros(shape, jnp.uint32)
    x2 = jnp.broadcast_to(msgs, shape)
  else:  # random_bits, random_split: one counter per drawn element
    draw = tuple(eqn.params['shape'])
    shape = keys.shape + draw
    expand = (Ellipsis,) + (None,) * len(draw)
    k1, k2 = k1[expand], k2[expand]
    x1, x2 = (jnp.broadcast_to(c, shape) for c in _counters(draw))
  return [jnp.broadcast_to(k, shape) for k in (k1, k2)] + [x1, x2]


def _hash_outputs(node, bits1, bits2):
  """The primitive's output from the two hash words of its counters."""
  eqn = node.eqn
  name = eqn.primitive.name
  keys = node.inputs[0].value
  if name in ('random_split', 'random_fold_in'):
    words = jnp.stack([bits1, bits2], axis=-1)
    return jax.random.wrap_key_data(words, impl=jax.random.key_impl(keys))
  width = eqn.params['bit_width']
  dtype = eqn.outvars[0].aval.dtype
  if width == 64:
    high = lax.convert_element_type(bits1, dtype)
    low = lax.convert_element_type(bits2, dtype)
    return lax.shift_left(high, jnp.asarray(32, dtype)) | low
  if width == 32:
    return bits1 ^ bits2
  return lax.convert_element_type(bits1 ^ bits2, dtype)


def _evaluate_hashes(batch):
  """Values of the held-back random primitives, from one threefry call."""
  outputs = []
  with jax.named_scope('batched_threefry'):
    parts = []
    for node in batch:
      with _context(node), node.eqn.ctx.manager:
        parts.append(_hash_inputs(node))
    shapes = [p[0].shape for p in parts]
    flat = [
        jnp.concatenate([p[i].reshape(-1) for p in parts]) for i in range(4)
    ]
    bits1, bits2 = jex.random.threefry2x32_p.bind(*flat)
    start = 0
    for node, shape in zip(batch, shapes):
      size = math.prod(shape)
      stop = start + size
      with _context(node), node.eqn.ctx.manager:
        value = _hash_outputs(
            node,
            bits1[start:stop].reshape(shape),
            bits2[start:stop].reshape(shape),
        )
      outputs.append([value])
      start = stop
  return outputs
