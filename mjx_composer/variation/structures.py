"""Nested structures of variations: their state, and their evaluation.

`initial_state`, `sample` and `evaluate` take a variation, a constant, or a
nested structure (lists, tuples, dicts, namedtuples) of them, as composer's
`variation.evaluate` does: every variation leaf is evaluated with its own
key (`fold_in(key, i)` for flattened leaf `i`; a bare variation gets the key
itself) and constants pass through. `base`'s module docstring says how keys
are split and what a structure's state is.
"""

import jax
import jax.numpy as jnp
import numpy as np
import tree

from mjx_composer.utils import stable_id
from mjx_composer.variation import base
from mjx_composer.variation import random_state as random_state_lib
from mjx_composer.variation import rounds


def collapse(states):
  """A tuple of states, or `None` when none of them holds an array."""
  states = tuple(states)
  return tuple(states) if jax.tree_util.tree_leaves(states) else None


def _leaf_values(structure, n, value, per_leaf):
  """The initial/current value handed to each flattened leaf of `structure`.

  With `per_leaf`, a `value` that has the structure of `structure` is split
  leaf by leaf; anything else (an array, a scalar, a structure that does not
  match) is handed whole to every leaf, as composer's `evaluate` does.
  """
  if value is None:
    return [None] * n
  if per_leaf:
    try:
      return tree.flatten_up_to(structure, value)
    except (TypeError, ValueError):
      pass
  return [value] * n


def structure_initial_state(structure, initial_value, per_leaf):
  if isinstance(structure, base.Variation):
    return structure.initial_state(initial_value)
  leaves = tree.flatten(structure)
  ivs = _leaf_values(structure, len(leaves), initial_value, per_leaf)
  return collapse(
      leaf.initial_state(iv) if isinstance(leaf, base.Variation) else None
      for leaf, iv in zip(leaves, ivs)
  )


def sample_structure(
    structure, state, key, initial_value, current_value, per_leaf
):
  """Evaluates every variation leaf of `structure`; returns (values, state)."""
  if isinstance(structure, base.Variation):
    return structure._sample(state, key, initial_value, current_value)
  if callable(structure):
    return structure(initial_value, current_value, key), None
  leaves = tree.flatten(structure)
  if not any(base.is_variation(leaf) for leaf in leaves):
    return structure, None
  n = len(leaves)
  ivs = _leaf_values(structure, n, initial_value, per_leaf)
  cvs = _leaf_values(structure, n, current_value, per_leaf)
  states = state if state is not None else (None,) * n
  # Leaf i's key is fold_in(key, i), all of them from one hash.
  keyed = [i for i, leaf in enumerate(leaves) if callable(leaf)]
  leaf_keys = dict(zip(keyed, stable_id.fold_in_each(key, keyed)))
  values, new_states = [], []
  for i, (leaf, leaf_state, iv, cv) in enumerate(zip(leaves, states, ivs, cvs)):
    if isinstance(leaf, base.Variation):
      value, leaf_state = leaf._sample(leaf_state, leaf_keys[i], iv, cv)
    elif callable(leaf):
      value = leaf(iv, cv, leaf_keys[i])
    else:
      value = leaf
    values.append(value)
    new_states.append(leaf_state)
  return tree.unflatten_as(structure, values), collapse(new_states)


def initial_state(structure, initial_value=None):
  """Returns the state of a nested structure of variations.

  Args:
    structure: a variation, a constant, or a nested structure (lists,
      tuples, dicts, namedtuples) of them.
    initial_value: `None`, a structure matching `structure` (one value per
      leaf), or a single value handed to every leaf.

  Returns:
    The variation's own state if `structure` is a variation; otherwise a
    tuple with one state per flattened leaf, or `None` if nothing in the
    structure is stateful.
  """
  return structure_initial_state(structure, initial_value, per_leaf=True)


def sample(
    structure,
    state,
    key=None,
    initial_value=None,
    current_value=None,
    *,
    random_state=random_state_lib.NO_RANDOM_STATE,
):
  """Evaluates a nested structure of variations and advances its state.

  Args:
    structure: a variation, a constant, or a nested structure of them.
      Non-variation leaves are returned unchanged (no array conversion, so
      Python ints stay static). Any callable leaf is treated as a stateless
      variation and called as `leaf(initial_value, current_value, key)`.
    state: as returned by `initial_state(structure, ...)` or a previous call.
    key: a JAX PRNG key, split per leaf as described in the module
      docstring, or `None` if the structure is deterministic.
    initial_value: `None`, a structure matching `structure` (one value per
      leaf), or a single value handed to every leaf (composer's behaviour).
    current_value: like `initial_value`.

    random_state: composer's numpy `RandomState`: raises a `TypeError` that
      says to pass `key=`.

  Returns:
    `(values, new_state)`: `values` has the structure of `structure`.
  """
  random_state_lib.reject(random_state, "variation.sample")
  rounds.check_key(key, structure)
  with rounds.evaluation_round(key):
    return sample_structure(
        structure, state, key, initial_value, current_value, per_leaf=True
    )


