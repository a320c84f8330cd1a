"""What the compiler reads (`Host`) and what one call writes (`Fields`)."""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np

from mjx_composer.model import kinematics
from mjx_composer.compiler import inertia


class Host:
  """The compiled host model and the spec handles of its elements.

  Args:
    index: the environment's `ElementIndex`.
  """

  def __init__(self, index):
    self.m: mujoco.MjModel = index.mj_model
    # {kind name: {compiled id: element handle}}
    self.handles: dict[str, dict[int, Any]] = index.handles_by_id()
    body_geoms = {}
    for g in range(self.m.ngeom):
      body_geoms.setdefault(int(self.m.geom_bodyid[g]), []).append(g)
    self.body_geoms: dict[int, list[int]] = body_geoms

  @functools.cached_property
  def qpos0_kinematics(self) -> kinematics.ReferenceKinematics:
    """Positions and com-based quantities of the host model at `qpos0`."""
    return kinematics.ReferenceKinematics(self.m)

  def body_name(self, b: int) -> str:
    return mujoco.mj_id2name(self.m, mujoco.mjtObj.mjOBJ_BODY, b)

  def inertia_geoms(self, b: int, compiler=None) -> list[int]:
    """The compiled geoms of body `b` in the compiler's inertia group.

    Judged from the compiled model: an attachment frame's handle does not
    hold the attached entity's geoms.
    """
    if compiler is None:
      compiler = self.handles['body'][b].compiler
    return [
        g
        for g in self.body_geoms.get(b, ())
        if inertia.in_inertia_group(self.handles['geom'][g], compiler)
    ]

  def infers_from_geoms(self, b: int) -> bool:
    """Whether body `b` infers its inertial from geoms that it has."""
    body = self.handles['body'].get(b)
    return (
        body is not None
        and inertia.infers_inertia(body)
        and bool(self.inertia_geoms(b))
    )

  def copies_body_frame(self, b: int) -> bool:
    """Whether the body's inertial frame is its (local) body frame."""
    body = self.handles['body'].get(b)
    if body is None or not np.isnan(body.ipos[0]):
      return False
    if not inertia.infers_inertia(body):
      return True
    return not self.inertia_geoms(b)


@dataclasses.dataclass
class Fields:
  """The model fields that one call replaces, over a world's model.

  Attributes:
    host: the `Host`.
    model: the world's current mjx.Model (fields that are not replaced are
      read from it).
    fields: `{field name: new value}`.
    values: `{kind: {compiled id: {attribute: value}}}`, the bound values.
    opt: `{option field: new value}`.
  """

  host: Host
  model: mjx.Model
  fields: dict = dataclasses.field(default_factory=dict)
  values: dict = dataclasses.field(default_factory=dict)
  opt: dict = dataclasses.field(default_factory=dict)

  def get(self, name: str):
    """The field as replaced so far, else the model's."""
    return (
        self.fields[name] if name in self.fields else getattr(self.model, name)
    )

  def put(self, name: str, index, value):
    """Sets `name[index] = value` (in the field's dtype)."""
    old = self.get(name)
    self.fields[name] = old.at[index].set(jnp.asarray(value, old.dtype))

  def bound(self, kind: str, obj_id: int) -> dict:
    """`{attribute: value}` bound to one element (empty if none)."""
    return self.values.get(kind, {}).get(obj_id, {})
