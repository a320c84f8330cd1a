"""Tests for mjx_composer.variation.colors, against Python's `colorsys`."""

import colorsys

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer.variation import colors
from mjx_composer.variation import deterministic
from mjx_composer.variation import distributions
from mjx_composer.variation import noises

KEY = jax.random.key(0)


def test_rgb_variation():
  np.testing.assert_allclose(
      colors.RgbVariation(0.1, 0.2, 0.3)(), [0.1, 0.2, 0.3, 1.0]
  )
  np.testing.assert_allclose(
      colors.RgbVariation(0.1, 0.2, 0.3, 0.5)(), [0.1, 0.2, 0.3, 0.5]
  )
  random = colors.RgbVariation(
      distributions.Uniform(),
      distributions.Uniform(0.5, 1.0),
      0.0,
      distributions.Uniform(),
  )
  # Bound to an rgba attribute: each channel draws a scalar.
  value = random(jnp.ones(4), None, KEY)
  assert value.shape == (4,)
  assert 0 <= value[0] < 1 and 0.5 <= value[1] < 1 and value[2] == 0
  assert value[0] != value[3]  # Channels get independent subkeys.


def test_rgb_channels_receive_their_channel_of_the_value():
  initial = jnp.asarray([0.1, 0.2, 0.3, 0.4])
  current = jnp.asarray([0.5, 0.6, 0.7, 0.8])
  identity = deterministic.Identity()
  np.testing.assert_allclose(
      colors.RgbVariation(identity, identity, identity, identity)(
          initial, current
      ),
      current,
  )
  brighter_red = colors.RgbVariation(noises.Additive(0.5), 0.0, 0.0)
  np.testing.assert_allclose(
      brighter_red(initial), [0.6, 0.0, 0.0, 1.0], rtol=1e-6
  )


def test_batched_channels_stack_on_the_last_axis():
  value = colors.RgbVariation(jnp.asarray([0.1, 0.2]), 0.5, 0.5)()
  np.testing.assert_allclose(
      value, [[0.1, 0.5, 0.5, 1.0], [0.2, 0.5, 0.5, 1.0]]
  )


def test_hsv_variation_matches_colorsys():
  rng = np.random.default_rng(0)
  h, s, v = rng.uniform(size=(3, 200))
  s[:10] = 0.0  # Gray.
  h[10:20] = 1.0  # Hue wraps.
  alpha = rng.uniform(size=200)
  actual = np.asarray(colors.HsvVariation(h, s, v, alpha)())
  expected = np.array(
      [
          list(colorsys.hsv_to_rgb(*hsv)) + [a]
          for hsv, a in zip(zip(h, s, v), alpha)
      ]
  )
  np.testing.assert_allclose(actual, expected, atol=1e-6)


def test_hsv_channels_receive_hsv_of_the_value():
  rgba = jnp.asarray([0.8, 0.3, 0.1, 0.6])
  identity = deterministic.Identity()
  round_trip = colors.HsvVariation(identity, identity, identity, identity)(
      None, rgba
  )
  np.testing.assert_allclose(round_trip, rgba, atol=1e-6)
  # Only the hue is kept; saturation and value are set to 1.
  hue_only = colors.HsvVariation(identity, 1.0, 1.0)(None, rgba)
  expected_h = colorsys.rgb_to_hsv(0.8, 0.3, 0.1)[0]
  np.testing.assert_allclose(
      hue_only[:3], colorsys.hsv_to_rgb(expected_h, 1.0, 1.0), atol=1e-6
  )


def test_gray_variation():
  np.testing.assert_allclose(colors.GrayVariation(0.3)(), [0.3, 0.3, 0.3, 1.0])
  np.testing.assert_allclose(
      colors.GrayVariation(0.3, alpha=0.5)(), [0.3, 0.3, 0.3, 0.5]
  )
  value = colors.GrayVariation(distributions.Uniform())(jnp.ones(4), None, KEY)
  assert (
      value.shape == (4,)
      and value[0] == value[1] == value[2]
      and value[3] == 1.0
  )
  assert (
      repr(colors.GrayVariation(0.3))
      == "GrayVariation(gray_level=0.3, alpha=1.0)"
  )
  assert colors.GrayVariation(0.3) == colors.GrayVariation(0.3)
  assert colors.GrayVariation(0.3) != colors.GrayVariation(0.4)
