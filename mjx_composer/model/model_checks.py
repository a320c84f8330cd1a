"""Checks of a compiled `mujoco.MjModel` before it goes to MJX.

`check_compiled_model` runs once, on the host, right after the composed spec
compiles. It turns what would otherwise fail deep inside a traced step, fail
with a terse message in `mjx.put_model`, or silently behave differently from
MuJoCo into errors and warnings that say what to change:

* errors (`ValueError`): a physics timestep that is not a positive, finite
  number of seconds (MuJoCo's compiler accepts any value); a model with no
  degrees of freedom (MJX's step fails with "Scan across Model with zero DoFs
  unsupported");
* errors (`NotImplementedError`, as `mjx.put_model` raises, with the fix):
  an integrator, solver or enable flag that MJX does not implement; a touch
  sensor on a site whose shape MJX cannot ray cast (a cylinder: MJX would
  fail while tracing the step, deep in its ray code);
* errors (`NotImplementedError`, from `check_jax_collisions`, for the JAX
  implementation only): geoms that collide in shapes MJX has no collision
  function for (a cylinder against a box or a height field), named, where
  MJX would fail while sizing its contacts with only the two type numbers;
* one `MjxIgnoredOptionWarning` naming every option MJX's JAX backend accepts
  but ignores (e.g. `noslip_iterations > 0`: MJX has no noslip solver).
"""

from __future__ import annotations

import functools
import math
import warnings

import mujoco
from mujoco import mjx

from mjx_composer.platform import internals


class MjxIgnoredOptionWarning(UserWarning):
  """A model option is set that MJX (JAX backend) ignores."""


# Disable flags MJX does not implement whose MuJoCo behaviour MJX already has
# (it never auto-resets, has no islands and no midphase to disable): setting
# them changes nothing, so they are not worth a warning.
_HARMLESS_DISABLE = frozenset(
    int(getattr(mujoco.mjtDisableBit, name))
    for name in ('mjDSBL_AUTORESET', 'mjDSBL_ISLAND', 'mjDSBL_MIDPHASE')
    if hasattr(mujoco.mjtDisableBit, name)
)
# Enable flags `mjx.put_model` accepts but the JAX backend never reads.
_IGNORED_ENABLE = frozenset(
    int(getattr(mujoco.mjtEnableBit, name))
    for name in ('mjENBL_SLEEP', 'mjENBL_IPC')
    if hasattr(mujoco.mjtEnableBit, name)
)
# Numeric options the JAX backend never reads (MuJoCo's option names).
_IGNORED_NUMERIC = (
    ('ccd_iterations', 'its convex collision uses its own iteration limit'),
    ('ccd_tolerance', 'its convex collision uses its own tolerance'),
    ('sdf_iterations', 'SDF collision uses sdf_initpoints only'),
)


@functools.lru_cache(maxsize=1)
def _default_option():
  return mujoco.MjModel.from_xml_string('<mujoco/>').opt


def _flag_names(enum_type, bits):
  names = []
  for bit in range(32):
    if bits & (1 << bit):
      try:
        names.append(enum_type(1 << bit).name)
      except ValueError:
        names.append(f'bit {1 << bit}')
  return names


def _mjcf_flag(name):
  """`mjDSBL_NATIVECCD` -> `<flag nativeccd="disable"/>`."""
  prefix, _, flag = name.partition('_')
  value = 'disable' if prefix == 'mjDSBL' else 'enable'
  return f'<flag {flag.lower()}="{value}"/>'


