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


def test_unnamed_kernels_are_told_apart_by_kind(monkeypatch):
  # Kernels outside every named scope (a CUDA graph's copies, XLA's
  # loop plumbing) are counted by their names without numbers; the
  # others only by scope.
  op_names = {
      'loop_add_fusion.2': 'jit(rollout)/forward/add',
      'copy.3': 'jit(rollout)/copy',
  }
  process = lambda pid, name: {
      'ph': 'M',
      'name': 'process_name',
      'pid': pid,
      'args': {'name': name},
  }
  kernel = lambda name, op, dur: {
      'ph': 'X',
      'pid': 1,
      'name': name,
      'dur': dur,
      'args': {'hlo_op': op},
  }
  events = [process(1, '/device:GPU:0'), process(2, '/host:CPU')] + [
      kernel('memcpy32_post', 'command_buffer_1', 2.0),
      kernel('memcpy7_post', 'command_buffer_4', 3.0),
      kernel('memcpy7', 'command_buffer_4', 5.0),
      kernel('copy_3', 'copy.3', 7.0),
      kernel('loop_add_fusion_2', 'command_buffer_4', 11.0),
  ]
  # On the host's rows: not a kernel of the device.
  events.append({'ph': 'X', 'pid': 2, 'name': 'memcpy1', 'dur': 13.0})
  monkeypatch.setattr(profile_step.common, 'perfetto_events', lambda _: events)
  outer, _, _, (unnamed_us, unnamed) = profile_step._kernel_times(
      'trace', op_names
  )
  assert outer == {'(none)': 17.0, 'forward': 11.0}
  assert unnamed_us == {'memcpy#_post': 5.0, 'memcpy#': 5.0, 'copy_#': 7.0}
  assert unnamed == {'memcpy#_post': 2, 'memcpy#': 1, 'copy_#': 1}
