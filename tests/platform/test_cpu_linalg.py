"""`cpu_linalg.enable()`: XLA's Cholesky on the CPU, and how to say no."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_composer.platform import cpu_linalg


def _factor(a):
  return jnp.linalg.cholesky(a)  # lower: a = L L^T


@pytest.fixture(name='restore')
def _restore():
  yield
  cpu_linalg.enable()  # as tests/conftest.py leaves it


def test_the_factor_is_lapacks_without_a_lapack_call(restore):
  del restore
  rng = np.random.default_rng(0)
  a = rng.normal(size=(16, 27, 27))
  a = jnp.asarray(a @ np.swapaxes(a, -1, -2) + 27 * np.eye(27), jnp.float32)
  assert cpu_linalg.enable(enabled=False) is False
  program = jax.jit(jax.vmap(_factor))
  assert 'lapack_spotrf' in program.lower(a).as_text()
  lapack = np.asarray(program(a))
  assert cpu_linalg.enable(enabled=True) is True
  program = jax.jit(jax.vmap(_factor))  # lowered again: a new function
  assert 'lapack' not in program.lower(a).as_text()
  xla = np.asarray(program(a))
  np.testing.assert_allclose(xla, lapack, rtol=0, atol=2e-6 * abs(lapack).max())
  np.testing.assert_allclose(
      np.einsum('bij,bkj->bik', xla, xla), a, rtol=0, atol=1e-4 * 27
  )
  # Not positive definite: NaN, as LAPACK's lowering gives.
  factor = np.asarray(jax.jit(lambda x: _factor(x))(-jnp.eye(3)))
  assert np.isnan(factor[np.tril_indices(3)]).all()


def test_the_environment_switches_it_off(monkeypatch, restore):
  del restore
  monkeypatch.setenv(cpu_linalg.SWITCH_ENV, 'off')
  assert cpu_linalg.enable() is False
  a = jnp.eye(3)
  # A new function: JAX caches lowered programs per function.
  assert 'lapack_spotrf' in jax.jit(lambda x: _factor(x)).lower(a).as_text()
  monkeypatch.setenv(cpu_linalg.SWITCH_ENV, '1')
  assert cpu_linalg.enable() is True
