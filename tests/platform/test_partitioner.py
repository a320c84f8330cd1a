"""`mjx_composer.platform.partitioner`: GSPMD for programs over several GPUs."""

import jax
import pytest

from mjx_composer.platform import internals_jax
from mjx_composer.platform import partitioner


class _FakeDevice:

  def __init__(self, platform):
    self.platform = platform


def _shardy_on():
  return jax.config.jax_use_shardy_partitioner


@pytest.fixture(autouse=True)
def _unset(monkeypatch):
  monkeypatch.delenv(partitioner.PARTITIONER_ENV, raising=False)


def test_several_gpus_get_gspmd_and_everything_else_shardy():
  gpu, cpu = _FakeDevice('gpu'), jax.devices('cpu')[0]
  assert partitioner.name_for([gpu, gpu]) == 'gspmd'
  assert partitioner.name_for([gpu]) == 'shardy'
  assert partitioner.name_for([cpu, cpu]) == 'shardy'
  assert partitioner.name_for([cpu]) == 'shardy'


def test_the_environment_variable_overrides_the_choice(monkeypatch):
  gpu, cpu = _FakeDevice('gpu'), jax.devices('cpu')[0]
  monkeypatch.setenv(partitioner.PARTITIONER_ENV, 'shardy')
  assert partitioner.name_for([gpu, gpu]) == 'shardy'
  monkeypatch.setenv(partitioner.PARTITIONER_ENV, ' GSPMD ')
  assert partitioner.name_for([cpu]) == 'gspmd'
  monkeypatch.setenv(partitioner.PARTITIONER_ENV, 'auto')
  assert partitioner.name_for([gpu, gpu]) == 'gspmd'


def test_an_unknown_partitioner_says_what_to_set(monkeypatch):
  monkeypatch.setenv(partitioner.PARTITIONER_ENV, 'xla')
  with pytest.raises(ValueError, match='one of auto, shardy, gspmd, or unset'):
    partitioner.name_for([jax.devices()[0]])


def test_the_scope_sets_jax_partitioner_and_restores_it():
  assert _shardy_on()
  with partitioner.scope([_FakeDevice('gpu')] * 2) as name:
    assert name == 'gspmd'
    assert not _shardy_on()
  assert _shardy_on()
  with partitioner.scope(jax.devices()) as name:
    assert name == 'shardy'
    assert _shardy_on()


def test_a_jax_without_gspmd_keeps_shardy(monkeypatch):
  monkeypatch.setattr(internals_jax, 'shardy_partitioner_state', lambda: None)
  with partitioner.scope([_FakeDevice('gpu')] * 2) as name:
    assert name == 'shardy'
    assert _shardy_on()
