"""Kinematics at a configuration the host already knows.

A reset needs positions twice before its forward pass: at the initial state,
for the `initialize_episode` hooks, and at `qpos0`, for the `mj_setConst`
quantities that randomized masses change. `mjx.kinematics` unrolls the body
tree level by level, so each call adds thousands of equations to every
program holding a reset (the step program does, through auto-reset) and
lengthens its compile time.

Both configurations are known when the environment is built. A
`ReferenceKinematics` computes them once with MuJoCo's C library, and
`ReferenceKinematics.apply` returns what `mjx.com_pos(model,
mjx.kinematics(model, data))` would, recomputing on the device only what
the model fields that can differ from the host model's change:

* joint axes and anchors, body positions and orientations: the tree fields
  (`qpos0`, `body_pos`, `body_quat`, `jnt_pos`, `jnt_axis`); any of them
  varying falls back to the full `mjx.kinematics`;
* inertial frames (`body_ipos`, `body_iquat`), geom frames (`geom_pos`,
  `geom_quat`), site frames (`site_pos`, `site_quat`): one rotation each,
  from the body frames;
* the com-based quantities (`subtree_com`, `cinert`, `cdof`): `mjx.com_pos`
  when a mass, inertia or inertial frame can differ.

A field "can differ" when it is traced (per-world) or its value is not the
host model's (an `after_compile` hook changed it). The results equal MJX's
to float32 rounding: the host computes in float64.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np

from mjx_composer.platform import internals
from mjx_composer.utils import transformations

_TREE = ('qpos0', 'body_pos', 'body_quat', 'jnt_pos', 'jnt_axis')
_INERTIAL_FRAME = ('body_ipos', 'body_iquat')
_MASS = ('body_mass', 'body_inertia')
_FRAMES = (  # (frame inputs, body id field, output position, output matrix)
    (_INERTIAL_FRAME, None, 'xipos', 'ximat'),
    (('geom_pos', 'geom_quat'), 'geom_bodyid', 'geom_xpos', 'geom_xmat'),
    (('site_pos', 'site_quat'), 'site_bodyid', 'site_xpos', 'site_xmat'),
)
_BODY_OUTPUTS = ('xanchor', 'xaxis', 'xpos', 'xquat', 'xmat')
_COM_OUTPUTS = ('subtree_com', 'cinert', 'cdof')


class ReferenceKinematics:
  """Positions and com-based quantities of one configuration, from the host.

  Args:
    mj_model: the compiled host model.
    qpos: the configuration's joint positions (default: `qpos0`).
    mocap_pos, mocap_quat: its mocap poses (default: the model's).
  """

  def __init__(self, mj_model, qpos=None, mocap_pos=None, mocap_quat=None):
    d = mujoco.MjData(mj_model)
    if qpos is not None:
      d.qpos[:] = qpos
    if mocap_pos is not None:
      d.mocap_pos[:] = mocap_pos
    if mocap_quat is not None:
      d.mocap_quat[:] = mocap_quat
    mujoco.mj_kinematics(mj_model, d)
    mujoco.mj_comPos(mj_model, d)
    self._m = mj_model
    self._config = {
        'qpos': d.qpos.copy(),
        'mocap_pos': d.mocap_pos.copy(),
        'mocap_quat': d.mocap_quat.copy(),
    }
    self._values = {}
    frames = tuple(name for f in _FRAMES for name in f[2:])
    for name in _BODY_OUTPUTS + _COM_OUTPUTS + frames:
      value = np.array(getattr(d, name))
      self._values[name] = value.reshape(-1, 3, 3) if 'mat' in name else value

  def matches(self, data) -> bool:
    """Whether `data` is at this configuration (known while tracing)."""
    for name, value in self._config.items():
      field = getattr(data, name)
      if not value.size:
        continue  # e.g. no mocap bodies
      if isinstance(field, jax.core.Tracer):
        return False
      if not np.array_equal(np.asarray(field), value.astype(field.dtype)):
        return False
    return True

  def _varies(self, model, names, written) -> bool:
    for name in names:
      if name in written:
        return True
      value = getattr(model, name)
      if isinstance(value, jax.core.Tracer):
        return True
      host = getattr(self._m, name)
      if not np.array_equal(np.asarray(value), host.astype(value.dtype)):
        return True
    return False

  def com_varies(self, model, written=()) -> bool:
    """Whether `model`'s com-based quantities (`subtree_com`, `cinert`,
    `cdof`) can differ from the host's: a mass, an inertia or an inertial
    frame can (`written` as in `apply`)."""
    return self._varies(model, _MASS + _INERTIAL_FRAME, frozenset(written))

  @jax.named_scope('kinematics')
  def apply(self, model, data, written=(), com=True) -> mjx.Data:
    """`mjx.com_pos(model, mjx.kinematics(model, data))`, reusing the host's.

    Args:
      model: the world's mjx.Model.
      data: its mjx.Data; must be at this configuration (`matches`), else
        MJX computes everything.
      written: names of model fields about to change (e.g. set by the
        compiler in this call), treated as varying.
      com: False leaves the com-based quantities at the host's values
        where only a mass, an inertia or an inertial frame varies
        (`com_varies`), for a caller that marks them stale and computes
        them where they are read (a reset's hooks: `Physics.read`).

    Returns:
      `data` with the kinematics and com-based fields set.
    """
    written = frozenset(written)
    if not self.matches(data) or self._varies(model, _TREE, written):
      return mjx.com_pos(model, mjx.kinematics(model, data))
    dtype = data.xpos.dtype
    values = {
        name: jnp.asarray(self._values[name], dtype) for name in _BODY_OUTPUTS
    }
    for inputs, body_id, pos_name, mat_name in _FRAMES:
      if self._varies(model, inputs, written):
        ids = (
            np.arange(self._m.nbody)
            if body_id is None
            else np.asarray(getattr(self._m, body_id))
        )
        local_pos, local_quat = (getattr(model, name) for name in inputs)
        values[pos_name], values[mat_name] = _to_global(
            values['xpos'][ids], values['xquat'][ids], local_pos, local_quat
        )
      else:
        values[pos_name] = jnp.asarray(self._values[pos_name], dtype)
        values[mat_name] = jnp.asarray(self._values[mat_name], dtype)
    data = _set(data, values)
    if com and self.com_varies(model, written):
      return mjx.com_pos(model, data)
    return _set(
        data,
        {name: jnp.asarray(self._values[name], dtype) for name in _COM_OUTPUTS},
    )


def _set(data, values):
  """`data` with fields replaced, public or (like `cinert`) MJX-internal."""
  public = {f.name for f in dataclasses.fields(data)}
  data = data.replace(**{k: v for k, v in values.items() if k in public})
  # MJX 3.17 keeps `cinert` and `cdof` in its JAX-backend data (`_impl`),
  # with no public setter; `mjx.com_pos` writes them the same way.
  internal = {k: v for k, v in values.items() if k not in public}
  if not internal:
    return data
  return internals.replace_data_impl(data, **internal)


def _to_global(body_pos, body_quat, local_pos, local_quat):
  """World position and rotation matrix of frames given in body frames."""
  pos = body_pos + transformations.rotate_vec(body_quat, local_pos)
  quat = transformations.quat_mul(body_quat, local_quat)
  return pos, transformations.quat_to_mat(quat)
