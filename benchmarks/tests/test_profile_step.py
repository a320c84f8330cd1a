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


def test_kernels_in_cuda_graphs_are_found_by_their_names():
  op_names = {
      'loop_add_fusion.2': 'jit(rollout)/forward/add',
      'loop_add_fusion': 'jit(rollout)/end_step/add',
      'copy.3': 'jit(rollout)/copy',
  }
  kernel = lambda name, op: {'name': name, 'args': {'hlo_op': op}}
  instruction = lambda e: profile_step._instruction(e, op_names)
  # A kernel launched by itself names its instruction.
  assert instruction(kernel('copy_3', 'copy.3')) == 'copy.3'
  # In a CUDA graph it names the command buffer; its kernel's name is the
  # instruction's, with its number after '_'.
  assert instruction(kernel('loop_add_fusion_2', 'command_buffer_12')) == (
      'loop_add_fusion.2'
  )
  assert instruction(kernel('loop_add_fusion', 'command_buffer_12')) == (
      'loop_add_fusion'
  )
  # A copy the graph adds names no instruction: it keeps the buffer's name.
  assert instruction(kernel('memcpy32_post', 'command_buffer_1')) == (
      'command_buffer_1'
  )
  assert instruction({'name': 'memset', 'args': {}}) is None
  assert profile_step._scope(op_names['loop_add_fusion.2'])[0] == 'forward'
