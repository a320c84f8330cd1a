"""What a traced function reads of an `mjx.Data`, and of its inputs.

A reset's forward pass needs to compute only what is read of the new state
before the next physics step (`reset_forward.py`). This module answers that
from the readers' jaxpr, at trace time:

* the fields: the inputs left after dead-code elimination, so a field that only reaches ignored outputs is not read,
  and one that passes through a branch or loop is;
* the `sensordata` elements: those the remaining program takes with static
  slices, constant-index dynamic slices or constant-index gathers (a
  binding of one sensor, or of several non-contiguous ones), following calls
  into their sub-jaxprs; any other use of `sensordata` counts as reading
  all of it.

`reads` returns both.

Both err towards reading more, never less: a JAX without dead-code
elimination makes everything read.
"""

import dataclasses

import jax
import numpy as np

from mjx_composer.platform import answer_cache
from mjx_composer.platform import internals_jax


def leaf_names(data) -> list[str]:
  """The names of `data`'s leaves, e.g. `'qpos'`, `'_impl.efc_J'`."""
  paths, _ = jax.tree_util.tree_flatten_with_path(data)
  return [
      '.'.join(
          str(getattr(k, 'name', getattr(k, 'key', getattr(k, 'idx', k))))
          for k in path
      )
      for path, _ in paths
  ]


def leaves_named(data, names) -> dict:
  """`{name: leaf}` of `data`'s leaves named in `names` (`leaf_names`)."""
  names = frozenset(names)
  return {
      name: leaf
      for name, leaf in zip(leaf_names(data), jax.tree.leaves(data))
      if name in names
  }


def with_leaves(data, leaves: dict):
  """`data` with the leaves named in `leaves` (`leaves_named`) replaced."""
  if not leaves:
    return data
  return jax.tree.unflatten(
      jax.tree.structure(data),
      [
          leaves.get(name, leaf)
          for name, leaf in zip(leaf_names(data), jax.tree.leaves(data))
      ],
  )


def replaced(before, after) -> list:
  """The leaves of `after` that are not `before`'s (the same structure):
  what a traced function wrote, as new values, for `reads`' outputs."""
  pairs = zip(jax.tree.leaves(after), jax.tree.leaves(before))
  return [new for new, old in pairs if new is not old]


def replaced_names(before, after) -> frozenset[str]:
  """The names (`leaf_names`) of the leaves of `before` that `after` (the
  same structure, traced from it) replaced."""
  pairs = zip(
      leaf_names(before), jax.tree.leaves(before), jax.tree.leaves(after)
  )
  return frozenset(name for name, old, new in pairs if new is not old)


def structure_key(tree) -> tuple:
  """What a trace of a function of `tree` can depend on: its structure
  (with MJX's static fields, which drive MJX's Python branches) and its
  leaves' shapes and dtypes, not their values."""
  leaves, treedef = jax.tree.flatten(tree)
  return treedef, tuple(
      (np.shape(x), str(getattr(x, 'dtype', type(x).__name__))) for x in leaves
  )


class PerStructure:
  """Answers of traces that depend on what they trace only through its
  `structure_key`, each computed once per key in this process, and kept on
  disk for later processes where the compilation cache is on
  (`platform.answer_cache`).

  Every environment of a model asks the same few questions of MJX's forward
  pass (what a stage reads and writes), and environments of one model ask
  them again: each trace of a stage takes a fraction of a second, of the
  full forward pass seconds. The oldest answers in memory are dropped past
  `max_entries`. An answer is a frozenset of strings or a tuple of them
  (what a JSON file can hold as such).
  """

  def __init__(self, kind: str | None = None, max_entries: int = 256):
    """`kind`: which analysis asks, unique to it (part of the disk key);
    None keeps the answers in memory only."""
    self._kind = kind
    self._answers = {}
    self._max_entries = max_entries

  def __call__(self, key, compute):
    """The answer for `key` (a tuple that holds `structure_key`s): from
    memory, else from disk, else from `compute()`."""
    if key not in self._answers:
      if len(self._answers) >= self._max_entries:
        self._answers.pop(next(iter(self._answers)))
      self._answers[key] = self._kept_or_computed(key, compute)
    return self._answers[key]

  def _kept_or_computed(self, key, compute):
    name = None
    if self._kind is not None and answer_cache.folder() is not None:
      name = answer_cache.question_digest(self._kind, key)
    if name is not None:
      kept = _decoded(answer_cache.load(name))
      if kept is not None:
        return kept
    answer = compute()
    if name is not None:
      answer_cache.store(name, _encoded(answer))
    return answer


