"""Device writes: how a bound value becomes the compiled fields it sets.

Each is a `ModelWrite`, `(fields, compiled id, float32 value) -> None`,
that writes into a `context.Fields`; the attribute catalogue
(`attributes.CATALOGUE`) names one per attribute.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import jax.numpy as jnp
import mujoco

from mjx_composer.model import element_index
from mjx_composer.compiler import frames
from mjx_composer.compiler import geoms

ModelWrite = Callable[[Any, int, Any], None]


def put(field: str) -> ModelWrite:
  """Writes the value to `field[compiled id]`."""
  return lambda fields, i, value: fields.put(field, i, value)


def dof_slice(m, j: int) -> slice:
  """The dofs of joint `j`."""
  adr = int(m.jnt_dofadr[j])
  return slice(adr, adr + element_index.DOF_WIDTH[int(m.jnt_type[j])])


def put_dofs(field: str) -> ModelWrite:
  """Writes the value to the joint's dofs of `field`."""
  return lambda fields, j, value: fields.put(
      field, dof_slice(fields.host.m, j), value
  )


def put_pose(kind: str, part: str) -> ModelWrite:
  """Writes `<kind>_<part>` (part: pos or quat): the compiled local pose.

  A body's compiled pose is also its free joint's qpos0 and qpos_spring.
  """

  def write(fields, i, value):
    m = fields.host.m
    element = fields.host.handles[kind][i]
    frame = frames.frame_between(
        getattr(m, f'{kind}_pos')[i],
        getattr(m, f'{kind}_quat')[i],
        element.pos,
        element.quat,
    )
    pose = frames.apply_frame(frame, **{part: value})
    fields.put(f'{kind}_{part}', i, pose)
    if kind != 'body':
      return
    start = 0 if part == 'pos' else 3
    for j in range(m.body_jntadr[i], m.body_jntadr[i] + m.body_jntnum[i]):
      if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
        adr = int(m.jnt_qposadr[j]) + start
        index = slice(adr, adr + pose.shape[0])
        fields.put('qpos0', index, pose)
        fields.put('qpos_spring', index, pose)

  return write


def geom_size(fields, g, size):
  """The compiled size (`fromto` fixes the length), bounding sphere, AABB."""
  m = fields.host.m
  size = geoms.compiled_size(m, g, fields.host.handles['geom'][g], size)
  gtype = int(m.geom_type[g])
  fields.put('geom_size', g, size)
  fields.put('geom_rbound', g, geoms.rbound(gtype, size))
  # MuJoCo's (6,) row; a 'warp' model lays it out as (2, 3).
  aabb_shape = fields.get('geom_aabb').shape[1:]
  fields.put('geom_aabb', g, jnp.reshape(geoms.aabb(gtype, size), aabb_shape))


def joint_range(fields, j, value):
  """Degrees to radians for the angles of a spec that uses degrees."""
  joint = fields.host.handles['joint'][j]
  if joint.compiler.degree and joint.type in (
      mujoco.mjtJoint.mjJNT_HINGE,
      mujoco.mjtJoint.mjJNT_BALL,
  ):
    value = value * (math.pi / 180)
  fields.put('jnt_range', j, value)


def kp(fields, a, value):
  fields.put('actuator_gainprm', (a, 0), value)
  fields.put('actuator_biasprm', (a, 1), -value)


def kv(fields, a, value):
  fields.put('actuator_biasprm', (a, 2), -value)


def option(name: str) -> ModelWrite:
  def write(fields, i, value):
    del i  # The option is not an element.
    fields.opt[name] = value

  return write
