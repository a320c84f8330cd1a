"""Colour variations, specified per channel; values are always RGBA arrays.

Mirrors `dm_control.composer.variation.colors`. Each channel may be a constant
or a variation; the result has shape `channel_shape + (4,)` (channels
broadcast together), i.e. `(4,)` for scalar channels.

Deviation from composer: when the initial (or current) value is an RGBA
array (last axis of size 4, e.g. a geom's `rgba`), each channel variation
receives its own channel of it rather than the whole array: `r` gets
`initial[..., 0]`, etc.; for `HsvVariation` and `GrayVariation`, the
hue/saturation/value of the initial colour. So `RgbVariation(Uniform(), ...)`
bound to an `rgba` draws scalars, and relative variations such as
`HsvVariation(h=Additive(Normal(0, .05)), s=Identity(), v=Identity())`
perturb the existing colour. composer passes the whole RGBA array, which made
non-`single_sample` distributions draw 4 values per channel and fail. Values
without a last axis of size 4 are handed whole to every channel, as composer.
"""

import jax.numpy as jnp

from mjx_composer.variation import arrays as arrays_lib
from mjx_composer.variation import composite
from mjx_composer.variation import printing


def _stack_channels(channels):
  arrays = [jnp.asarray(c) for c in channels]
  dtype = arrays_lib.float_dtype(*arrays)
  return jnp.stack(
      jnp.broadcast_arrays(*[a.astype(dtype) for a in arrays]), axis=-1
  )


def _is_rgba(value):
  return value is not None and jnp.shape(value)[-1:] == (4,)


def _split_rgba(value):
  """Per-channel values of an RGBA array, or the value whole for each."""
  if not _is_rgba(value):
    return [value] * 4
  value = jnp.asarray(value)
  return [value[..., i] for i in range(4)]


def _hsv_to_rgb(h, s, v):
  """Vectorised `colorsys.hsv_to_rgb` (same sector rule: int() truncation)."""
  h, s, v = (jnp.asarray(x) for x in (h, s, v))
  dtype = arrays_lib.float_dtype(h, s, v)
  h, s, v = (x.astype(dtype) for x in (h, s, v))
  sector = jnp.trunc(h * 6.0)
  f = h * 6.0 - sector
  sector = jnp.mod(sector, 6).astype(jnp.int32)
  p = v * (1.0 - s)
  q = v * (1.0 - s * f)
  t = v * (1.0 - s * (1.0 - f))
  choose = lambda options: jnp.select([sector == i for i in range(6)], options)
  r = choose([v, q, p, p, t, v])
  g = choose([t, v, v, q, p, p])
  b = choose([p, p, t, v, v, q])
  gray = s == 0.0
  return tuple(jnp.where(gray, v, c) for c in (r, g, b))


def _rgb_to_hsv(r, g, b):
  """Vectorised `colorsys.rgb_to_hsv`."""
  max_c = jnp.maximum(jnp.maximum(r, g), b)
  min_c = jnp.minimum(jnp.minimum(r, g), b)
  delta = max_c - min_c
  gray = delta == 0
  safe_delta = jnp.where(gray, 1.0, delta)
  s = jnp.where(gray, 0.0, delta / jnp.where(max_c == 0, 1.0, max_c))
  rc, gc, bc = ((max_c - c) / safe_delta for c in (r, g, b))
  h = jnp.where(
      r == max_c, bc - gc, jnp.where(g == max_c, 2.0 + rc - bc, 4.0 + gc - rc)
  )
  h = jnp.where(gray, 0.0, jnp.mod(h / 6.0, 1.0))
  return h, s, max_c


class RgbVariation(composite.CompositeVariation):
  """A colour given by independent R, G, B and alpha channels in [0, 1]."""

  def __init__(self, r, g, b, alpha=1.0):
    """Initializes an `RgbVariation`.

    Args:
      r: red channel: constant or variation.
      g: green channel: constant or variation.
      b: blue channel: constant or variation.
      alpha: opacity: constant or variation.
    """
    self._r, self._g, self._b, self._alpha = r, g, b, alpha
    self._operands = (r, g, b, alpha)

  def _operand_inputs(self, initial_value, current_value):
    return list(zip(_split_rgba(initial_value), _split_rgba(current_value)))

  def _apply(self, values, key, initial_value, current_value):
    return _stack_channels(values)

  def _eq_fields(self):
    return self._operands

  def __repr__(self):
    return printing.format_call(
        type(self).__name__, r=self._r, g=self._g, b=self._b, alpha=self._alpha
    )


class HsvVariation(composite.CompositeVariation):
  """A colour given by hue, saturation, value and alpha channels in [0, 1].

  Converted with the rule of `colorsys.hsv_to_rgb` (hue wraps modulo 1).
  """

  def __init__(self, h, s, v, alpha=1.0):
    """Initializes an `HsvVariation`.

    Args:
      h: hue: constant or variation.
      s: saturation: constant or variation.
      v: value (brightness): constant or variation.
      alpha: opacity: constant or variation.
    """
    self._h, self._s, self._v, self._alpha = h, s, v, alpha
    self._operands = (h, s, v, alpha)

  def _operand_inputs(self, initial_value, current_value):
    def channels(value):
      if not _is_rgba(value):
        return [value] * 4
      r, g, b, alpha = _split_rgba(value)
      return list(_rgb_to_hsv(r, g, b)) + [alpha]

    return list(zip(channels(initial_value), channels(current_value)))

  def _apply(self, values, key, initial_value, current_value):
    h, s, v, alpha = values
    return _stack_channels(list(_hsv_to_rgb(h, s, v)) + [alpha])

  def _eq_fields(self):
    return self._operands

  def __repr__(self):
    return printing.format_call(
        type(self).__name__, h=self._h, s=self._s, v=self._v, alpha=self._alpha
    )


class GrayVariation(HsvVariation):
  """A gray colour: `HsvVariation(0, 0, gray_level, alpha)`."""

  def __init__(self, gray_level, alpha=1.0):
    """Initializes a `GrayVariation`.

    Args:
      gray_level: brightness in [0, 1]: constant or variation.
      alpha: opacity: constant or variation.
    """
    super().__init__(h=0.0, s=0.0, v=gray_level, alpha=alpha)

  def __repr__(self):
    return printing.format_call(
        type(self).__name__, gray_level=self._v, alpha=self._alpha
    )