def _encoded(answer):
  """`answer` (frozensets of strings, tuples of them) as JSON data."""
  if isinstance(answer, frozenset):
    return {'set': sorted(answer)}
  return {'tuple': [_encoded(x) for x in answer]}


def _decoded(value):
  """`_encoded`'s answer back, or None where `value` is not one."""
  if not isinstance(value, dict) or len(value) != 1:
    return None
  ((kind, items),) = value.items()
  if not isinstance(items, list):
    return None
  if kind == 'set' and all(isinstance(x, str) for x in items):
    return frozenset(items)
  if kind == 'tuple':
    parts = [_decoded(x) for x in items]
    return None if any(p is None for p in parts) else tuple(parts)
  return None


@dataclasses.dataclass(frozen=True)
class Reads:
  """What a function reads of an `mjx.Data` (`reads`).

  Attributes:
    fields: the names (`leaf_names`) of the leaves it reads.
    sensordata: the indices of the `sensordata` elements it reads: empty
      where it reads no `sensordata`, None for all of them (also where that
      could not be told).
  """

  fields: frozenset
  sensordata: frozenset | None


def reads(fn, data, *args) -> Reads:
  """What `fn(data, *args)`'s outputs depend on, of `data`.

  `fn` returns `(outputs, ignored)`: a pytree whose every leaf counts, and
  one whose leaves do not (e.g. values the next physics step overwrites).
  The dependence is that of the traced program after dead-code elimination,
  so a leaf a branch or loop passes through counts as read. Where this JAX
  has no dead-code elimination to call, everything counts as read.
  """
  names = leaf_names(data)
  if internals_jax.dce_jaxpr is None:
    return Reads(frozenset(names), None)
  closed, (outputs, ignored) = jax.make_jaxpr(fn, return_shape=True)(
      data, *args
  )
  used_outputs = [True] * len(jax.tree.leaves(outputs)) + [False] * len(
      jax.tree.leaves(ignored)
  )
  jaxpr, used_inputs = internals_jax.dce_jaxpr(
      closed.jaxpr, used_outputs, instantiate=False
  )
  used = [n for n, u in zip(names, used_inputs) if u]
  sensordata = frozenset()
  if 'sensordata' in used:
    sensordata = _elements_read(
        jaxpr,
        jaxpr.invars[used.index('sensordata')],
        dict(zip(closed.jaxpr.constvars, closed.consts)),
    )
  return Reads(frozenset(used), sensordata)


def depends_on_inputs(closed, outputs, selected) -> bool:
  """Whether the leaves `selected` of `outputs`, the result of the
  `ClosedJaxpr` `closed`, may depend on any of its inputs.

  By dead-code elimination, as `reads`: a leaf a branch or loop passes
  through depends on all of the branch's or loop's inputs. True where this
  JAX has no dead-code elimination to call.
  """
  if internals_jax.dce_jaxpr is None:
    return True
  wanted = {id(leaf) for leaf in jax.tree.leaves(selected)}
  used_outputs = [id(leaf) in wanted for leaf in jax.tree.leaves(outputs)]
  _, used_inputs = internals_jax.dce_jaxpr(
      closed.jaxpr, used_outputs, instantiate=False
  )
  return any(used_inputs)


# Primitives whose parameter holds a sub-jaxpr called with the operands in
# order (jit, checkpointing, custom derivatives).
_CALL_JAXPR_PARAMS = ('jaxpr', 'call_jaxpr', 'fun_jaxpr')
# Constant folding evaluates no operation on more elements than this, nor
# chains of operations deeper than this.
_FOLD_MAX_ELEMENTS = 1 << 16
_FOLD_MAX_DEPTH = 32


