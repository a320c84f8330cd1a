"""benchmarks/profile_step.py: the environments its variants name."""

import argparse

import pytest

import profile_step  # benchmarks/profile_step.py

_FEATURES = 'only_noise+delay+history+randomize+groups'


def test_walk_takes_playground_compares_programs():
  envs = profile_step._make_envs('walk', [_FEATURES, 'only_push'])
  assert list(envs) == ['composed', _FEATURES, 'only_push']
  features, push = envs[_FEATURES], envs['only_push']
  # 'groups' observes the critic group too; the others only the policy's,
  # whose history makes it longer.
  features_spec, push_spec = (
      features.observation_spec(),
      push.observation_spec(),
  )
  assert set(features_spec) == {'policy', 'critic'}
  assert set(push_spec) == {'policy'}
  assert features_spec['policy'].shape[0] > push_spec['policy'].shape[0]
  # Randomization makes the geoms' masses and the motors' gears per-world;
  # without it no model field is.
  assert {'body_mass', 'actuator_gear'} <= set(features.per_world_model_fields)
  assert not push.per_world_model_fields
  assert features.auto_reset == push.auto_reset == 'same_step'


def test_unknown_variants_are_refused():
  with pytest.raises(argparse.ArgumentTypeError, match='unknown program'):
    profile_step._make_envs('walk', ['only_wings'])
  with pytest.raises(ValueError, match='Unknown variant'):
    profile_step._make_envs('reach', [_FEATURES])