def check_compiled_model(mj_model: mujoco.MjModel):
  """Raises on options MJX cannot run; warns once about options it ignores.

  Call it once per build, right after compiling the composed spec.

  Args:
    mj_model: the compiled host model.

  Raises:
    ValueError: the timestep is not a positive, finite number, or the model
      has no degrees of freedom.
    NotImplementedError: an integrator, solver or enable flag that MJX does
      not implement.
  """
  opt = mj_model.opt
  timestep = float(opt.timestep)
  if not math.isfinite(timestep) or timestep <= 0:
    raise ValueError(
        f"The compiled model's option.timestep is {timestep!r}: the physics "
        'timestep must be a positive, finite number of seconds. Set it with '
        'task.set_timesteps(control_timestep=..., physics_timestep=...) (or '
        "task.physics_timestep = ...) rather than writing a spec's "
        'option.timestep.'
    )
  if mj_model.nv == 0:
    raise ValueError(
        'The composed model has no degrees of freedom (nv == 0): nothing in '
        "it can move, and MJX cannot step it ('Scan across Model with zero "
        "DoFs unsupported'). Give a body a joint (body.add_joint(...)), or "
        'make an entity free (arena.add_free_entity(entity), or '
        'entity.attachment_frame.add_freejoint()).'
    )
  _check_rejected(opt)
  _check_touch_sites(mj_model)
  ignored = ignored_options(mj_model)
  if ignored:
    warnings.warn(
        'MJX ignores these options of the compiled model, so it will not '
        'simulate what MuJoCo would: '
        + '; '.join(ignored)
        + '. Leave them at their defaults to silence this warning.',
        MjxIgnoredOptionWarning,
        stacklevel=2,
    )


# The site shapes whose ray intersection MJX implements, so the shapes a
# touch sensor's site may have (MJX finds the contacts inside the site's
# volume by ray casting, `mjx._src.ray`). The cylinder's is the package's
# (`platform.internals.add_missing_ray_functions`, run at import).
TOUCH_SITE_TYPES = (
    mujoco.mjtGeom.mjGEOM_SPHERE,
    mujoco.mjtGeom.mjGEOM_CAPSULE,
    mujoco.mjtGeom.mjGEOM_ELLIPSOID,
    mujoco.mjtGeom.mjGEOM_CYLINDER,
    mujoco.mjtGeom.mjGEOM_BOX,
)


def _check_touch_sites(mj_model):
  """Touch sensors on sites of a shape MJX cannot ray cast, refused.

  MJX would fail deep in its ray code while tracing the step
  (`KeyError: np.int32(5)` for a cylinder).
  """
  supported = {int(t) for t in TOUCH_SITE_TYPES}
  bad = []
  for i in range(mj_model.nsensor):
    if mj_model.sensor_type[i] != mujoco.mjtSensor.mjSENS_TOUCH:
      continue
    site = int(mj_model.sensor_objid[i])
    site_type = int(mj_model.site_type[site])
    if site_type not in supported:
      sensor_name = mujoco.mj_id2name(mj_model, mujoco.mjtObj.mjOBJ_SENSOR, i)
      site_name = mujoco.mj_id2name(mj_model, mujoco.mjtObj.mjOBJ_SITE, site)
      bad.append(
          f'touch sensor {sensor_name or i!r} on site {site_name or site!r} '
          f'of type {mujoco.mjtGeom(site_type).name}'
      )
  if bad:
    names = ', '.join(t.name for t in TOUCH_SITE_TYPES)
    raise NotImplementedError(
        'MJX computes touch sensors only on sites of type '
        f'{names}: ' + '; '.join(bad) + '. Give the site one of those '
        "shapes (a box or capsule of the cylinder's size, "
        'site.type = mujoco.mjtGeom.mjGEOM_BOX), or remove the sensor.'
    )