def _elements_read(jaxpr, var, known=None):
  """Indices of the 1-D `var`'s elements that `jaxpr` reads, or None.

  Known only where every use of `var` is a static `slice`, a
  `dynamic_slice` at a constant index, a one-element-per-index `gather` at
  constant indices (an index array, as a binding of non-contiguous
  sensors takes), or a call whose sub-jaxpr uses its operand so; any other
  use (an output, a branch, a loop, an operation on the whole array) gives
  None: every element. `known` maps the jaxpr's constant vars to their
  values (a closed jaxpr's constants); `_Constants` folds what is computed
  from them.
  """
  if any(out is var for out in jaxpr.outvars):
    return None
  constants = _Constants(jaxpr, known or {})
  size = var.aval.shape[0] if var.aval.shape else 1
  found = set()
  for eqn in jaxpr.eqns:
    positions = [i for i, v in enumerate(eqn.invars) if v is var]
    if not positions:
      continue
    elements = _elements_of_use(eqn, positions, size, constants)
    if elements is None:
      return None
    found |= elements
  return frozenset(found)


def _elements_of_use(eqn, positions, size, constants):
  """The elements `eqn` reads of the operand at `positions`, or None."""
  name = eqn.primitive.name
  if positions != [0] and name in ('slice', 'dynamic_slice', 'gather'):
    return None
  if name == 'slice':
    (start,), (limit,) = (
        eqn.params['start_indices'],
        eqn.params['limit_indices'],
    )
    return frozenset(range(start, limit, (eqn.params['strides'] or (1,))[0]))
  if name == 'dynamic_slice':
    start = constants.value(eqn.invars[1]) if len(eqn.invars) == 2 else None
    if start is None:
      return None
    (n,) = eqn.params['slice_sizes']
    start = min(max(int(start), 0), size - n)  # As dynamic_slice clamps.
    return frozenset(range(start, start + n))
  if name == 'gather':
    numbers = eqn.params['dimension_numbers']
    indices = constants.value(eqn.invars[1])
    if (
        indices is None
        or eqn.params['slice_sizes'] != (1,)
        or tuple(numbers.offset_dims) != ()
        or tuple(numbers.collapsed_slice_dims) != (0,)
        or tuple(numbers.start_index_map) != (0,)
    ):
      return None
    indices = np.asarray(indices).reshape(-1)
    if indices.size and (indices.min() < 0 or indices.max() >= size):
      return None  # Out of bounds: clamped or filled, as the mode says.
    return frozenset(int(i) for i in indices)
  sub = next(
      (eqn.params[k] for k in _CALL_JAXPR_PARAMS if k in eqn.params), None
  )
  sub = getattr(sub, 'jaxpr', sub)
  if sub is None or len(sub.invars) != len(eqn.invars):
    return None
  inner_known = {}
  for inner, outer in zip(sub.invars, eqn.invars):
    value = constants.value(outer)
    if value is not None:
      inner_known[inner] = value
  found = set()
  for i in positions:
    inner = _elements_read(sub, sub.invars[i], inner_known)
    if inner is None:
      return None
    found |= inner
  return frozenset(found)


class _Constants:
  """The values of a jaxpr's vars computed from constants alone, on demand.

  A var's value is a literal's, a known constant's, or that of the equation
  computing it, evaluated where all its operands have values (index
  arithmetic: the negative-index wrap, broadcasts, casts); equations with
  sub-jaxprs, large operands, and anything that fails to evaluate (a key,
  an effect) give None.
  """

  def __init__(self, jaxpr, known):
    self._known = dict(known)
    self._producers = {out: eqn for eqn in jaxpr.eqns for out in eqn.outvars}

  def value(self, var, depth=0):
    if hasattr(var, 'val'):  # a Literal
      return var.val
    if var in self._known:
      return self._known[var]
    eqn = self._producers.get(var)
    if eqn is None or depth > _FOLD_MAX_DEPTH:
      return None
    if any(
        hasattr(p, 'eqns') or hasattr(p, 'jaxpr') for p in eqn.params.values()
    ):
      return None
    values = [self.value(v, depth + 1) for v in eqn.invars]
    if any(v is None for v in values) or (
        sum(np.size(v) for v in values) > _FOLD_MAX_ELEMENTS
    ):
      return None
    try:
      with jax.ensure_compile_time_eval():
        out = eqn.primitive.bind(*values, **eqn.params)
      outs = out if eqn.primitive.multiple_results else [out]
      for out_var, out_value in zip(eqn.outvars, outs):
        self._known[out_var] = np.asarray(out_value)
    except Exception:  # pylint: disable=broad-except
      return None
    return self._known.get(var)
