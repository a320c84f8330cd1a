"""A variator's draws, with equal variations drawn together.

Tasks bind the same kind of variation to many elements: every geom's density
scaled by `Multiplicative(Uniform(0.9, 1.1))`, every actuator's gear, every
link's colour. Drawn one binding at a time, each such binding puts its own
copy of the variation's operations (the threefry hash, the transform of the
uniform bits, the arithmetic) into the reset program, and the step program
that holds an auto-reset: the walk task's 41 bindings (19 densities, 21
gears, the floor's friction) were 41 copies; drawn in groups they are 3.
On a CPU, the step program of `walk:only_randomize` (`benchmarks/
compile_time.py`) shrank from 43,656 to 37,497 HLO instructions; its
compile time did not measurably change there. Here bindings whose variations compare equal (`==`, structural)
are drawn by one `jax.vmap` of the variation over their keys and values: one
copy per group in the program. Each binding keeps its own key, and a vmapped
draw computes exactly what the separate draws compute, so the values are
bit-identical to drawing one binding at a time
(`tests/test_batched_sampling.py`).

Drawn alone, as before: stateful variations (their states have their own
structure per binding), variations with a node anywhere in their tree that
compares by identity: a `VariationBroadcaster` proxy (its draws are keyed
by the order in which the round first meets each broadcaster, which must
not change) or a composer-style subclass without `_eq_fields` (it may read
its initial value as a concrete array; vmapped, that is a tracer);
structures of variations (not one `Variation`); and bindings whose values
differ in shape or dtype.
"""

from __future__ import annotations

from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer.variation import base


def _structural(variation) -> bool:
  """Whether every node of the variation compares by structure.

  A node that compares by identity (`_eq_fields` None) may be a
  composer-style subclass, which may read its initial value as a concrete
  array; a broadcaster proxy is one too (it draws by the round's order of
  first use, which a group would change).
  """
  fields = variation._eq_fields()  # pylint: disable=protected-access
  if fields is None:
    return False
  is_node = lambda x: isinstance(x, base.Variation)
  return all(
      _structural(leaf)
      for leaf in jax.tree.leaves(fields, is_leaf=is_node)
      if is_node(leaf)
  )


def _groupable(variation, state) -> bool:
  return (
      isinstance(variation, base.Variation)
      and state is None
      and _structural(variation)
  )


def groups(variations: Sequence[Any], states, initial) -> list[list[int]]:
  """Indices of the bindings drawn together, in order of first member.

  Args:
    variations: each binding's variation.
    states: each binding's variation state (None when stateless).
    initial: each binding's initial value (its shape and dtype must match
      within a group).
  """
  found: list[tuple[Any, tuple, Any, list[int]]] = []
  for i, (variation, state) in enumerate(zip(variations, states)):
    shape, dtype = np.shape(initial[i]), np.asarray(initial[i]).dtype
    if _groupable(variation, state):
      for other, other_shape, other_dtype, members in found:
        if (
            other is not None
            and other_shape == shape
            and other_dtype == dtype
            and other == variation
        ):
          members.append(i)
          break
      else:
        found.append((variation, shape, dtype, [i]))
    else:
      found.append((None, shape, dtype, [i]))
  return [members for *_, members in found]


def sample_bindings(variations, states, keys, initial, current):
  """Draws every binding's value; returns `(values, new_states)` lists.

  The same as `base.sample(variations[i], states[i], keys[i], initial[i],
  current[i])` for every i, evaluated group by group (`groups`). Call it
  inside the variator's evaluation round.
  """
  count = len(variations)
  values, new_states = [None] * count, list(states)
  for members in groups(variations, states, initial):
    if len(members) == 1:
      i = members[0]
      values[i], new_states[i] = base.sample(
          variations[i], states[i], keys[i], initial[i], current[i]
      )
      continue
    variation = variations[members[0]]

    def draw(key, initial_value, current_value, variation=variation):
      value, _ = base.sample(variation, None, key, initial_value, current_value)
      return value

    member_keys = [keys[i] for i in members]
    keyless = any(k is None for k in member_keys)
    stacked = jax.vmap(draw, in_axes=(None if keyless else 0, 0, 0))(
        None if keyless else jnp.stack(member_keys),
        jnp.stack([jnp.asarray(initial[i]) for i in members]),
        jnp.stack([jnp.asarray(current[i]) for i in members]),
    )
    for row, i in enumerate(members):
      values[i] = stacked[row]
  return values, new_states
