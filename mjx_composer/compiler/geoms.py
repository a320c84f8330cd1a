"""Geom quantities that MuJoCo's compiler derives from a geom's size.

Ports of `mjCGeom::GetVolume`, `mjCGeom::SetInertia` (mass from density,
principal inertia) and `mjCGeom::ComputeAABB` for primitive geoms, and the
bounding sphere radius. Geom types are static, so a geom's type picks its
formula on the host; the mass and inertia formulas take arrays of sizes, so
that one call covers every geom of a type.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import mujoco
import numpy as np

from mjx_composer.compiler import frames

_Geom = mujoco.mjtGeom
# Geoms whose size, inertia and frame come from an asset.
MESHLIKE = (_Geom.mjGEOM_MESH, _Geom.mjGEOM_SDF, _Geom.mjGEOM_HFIELD)


def volume(gtype, shell, size):
  """Volumes of primitive geoms of one type; `size` is `(..., 3)`."""
  s0, s1, s2 = size[..., 0], size[..., 1], size[..., 2]
  if gtype == _Geom.mjGEOM_SPHERE:
    return 4 * math.pi * s0**2 if shell else 4 * math.pi * s0**3 / 3
  if gtype == _Geom.mjGEOM_CAPSULE:
    height = 2 * s1
    if shell:
      return 4 * math.pi * s0 * s0 + 2 * math.pi * s0 * height
    return math.pi * (s0 * s0 * height + 4 * s0**3 / 3)
  if gtype == _Geom.mjGEOM_CYLINDER:
    height = 2 * s1
    if shell:
      return 2 * math.pi * s0 * s0 + 2 * math.pi * s0 * height
    return math.pi * s0 * s0 * height
  if gtype == _Geom.mjGEOM_ELLIPSOID:
    if shell:
      p = 1.6075
      tmp = (s0 * s1) ** p + (s1 * s2) ** p + (s2 * s0) ** p
      return 4 * math.pi * (tmp / 3) ** (1 / p)
    return 4 * math.pi * s0 * s1 * s2 / 3
  if gtype == _Geom.mjGEOM_BOX:
    if shell:
      return 8 * (s0 * s1 + s1 * s2 + s2 * s0)
    return s0 * s1 * s2 * 8
  return jnp.zeros_like(s0)


def principal_inertia(gtype, shell, size, mass):
  """Principal inertias (geom frames) of primitive geoms of one type.

  `size` is `(..., 3)` and `mass` `(...)`; returns `(..., 3)`.
  """
  s0, s1, s2 = size[..., 0], size[..., 1], size[..., 2]
  stack = lambda *columns: jnp.stack(columns, axis=-1)
  if gtype == _Geom.mjGEOM_SPHERE:
    i = (2 / 3 if shell else 2 / 5) * mass * s0**2
    return stack(i, i, i)
  if gtype == _Geom.mjGEOM_CAPSULE:
    r, half = s0, s1
    height = 2 * half
    if not shell:
      sphere_mass = mass * 4 * r / (4 * r + 3 * height)
      cyl_mass = mass - sphere_mass
      ixy = cyl_mass * (3 * r * r + height * height) / 12
      iz = cyl_mass * r * r / 2
      sphere_i = 2 * sphere_mass * r * r / 5
      ixy = ixy + sphere_i + sphere_mass * height * (3 * r + 2 * height) / 8
      return stack(ixy, ixy, iz + sphere_i)
    a_sphere = 4 * math.pi * r * r
    a_cyl = 2 * math.pi * r * height
    sphere_mass = mass * a_sphere / (a_sphere + a_cyl)
    cyl_mass = mass - sphere_mass
    ixy = cyl_mass * (6 * r * r + height * height) / 12
    iz = cyl_mass * r * r
    sphere_i = 2 * sphere_mass * r * r / 3
    hs_com = r / 2
    hs_pos = half + hs_com
    ixy = ixy + sphere_i + sphere_mass * (hs_pos * hs_pos - hs_com * hs_com)
    return stack(ixy, ixy, iz + sphere_i)
  if gtype == _Geom.mjGEOM_CYLINDER:
    r, half = s0, s1
    height = 2 * half
    if not shell:
      ixy = mass * (3 * r * r + height * height) / 12
      return stack(ixy, ixy, mass * r * r / 2)
    a_disk = math.pi * r * r
    a_cyl = 2 * math.pi * r * height
    mass_disk = mass * a_disk / (2 * a_disk + a_cyl)
    mass_cyl = mass - 2 * mass_disk
    ixy = mass_cyl * (6 * r * r + height * height) / 12
    iz = mass_cyl * r * r
    disk_x = mass_disk * r * r / 4 + mass_disk * half * half
    disk_z = mass_disk * r * r / 2
    return stack(ixy + 2 * disk_x, ixy + 2 * disk_x, iz + 2 * disk_z)
  if gtype == _Geom.mjGEOM_ELLIPSOID:
    s00, s11, s22 = s0**2, s1**2, s2**2
    if not shell:
      return _solid_inertia(mass, s00, s11, s22, 5)
    eps = 1e-6
    va = 4 * math.pi * s0 * s1 * s2 / 3
    ae, be, ce = s0 + eps, s1 + eps, s2 + eps
    vb = 4 * math.pi * ae * be * ce / 3
    density = mass / (vb - va)
    ma, mb = va * density, vb * density
    ia = stack(ma * (s11 + s22), ma * (s00 + s22), ma * (s00 + s11)) / 5
    ib = (
        stack(
            mb * (be * be + ce * ce),
            mb * (ae * ae + ce * ce),
            mb * (ae * ae + be * be),
        )
        / 5
    )
    return ib - ia
  if gtype == _Geom.mjGEOM_BOX:
    s00, s11, s22 = s0**2, s1**2, s2**2
    if not shell:
      return _solid_inertia(mass, s00, s11, s22, 3)
    lx, ly, lz = 2 * s0, 2 * s1, 2 * s2
    a0, a1, a2 = lx * ly, ly * lz, lz * lx
    total = 2 * (a0 + a1 + a2)
    m0, m1, m2 = mass * a0 / total, mass * a1 / total, mass * a2 / total
    ix = 2 * (
        m0 * s22
        + m2 * s11
        + m0 * ly * ly / 12
        + m1 * (ly * ly + lz * lz) / 12
        + m2 * lz * lz / 12
    )
    iy = 2 * (
        m0 * s22
        + m1 * s00
        + m0 * lx * lx / 12
        + m1 * lz * lz / 12
        + m2 * (lx * lx + lz * lz) / 12
    )
    iz = 2 * (
        m1 * s00
        + m2 * s11
        + m0 * (lx * lx + ly * ly) / 12
        + m1 * ly * ly / 12
        + m2 * lx * lx / 12
    )
    return stack(ix, iy, iz)
  return jnp.zeros_like(size)


def _solid_inertia(mass, s00, s11, s22, divisor):
  """Solid ellipsoid (`divisor` 5) or box (3) of squared half-sizes `sii`."""
  return jnp.stack(
      [
          mass * (s11 + s22) / divisor,
          mass * (s00 + s22) / divisor,
          mass * (s00 + s11) / divisor,
      ],
      axis=-1,
  )


def mass_and_inertia(gtype, shell, size, given, mass, density):
  """`(mass, inertia)` of geoms of one type as mjCGeom::Compile infers them.

  Args:
    gtype, shell: the geoms' type and whether their inertia is a shell's.
    size: `(k, 3)` compiled sizes.
    given: `(k,)` static bools, whether the geom's mass is defined (bound or
      set in the spec); where not, its density decides.
    mass, density: `(k,)` masses (read where `given`) and densities.
  """
  vol = volume(gtype, shell, size)
  ok = jnp.where(given, (mass != 0) & (vol > frames.EPS), density != 0)
  mass_ = jnp.where(ok, jnp.where(given, mass, density * vol), 0.0)
  inertia = jnp.where(
      ok[..., None], principal_inertia(gtype, shell, size, mass_), 0.0
  )
  return mass_, inertia


def rbound(gtype, size):
  if gtype == _Geom.mjGEOM_SPHERE:
    return size[0]
  if gtype == _Geom.mjGEOM_CAPSULE:
    return size[0] + size[1]
  if gtype == _Geom.mjGEOM_CYLINDER:
    return jnp.sqrt(size[0] ** 2 + size[1] ** 2)
  if gtype == _Geom.mjGEOM_ELLIPSOID:
    return jnp.max(size)
  if gtype == _Geom.mjGEOM_BOX:
    return jnp.sqrt(jnp.sum(size * size))
  return jnp.zeros((), size.dtype)


def aabb(gtype, size):
  """(center, half-size) as mjCGeom::ComputeAABB, for primitive geoms."""
  zero = jnp.zeros((), size.dtype)
  if gtype == _Geom.mjGEOM_SPHERE:
    half = jnp.stack([size[0]] * 3)
  elif gtype == _Geom.mjGEOM_CAPSULE:
    half = jnp.stack([size[0], size[0], size[0] + size[1]])
  elif gtype == _Geom.mjGEOM_CYLINDER:
    half = jnp.stack([size[0], size[0], size[1]])
  elif gtype == _Geom.mjGEOM_PLANE:
    return jnp.asarray(
        [
            0,
            0,
            -frames.MAXVAL / 2,
            frames.MAXVAL,
            frames.MAXVAL,
            frames.MAXVAL / 2,
        ],
        size.dtype,
    )
  else:
    half = size
  return jnp.concatenate([jnp.stack([zero, zero, zero]), half])


def compiled_size(m, g: int, geom, size):
  """A geom's compiled size: `fromto` fixes the length (and box y)."""
  if np.isnan(geom.fromto[0]):
    return size
  boxlike = geom.type in (_Geom.mjGEOM_BOX, _Geom.mjGEOM_ELLIPSOID)
  length = float(m.geom_size[g, 2 if boxlike else 1])
  if boxlike:
    return jnp.stack([size[0], size[0], jnp.asarray(length, size.dtype)])
  return size.at[1].set(length)