def batches(structure) -> bool:
  """Whether `sample_each` may draw equal copies of `structure` together.

  Every variation in it says it may (`Variation._BATCHES`); a bare callable
  leaf may do anything with its arguments, so it never does.
  """
  # A variation or a callable flattens to itself.
  return all(
      leaf._batches() if isinstance(leaf, base.Variation) else not callable(leaf)  # pylint: disable=protected-access
      for leaf in tree.flatten(structure)
  )


def sample_each(structures, states, keys, initial_values, current_values):
  """`sample` of each structure with its own state, key and values.

  The variations of a variator's bindings are often equal (one
  `Multiplicative(Uniform(0.9, 1.1))` bound to every geom's density): equal
  structures that `batches` allows, with arrays of one shape and dtype for
  their states and values, are drawn in one `jax.vmap` over those. A
  compiled reset then holds one PRNG call for all of them, not one each (on
  a GPU each is a kernel of its own; on a CPU, a few hundred instructions).
  The values are the same, bit for bit, as sampling each on its own. Runs in
  the caller's evaluation round (`rounds.evaluation_round`).

  Args:
    structures: a variation, constant or nested structure of them, each.
    states: their states (`initial_state` or an earlier sample), each.
    keys: one PRNG key each.
    initial_values: one initial value each (see `sample`).
    current_values: one current value each.

  Returns:
    `[(values, new_state), ...]`, one pair per structure, as `sample`'s.
  """
  inputs = list(zip(states, keys, initial_values, current_values))
  for structure, key in zip(structures, keys):
    rounds.check_key(key, structure)
  results = [None] * len(inputs)
  for group in _equal_groups(structures, inputs):
    structure = structures[group[0]]
    if len(group) == 1:
      results[group[0]] = sample_structure(
          structure, *inputs[group[0]], per_leaf=True
      )
      continue
    stacked = jax.tree.map(
        lambda *leaves: jnp.stack(leaves), *(inputs[i] for i in group)
    )
    drawn = jax.vmap(
        lambda state, key, initial, current: sample_structure(
            structure, state, key, initial, current, per_leaf=True
        )
    )(*stacked)
    for position, i in enumerate(group):
      results[i] = jax.tree.map(lambda x, p=position: x[p], drawn)
  return results


def _equal_groups(structures, inputs):
  """Indices of `structures` in groups that `sample_each` draws together."""
  groups, signatures = [], []
  for i, (structure, arguments) in enumerate(zip(structures, inputs)):
    signature = _array_signature(arguments) if batches(structure) else None
    for group, group_signature in zip(groups, signatures):
      if (
          signature is not None
          and signature == group_signature
          and base._structurally_equal(structures[group[0]], structure)  # pylint: disable=protected-access
      ):
        group.append(i)
        break
    else:
      groups.append([i])
      signatures.append(signature)
  return groups


def _array_signature(arguments):
  """The tree, shapes and dtypes of `arguments`; None if a leaf is no array
  (a Python number's weak type could change once stacked)."""
  leaves, treedef = jax.tree.flatten(arguments)
  if not all(isinstance(x, (np.ndarray, jax.Array)) for x in leaves):
    return None
  return treedef, tuple((x.shape, x.dtype) for x in leaves)


def evaluate(
    structure,
    initial_value=None,
    current_value=None,
    key=None,
    *,
    random_state=random_state_lib.NO_RANDOM_STATE,
):
  """Evaluates every variation in a nested structure (composer's `evaluate`).

  Stateful leaves are evaluated from a fresh state (see the module
  docstring); use `initial_state` and `sample` to carry their state.

  Args:
    structure: a variation, a constant, or a nested structure (lists,
      tuples, dicts, namedtuples) of them; constants pass through.
    initial_value: `None`, a structure matching `structure` (one value per
      leaf), or a single value handed to every leaf.
    current_value: like `initial_value`.
    key: a JAX PRNG key. Leaf `i` gets `jax.random.fold_in(key, i)`, so its
      value does not depend on the other leaves; a bare variation gets `key`.
    random_state: composer's numpy `RandomState` argument: passing it
      raises a `TypeError` that says to pass `key=` instead.

  Returns:
    The structure with every variation replaced by its value.
  """
  random_state_lib.reject(random_state, "variation.evaluate")
  state = initial_state(structure, initial_value)
  values, _ = sample(structure, state, key, initial_value, current_value)
  return values
