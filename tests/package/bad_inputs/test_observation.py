"""Observation groups refuse what would be read as something else."""

import pytest

import mjx_composer as composer


@pytest.mark.parametrize('keys', ['tip', b'tip'])
def test_observation_group_refuses_one_string_of_keys(keys):
  """A string is a sequence of one-letter keys: 't', 'i', 'p'."""
  with pytest.raises(
      TypeError,
      match=r"`keys` must be a sequence of observable keys.*'tip'.*would "
      r'read as the keys.*Pass keys=\[',
  ):
    composer.ObservationGroup(keys=keys)


def test_observation_group_keeps_a_sequence_of_keys():
  assert composer.ObservationGroup(keys=['tip']).keys == ['tip']
  assert composer.ObservationGroup(keys=('tip', 'base')).keys == ('tip', 'base')
  assert composer.ObservationGroup().keys is None
