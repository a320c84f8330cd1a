"""What one world carries of its `Physics` between programs and through loops.

`WorldFields` are a `Physics` less the model constants that every world
shares and the static index tables: `runtime.state.State` (carried between
steps) and `PhysicsCarry` (carried through a `lax.scan` over sub-steps or a
reset's retry loop) extend it, and `restore` rebuilds the `Physics`.
`changed_model_fields` tells, while tracing, which model fields a hook wrote:
those are the per-world `model_fields`.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from flax import struct
from mujoco import mjx

from mjx_composer.model import element_index
from mjx_composer.physics import world

_MODEL_FIELD_NAMES = tuple(f.name for f in dataclasses.fields(mjx.Model))


def changed_model_fields(before: mjx.Model, after: mjx.Model) -> list[str]:
  """The fields of `after` that are not `before`'s (by identity).

  A hook that writes a model field returns a model whose field is a new
  array; the fields it leaves alone are the same objects. So this tells,
  while tracing, which fields a hook wrote.
  """
  return [
      name
      for name in _MODEL_FIELD_NAMES
      if getattr(after, name) is not getattr(before, name)
  ]


@struct.dataclass
class WorldFields:
  """What one world carries of its `Physics`: everything but the shared
  model constants and the static index tables.

  `runtime.state.State` (carried between steps) and `PhysicsCarry` (carried
  through a loop) extend it; `Physics.world_fields` makes its fields and
  `restore` takes them back. Its leaves come first in both, in this order.

  Attributes:
    data: the world's `mjx.Data`.
    task_state: the task's per-episode state (`Task.initial_task_state`).
    entity_states: each entity's per-episode state (`Entity.initial_state`),
      keyed by the entity's full identifier ('' for the root entity).
    model_fields: per-world values of the model fields that hooks or
      variations write (`{field name: value}`); every other model field is
      the environment's shared constant.
    persistent: per-world entries that survive auto-resets
      (`Physics.get_persistent`), keyed by their owner's name.
    scheduled_hooks: hooks registered by `Physics.schedule_before_step`
      (static: part of the pytree's structure, not of its leaves).
  """

  data: mjx.Data
  task_state: Any
  entity_states: Any
  model_fields: dict
  persistent: Any
  scheduled_hooks: tuple = struct.field(
      pytree_node=False, default=(), kw_only=True
  )

  def restore(
      self, model: mjx.Model, index: element_index.ElementIndex
  ) -> world.Physics:
    """The `Physics` with these parts over the shared `model`."""
    if self.model_fields:
      model = model.replace(**self.model_fields)
    return world.Physics(
        model=model,
        data=self.data,
        task_state=self.task_state,
        index=index,
        persistent=self.persistent,
        initialization_failed=self._initialization_failed(),
        entity_states=self.entity_states,
        scheduled_hooks=self.scheduled_hooks,
    )

  def _initialization_failed(self):
    return None


@struct.dataclass
class PhysicsCarry(WorldFields):
  """The per-world parts of a `Physics`, and whether its initialization
  failed: what a `lax.scan` over sub-steps or a reset's retry loop carries.
  Made by `Physics.carry`; `restore` rebuilds the `Physics`.
  """

  initialization_failed: Any

  def _initialization_failed(self):
    return self.initialization_failed
