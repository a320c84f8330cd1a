"""benchmarks/playground_compare.py: program names, envs, ratios, and one
tiny measurement in a fresh process (raw MJX, one world, on the CPU)."""

import argparse
import json

import pytest

import playground_compare  # benchmarks/playground_compare.py


def test_ours_programs_take_the_shared_suffix():
  for name in (
      'ours_on',
      'ours_on_shared',
      'ours_off_shared',
      'only_noise+randomize_shared',
      'ours_on_chunk512',
      'only_noise+randomize+groups_chunk64',
      'ours_off_chunk8_all_sensors',
      'ours_off_all_sensors',
      'only_noise+randomize_all_sensors_shared',
      'playground',
      'playground_trained',
  ):
    assert playground_compare.program_name(name) == name
  for name, message in (
      ('playground_shared', 'unknown program'),
      ('playground_trained_shared', 'unknown program'),
      ('raw_shared', 'unknown program'),
      ('raw_all_sensors', 'unknown program'),
      ('ours_on_chunk512_shared', 'separate restart'),
      ('ours_off_shared_chunk8', 'separate restart'),
      ('ours_on_chunk0', 'unknown program'),
      ('only_wings_shared', 'unknown program'),
  ):
    with pytest.raises(argparse.ArgumentTypeError, match=message):
      playground_compare.program_name(name)


def test_suffixes_are_environment_arguments():
  assert playground_compare.split_suffixes(
      'only_noise+groups_chunk64_all_sensors'
  ) == ('only_noise+groups', dict(auto_reset_batch=64, substep_sensors='all'))
  assert playground_compare.split_suffixes('ours_on_shared') == (
      'ours_on',
      dict(share_reset_forward=True),
  )
  assert playground_compare.split_suffixes('ours_on_chunkall') == (
      'ours_on',
      dict(auto_reset_batch=None),
  )
  assert playground_compare.split_suffixes('ours_on_shared_cond') == (
      'ours_on',
      dict(share_reset_forward=True, branches='cond'),
  )


def test_a_shared_program_fuses_the_restart_whatever_the_default():
  envs = playground_compare.env_variants(
      ['ours_off', 'ours_off_shared'], share_reset_forward=False
  )
  assert not envs['ours_off'].share_reset_forward
  assert envs['ours_off_shared'].share_reset_forward
  assert envs['ours_off_shared'].task is not envs['ours_off'].task


def test_an_all_sensors_program_computes_them_at_every_substep():
  envs = playground_compare.env_variants(
      ['ours_off', 'ours_off_all_sensors'], share_reset_forward=False
  )
  assert envs['ours_off'].sensors_once_per_step
  assert not envs['ours_off_all_sensors'].sensors_once_per_step
  assert not envs['ours_off_all_sensors'].share_reset_forward


def test_ratios_divide_ours_by_each_reference_present():
  row = {
      'worlds': 4,
      'ours_off': {'control_steps_per_s': 300.0},
      'raw': {'control_steps_per_s': 200.0},
      'playground': {'control_steps_per_s': 250.0},
  }
  playground_compare._ratios(row, ['ours_off', 'ours_on'])
  assert row['ours_off/raw'] == pytest.approx(1.5)
  assert row['ours_off/playground'] == pytest.approx(1.2)
  assert 'ours_off/playground_trained' not in row
  assert not any(k.startswith('ours_on/') for k in row)


def _isolated_args(out, worlds, processes=1):
  """`--isolated` arguments: `worlds`, one step, one repeat."""
  return argparse.Namespace(
      worlds=worlds,
      steps=1,
      repeats=1,
      share_reset_forward=None,
      out=str(out),
      processes=processes,
  )


def test_isolated_measures_each_program_in_its_own_process(tmp_path):
  out = tmp_path / 'isolated.json'
  playground_compare._main_isolated(_isolated_args(out, [1]), ['raw'])
  with open(out) as f:
    payload = json.load(f)
  assert payload['isolated']
  assert payload['task'] == 'walk' and payload['sub_steps'] == 5
  (row,) = payload['results']
  assert row['worlds'] == 1
  assert row['raw']['control_steps_per_s'] > 0
  assert row['raw']['first_call_s'] >= row['raw']['rollout_compile_s'] > 0


def test_processes_take_turns_and_record_medians(tmp_path, monkeypatch):
  # Two programs in three processes each: the programs alternate, each
  # figure is the median of its processes, the first calls' samples are
  # kept, and the first calls' ratio divides the medians.
  order = []
  first_calls = {
      'playground': [10.0, 30.0, 20.0],
      'ours_off': [40.0, 20.0, 30.0],
  }

  def fake_row(args, worlds, name):
    del args
    i = sum(1 for n in order if n == name)
    order.append(name)
    row = {
        'control_steps_per_s': 100.0 * (i + 1),
        'reset_compile_s': 5.0,
        'rollout_compile_s': first_calls[name][i] - 1.0,
        'first_call_s': first_calls[name][i],
        'stored_restart': False,
    }
    return row, {'device': 'cpu', 'worlds': worlds, 'results': [{}]}

  monkeypatch.setattr(playground_compare, '_isolated_row', fake_row)
  out = tmp_path / 'processes.json'
  playground_compare._main_isolated(
      _isolated_args(out, [2], processes=3), ['playground', 'ours_off']
  )
  assert order == ['playground', 'ours_off'] * 3
  with open(out) as f:
    payload = json.load(f)
  assert payload['processes'] == 3
  (row,) = payload['results']
  ours, reference = row['ours_off'], row['playground']
  assert ours['processes'] == 3
  assert ours['control_steps_per_s'] == pytest.approx(200.0)
  assert ours['first_call_s'] == pytest.approx(30.0)
  assert ours['samples']['first_call_s'] == [40.0, 20.0, 30.0]
  assert ours['samples']['first_calls_s'] == [45.0, 25.0, 35.0]
  assert ours['stored_restart'] is False
  assert reference['first_calls_s'] == pytest.approx(25.0)
  assert row['ours_off/playground first calls'] == pytest.approx(35.0 / 25.0)
  assert row['ours_off/playground'] == pytest.approx(1.0)
