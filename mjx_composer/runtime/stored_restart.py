"""The auto-reset that restores the world's first state instead of a reset.

An auto-reset runs `Transitions.reset(key, previous)`, which reads of the
world's last state only what the world carries across episodes (its model
fields, persistent entries and scheduled hooks, `Transitions.start_carry`)
and, with `fixed_initial_state`, its first key (`keys.INITIAL_KEY`). Where
a world carries nothing else, every restart is the function of the
episode's key that its first reset was, and what of it does not depend on
the key is the same at every restart. Where that includes the physics the
episode starts from (its `mjx.Data`: the pose is fixed, or
`fixed_initial_state` gives every episode the first one's key), the step
program restores it instead of holding the reset (the `initialize_episode`
hooks, the reset's stage of the forward pass, the first observation), as
Playground's training wrapper restores the state of its last reset: a
smaller program, and a restart that costs a select. What depends on the
key (the key the next step takes, a drawn target or command, observation
noise) is computed from the key at every restart, as the reset computes
it. The episodes are the same, to float rounding in the derived fields of
the first state (`tests/runtime/test_stored_restart.py`).

`plan` decides once per environment, from the reset's jaxpr, split by JAX's
partial evaluation into what depends on the key and what does not (with the
values the first part needs of the second: its residuals). What does not
depend on the key is the same for every world: it is computed once, on the
host's CPU, and both a world's first reset and its restarts take those
values (`Plan.first`, `Plan.restore`). With `fixed_initial_state` it
depends on the world's first key: each world keeps a copy of its first
state (`State.stored_first`, one more state in memory, as Playground's
wrapper keeps), which its restarts restore.

The reset runs instead where the physics an episode starts from depends on
its key (a drawn pose, a randomized model), where the world carries model
fields, persistent entries or scheduled hooks, where the part that does not
depend on the key has effects (a debug print would run once, not at every
reset), with `ExecutionOptions(stored_restart='never')`, and on a backend
whose data holds buffers shared by the batch (`Backend.batch_shared_data`),
which one world's copy cannot hold.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.extend.core as jax_core
import jax.numpy as jnp
import numpy as np

from mjx_composer.platform import internals_jax
from mjx_composer.runtime import keys as keys_lib


@dataclasses.dataclass(frozen=True)
class Plan:
  """Where each leaf of a restarted `State` comes from.

  Attributes:
    treedef: the structure of a reset's `State` (`stored_first` None).
    stored: the leaves every restart of a world takes from its first state.
    computed: the leaves each restart computes from its key.
    constants: None where each world keeps its `stored` leaves
      (`fixed_initial_state`: they depend on its first key); else their
      values, the same for every world, then the residuals `unknown` takes
      (the reset's values it needs that do not depend on the key), as
      NumPy arrays (`_HostKeys` for keys) computed once on the host.
    unknown: a `ClosedJaxpr` of the residuals and the key that computes
      `computed`'s leaves, in that order.
  """

  treedef: Any
  stored: tuple[int, ...]
  computed: tuple[int, ...] = ()
  constants: tuple[np.ndarray, ...] | None = None
  unknown: Any = None

  def first(self, reset, key):
    """A world's first state, `reset(key)`; with `fixed_initial_state`, with
    the copy its restarts restore (`State.stored_first`)."""
    if self.constants is not None:
      return self._assemble(self.constants, key)
    leaves = jax.tree.leaves(reset(key))
    kept = tuple(leaves[i] for i in self.stored)
    return self._assemble(kept, key).replace(stored_first=kept)

  def restore(self, key, last):
    """What `Transitions.reset(key, previous=last)` computes."""
    if self.constants is not None:
      return self._assemble(self.constants, key)
    return self._assemble(last.stored_first, key).replace(
        stored_first=last.stored_first
    )

  def _assemble(self, kept, key):
    leaves = [None] * self.treedef.num_leaves
    n = len(self.stored)
    kept = [_on_the_device(leaf) for leaf in kept]
    for i, leaf in zip(self.stored, kept[:n]):
      leaves[i] = leaf
    if self.computed:
      values = jax_core.jaxpr_as_fun(self.unknown)(
          *kept[n:], *jax.tree.leaves(key)
      )
      for i, leaf in zip(self.computed, values):
        leaves[i] = leaf
    return jax.tree.unflatten(self.treedef, leaves)


def carries_nothing(state) -> bool:
  """Whether a world in `state` (shapes suffice) carries nothing across
  episodes that its reset reads but its first key."""
  return (
      not state.model_fields
      and set(state.persistent) <= {keys_lib.INITIAL_KEY}
      and not state.scheduled_hooks
  )


def plan(transitions) -> Plan | None:
  """The `Plan` of `transitions`' auto-reset, or None where it runs the
  reset (module docstring)."""
  shapes = transitions.analysis.reset_shapes
  if (
      transitions.stored_restart_mode == 'never'
      or transitions.backend.batch_shared_data
      or not carries_nothing(shapes.state)
      # Found without another trace: the attempt's physics depends on the
      # episode's key (which `fixed_initial_state` makes the first's).
      or (shapes.physics_drawn and not transitions.fixed_initial_state)
  ):
    return None
  key = keys_lib.key_shape()
  closed, state = jax.make_jaxpr(transitions.reset, return_shape=True)(key)
  treedef = jax.tree.structure(state)
  if transitions.fixed_initial_state:  # every episode is the first
    return Plan(treedef, stored=tuple(range(treedef.num_leaves)))
  if internals_jax.partial_eval_jaxpr_nounits is None:
    return None
  known, unknown, on_key, _ = internals_jax.partial_eval_jaxpr_nounits(
      closed, [True] * len(jax.tree.leaves(key)), instantiate=False
  )
  paths = [
      jax.tree_util.keystr(path)
      for path, _ in jax.tree_util.tree_flatten_with_path(state)[0]
  ]
  if any(u and path.startswith('.data.') for u, path in zip(on_key, paths)):
    return None  # the physics each episode starts from is drawn
  if known.effects:
    return None  # e.g. a debug print: it runs at every reset, not once
  constants = _on_the_host(known)
  if constants is None:
    return None
  return Plan(
      treedef,
      stored=tuple(i for i, u in enumerate(on_key) if not u),
      computed=tuple(i for i, u in enumerate(on_key) if u),
      constants=constants,
      unknown=unknown,
  )


def _on_the_host(closed) -> tuple | None:
  """The values of `closed`, a `ClosedJaxpr` without inputs, computed on
  the host's CPU: a program as large as the reset, compiled once (JAX's
  persistent compilation cache keeps it where it is on) so that no
  device program holds it. None where JAX has no CPU backend (e.g.
  `JAX_PLATFORMS=cuda`)."""
  try:
    cpu = jax.devices('cpu')[0]
  except RuntimeError:
    return None

  def values(consts):
    return jax_core.jaxpr_as_fun(jax_core.ClosedJaxpr(closed.jaxpr, consts))()

  # Run now, also where a program is being traced (the first trace of a
  # reset or step asks for the plan).
  with jax.ensure_compile_time_eval():
    consts = [jax.device_put(c, cpu) for c in closed.consts]
    return tuple(_HostKeys.of(v) for v in jax.jit(values)(consts))


@dataclasses.dataclass(frozen=True)
class _HostKeys:
  """PRNG keys kept on the host: their data and implementation (NumPy has
  no key type)."""

  data: np.ndarray
  impl: Any

  @classmethod
  def of(cls, value):
    """`value` as NumPy, or as `_HostKeys` where it holds keys."""
    if jnp.issubdtype(value.dtype, jax.dtypes.prng_key):
      return cls(
          np.asarray(jax.random.key_data(value)), jax.random.key_impl(value)
      )
    return np.asarray(value)


def _on_the_device(value):
  """A value a program takes: a traced one as it is, a host one as a
  constant of the program."""
  if isinstance(value, _HostKeys):
    return jax.random.wrap_key_data(value.data, impl=value.impl)
  if isinstance(value, np.ndarray):
    return jnp.asarray(value)
  return value
