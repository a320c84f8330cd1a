"""`prng_lowering.enable()`: JAX's threefry GPU kernel, and how to say no."""

import jax
import pytest

from mjx_composer.platform import prng_lowering


@pytest.fixture(autouse=True)
def _restore_flag(monkeypatch):
  before = getattr(jax.config, prng_lowering.FLAG)
  monkeypatch.delenv(prng_lowering.SWITCH_ENV, raising=False)
  monkeypatch.delenv(prng_lowering.FLAG.upper(), raising=False)
  yield
  jax.config.update(prng_lowering.FLAG, before)


def test_enable_turns_the_kernel_lowering_on():
  jax.config.update(prng_lowering.FLAG, False)
  assert prng_lowering.enable() is True
  assert getattr(jax.config, prng_lowering.FLAG) is True


@pytest.mark.parametrize('value', ['0', 'false', 'OFF', 'no'])
def test_environment_switch_turns_it_off(monkeypatch, value):
  jax.config.update(prng_lowering.FLAG, True)
  monkeypatch.setenv(prng_lowering.SWITCH_ENV, value)
  assert prng_lowering.enable() is False
  assert getattr(jax.config, prng_lowering.FLAG) is False


def test_argument_decides_over_the_environment(monkeypatch):
  monkeypatch.setenv(prng_lowering.SWITCH_ENV, '0')
  assert prng_lowering.enable(enabled=True) is True
  assert getattr(jax.config, prng_lowering.FLAG) is True


def test_jax_own_setting_wins(monkeypatch):
  jax.config.update(prng_lowering.FLAG, False)
  monkeypatch.setenv(prng_lowering.FLAG.upper(), '0')
  assert prng_lowering.enable(enabled=True) is False
  assert getattr(jax.config, prng_lowering.FLAG) is False