def check_jax_collisions(mj_model: mujoco.MjModel):
  """Raises where MJX's JAX implementation cannot collide two geoms.

  Call it once per build that runs on `impl='jax'`, before anything sizes
  MJX's contacts.

  Args:
    mj_model: the compiled host model.

  Raises:
    NotImplementedError: a pair of geoms that may touch (contype and
      conaffinity, exclusions and `<pair>`s as MuJoCo's) has shapes MJX
      implements no collision for; the message names every such pair.
  """
  missing = {}
  for g1, g2 in internals.colliding_geom_pairs(mj_model):
    t1, t2 = int(mj_model.geom_type[g1]), int(mj_model.geom_type[g2])
    if internals.has_collision_function(t1, t2):
      continue
    types = tuple(mujoco.mjtGeom(t).name for t in (t1, t2))
    names = tuple(
        mujoco.mj_id2name(mj_model, mujoco.mjtObj.mjOBJ_GEOM, g) or f'#{g}'
        for g in (g1, g2)
    )
    missing.setdefault(types, []).append(names)
  if not missing:
    return
  lines = []
  for (type1, type2), pairs in missing.items():
    shown = ', '.join(f'{a!r} with {b!r}' for a, b in pairs[:5])
    more = f' and {len(pairs) - 5} more' if len(pairs) > 5 else ''
    lines.append(f'{type1} with {type2}: {shown}{more}')
  raise NotImplementedError(
      'MJX has no collision function for these shapes, and these geoms may '
      'touch: ' + '; '.join(lines) + '. Give one geom of each pair another '
      'shape (a capsule or box instead of a cylinder), or keep the pair from '
      'colliding (contype/conaffinity 0 on a visual geom, or an <exclude> '
      'of their bodies).'
  )


def _check_rejected(opt):
  """Clear versions of the option errors `mjx.put_model` raises."""
  if opt.integrator not in set(mjx.IntegratorType):
    raise NotImplementedError(
        'MJX does not implement the integrator '
        f'{mujoco.mjtIntegrator(opt.integrator).name}: set option.integrator '
        'to implicitfast (the closest: mujoco.mjtIntegrator.mjINT_IMPLICITFAST'
        ', MJCF <option integrator="implicitfast"/>), Euler or RK4.'
    )
  if opt.solver not in set(mjx.SolverType):
    raise NotImplementedError(
        'MJX does not implement the constraint solver '
        f'{mujoco.mjtSolver(opt.solver).name}: set option.solver to Newton '
        '(mujoco.mjtSolver.mjSOL_NEWTON, MJCF <option solver="Newton"/>) or '
        'CG.'
    )
  supported = 0
  for bit in mjx.EnableBit:
    supported |= int(bit)
  unsupported = int(opt.enableflags) & ~supported
  if unsupported:
    names = _flag_names(mujoco.mjtEnableBit, unsupported)
    raise NotImplementedError(
        f'MJX does not implement the enable flags {names}: clear them '
        '(spec.option.enableflags &= ~flag, or remove '
        + ', '.join(_mjcf_flag(n) for n in names if n.startswith('mj'))
        + ' from the MJCF).'
    )


def ignored_options(mj_model: mujoco.MjModel) -> list[str]:
  """Descriptions of the options set in `mj_model` that MJX ignores."""
  opt = mj_model.opt
  default = _default_option()
  ignored = []
  if opt.noslip_iterations > 0:
    ignored.append(
        f'option.noslip_iterations={opt.noslip_iterations} (MJX has no noslip '
        'solver)'
    )
  for name, why in _IGNORED_NUMERIC:
    value, default_value = getattr(opt, name), getattr(default, name)
    if value != default_value:
      ignored.append(
          f'option.{name}={value} (MJX: {why}; default {default_value})'
      )
  if opt.disableactuator:
    ignored.append(
        f'option.disableactuator={opt.disableactuator} (MJCF '
        'actuatorgroupdisable: MJX applies every actuator group)'
    )
  supported = 0
  for bit in mjx.DisableBit:
    supported |= int(bit)
  for name in _flag_names(
      mujoco.mjtDisableBit, int(opt.disableflags) & ~supported
  ):
    bit = getattr(mujoco.mjtDisableBit, name, None)
    if bit is None or int(bit) not in _HARMLESS_DISABLE:
      ignored.append(f'disable flag {name} ({_mjcf_flag(name)})')
  for name in _flag_names(mujoco.mjtEnableBit, int(opt.enableflags)):
    bit = getattr(mujoco.mjtEnableBit, name, None)
    if bit is not None and int(bit) in _IGNORED_ENABLE:
      ignored.append(f'enable flag {name} ({_mjcf_flag(name)})')
  return ignored
