"""Nested structures of variations: their state, and their evaluation.

`initial_state`, `sample` and `evaluate` take a variation, a constant, or a
nested structure (lists, tuples, dicts, namedtuples) of them, as composer's
`variation.evaluate` does: every variation leaf is evaluated with its own
key (`fold_in(key, i)` for flattened leaf `i`; a bare variation gets the key
itself) and constants pass through. `base`'s module docstring says how keys
are split and what a structure's state is.
"""

import jax
import tree

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
  leaf_keys = dict(zip(keyed, rounds.fold_in_each(key, keyed)))
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
