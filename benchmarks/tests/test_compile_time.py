"""benchmarks/compile_time.py without compiling its programs: tasks, programs,
ratios, and the XLA timers it reads."""

import argparse
import json
import os
import subprocess
import sys

import jax
import pytest

import compile_time  # benchmarks/compile_time.py


def test_tasks_are_bundled_tasks_or_walk_variants():
  for name in (
      'reach',
      'push',
      'walk',
      'joystick',
      'walk:ours_off',
      'reach:fixed',
      'push:fixed',
  ):
    assert compile_time.task_name(name) == name
  assert (
      compile_time.task_name('walk:only_push+noise') == 'walk:only_push+noise'
  )
  for name, message in (
      ('run', 'unknown task'),
      ('reach:ours_off', 'unknown task'),
      ('walk:fixed', 'unknown'),  # walk's variants name their features
      ('walk:playground', 'unknown task'),  # not ours: nothing to compile
      ('walk:only_wind', "unknown program 'only_wind'"),
  ):
    with pytest.raises(argparse.ArgumentTypeError, match=message):
      compile_time.task_name(name)


def test_a_variants_raw_programs_are_measured_once_under_its_base_task():
  programs = ['raw_step', 'step']
  assert compile_time.measured_programs(
      ['walk', 'walk:ours_off', 'reach'], programs
  ) == [
      ('walk', 'raw_step'),
      ('walk', 'step'),
      ('walk:ours_off', 'step'),
      ('reach', 'raw_step'),
      ('reach', 'step'),
  ]
  # Without its base task, a variant measures its own raw programs.
  assert compile_time.measured_programs(['walk:ours_off'], programs) == [
      ('walk:ours_off', 'raw_step'),
      ('walk:ours_off', 'step'),
  ]


def test_a_variant_is_divided_by_its_base_tasks_raw_program():
  def row(task, program, total_s, hlo):
    return {
        'task': task,
        'program': program,
        'total_s': total_s,
        'hlo_instructions': hlo,
    }

  rows = [
      row('walk', 'raw_step', 10.0, 1000),
      row('walk', 'step', 20.0, 2000),
      row('walk:ours_off', 'step', 11.0, 1100),
  ]
  ratios = {r['task']: r for r in compile_time.ratios(rows)}
  assert ratios['walk']['total_s'] == pytest.approx(2.0)
  assert ratios['walk:ours_off']['total_s'] == pytest.approx(1.1)
  assert ratios['walk:ours_off']['hlo_instructions'] == pytest.approx(1.1)
  assert ratios['walk:ours_off']['program'] == 'step'


@pytest.mark.parametrize('task', ['reach', 'walk:ours_off'])
def test_share_reset_forward_reaches_the_environment(task):
  """`--share-reset-forward` builds the measured env with that setting."""
  default = compile_time.make_task_env(task).share_reset_forward
  for share in (True, False):
    env = compile_time.make_task_env(task, share_reset_forward=share)
    assert env.share_reset_forward is share
  # On a CPU (where the tests run) the default shares the forward pass.
  assert default is True


@pytest.mark.parametrize('task', ['reach', 'walk:ours_off'])
def test_branches_reach_the_environment(task):
  """`--branches` builds the measured env with that setting."""
  assert compile_time.make_task_env(task).branches == 'cond'  # a CPU's
  assert compile_time.make_task_env(task, branches='loop').branches == 'loop'


@pytest.mark.parametrize('task', ['reach', 'walk:ours_off'])
def test_reset_forward_reaches_the_environment(task):
  """`--reset-forward` builds the measured env with that setting."""
  assert (
      compile_time.make_task_env(task, reset_forward='full').reset_forward_stage
      == 'full'
  )
  observed = compile_time.make_task_env(task, reset_forward='observed')
  default = compile_time.make_task_env(task)
  assert observed.reset_forward_stage == default.reset_forward_stage
  if task == 'reach':  # its observables need positions and velocities
    assert observed.reset_forward_stage == 'velocity'


def test_scope_counts_attribute_every_equation_to_its_named_scopes():
  import jax  # pylint: disable=g-import-not-at-top
  import jax.numpy as jnp  # pylint: disable=g-import-not-at-top

  def f(x):
    with jax.named_scope('outer'):
      y = jnp.sin(x)

      def body(carry, _):
        with jax.named_scope('inner'):
          return carry * 2.0 + 1.0, None

      y, _ = jax.lax.scan(body, y, None, length=3)
    return y + 1.0

  jaxpr = jax.make_jaxpr(f)(jnp.ones(2))
  eqns = list(compile_time._flat_eqns(jaxpr.jaxpr))
  counts = compile_time.scope_counts(eqns)
  assert sum(counts.values()) == len(eqns)
  # The scan's body is counted once, under both scopes, not under 'scan'.
  assert counts['outer/inner'] == 2  # mul, add
  assert counts['outer'] == 2  # sin, the scan itself
  assert counts[''] == 1  # the final add
  assert list(counts.values()) == sorted(counts.values(), reverse=True)
  assert compile_time.scope_counts(eqns, depth=1)['outer'] == 4


def test_a_fixed_task_has_no_per_episode_randomization():
  """`reach:fixed` is the same model with no per-world model fields."""
  randomized = compile_time.make_task_env('reach')
  fixed = compile_time.make_task_env('reach:fixed')
  key = jax.random.key(0)
  assert 'body_mass' in jax.eval_shape(randomized.reset, key).model_fields
  assert not jax.eval_shape(fixed.reset, key).model_fields
  assert fixed.mj_model.nbody == randomized.mj_model.nbody


def test_the_record_is_written_after_every_program(tmp_path, monkeypatch):
  out = tmp_path / 'record.json'
  seen = []

  def fake_run(task, program, *args, **kwargs):
    del args, kwargs
    if program == 'reset':
      return None  # a failed worker
    if program == 'raw_reset':  # the run is stopped before its last program
      seen.append(json.loads(out.read_text()))
      raise KeyboardInterrupt
    return {
        'task': task, 'program': program, 'device': 'cpu', 'platform': 'cpu',
        'jax': jax.__version__, 'worlds': 8, 'trace_s': 1.0, 'lower_s': 0.5,
        'compile_s': 2.0, 'total_s': 3.5,
    }  # fmt: skip

  monkeypatch.setattr(compile_time, '_run_isolated', fake_run)
  argv = ['--tasks', 'reach', '--programs', 'step', 'reset', 'raw_reset']
  with pytest.raises(KeyboardInterrupt):
    compile_time.main(argv + ['--worlds', '8', '--out', str(out)])
  (record,) = seen
  assert [r['program'] for r in record['results']] == ['step']
  assert record['failed'] == ['reach/reset']
  assert record['unfinished'] == ['reach/raw_reset']
  assert json.loads(out.read_text()) == record  # nothing written after


def test_xla_phases_read_the_measured_programs_timers():
  log = '\n'.join(
      [
          'I1130 02:38:14.23 gpu_compiler.cc:2345] GpuCompiler::RunHloPasses for'
          ' jit_rollout time: 21.3 s (21317585 us) (cumulative: 31.6 s)',
          'I1130 02:38:14.23 gpu_compiler.cc:2345] GpuCompiler::RunHloPasses for'
          ' jit_rollout time: 3.12 ms (3125 us)',  # a small one of that name
          'I1130 02:38:14.23 gpu_compiler.cc:3017] GpuCompiler::RunBackend for'
          ' jit_convert time: 9.66 ms (9656 us)',
          'I1130 02:38:14.23 gpu_compiler.cc:3017] GpuCompiler::RunBackend for'
          ' jit_rollout time: 1.5 min (90000000 us)',
      ]
  )
  assert compile_time.xla_phases(log, 'jit_rollout') == {
      'xla_hlo_passes_s': 21.3,
      'xla_backend_s': 90.0,
  }
  assert not compile_time.xla_phases(log, 'jit_reset')


def test_xla_passes_sum_each_pass_of_the_measured_program_by_thread():
  line = 'I1130 04:31:08.39 {} hlo_pass_pipeline.cc:{}] {}'.format
  log = '\n'.join(
      [
          line(7, 303, 'Running HLO pass pipeline on module jit_rollout: simp'),
          line(7, 176, 'HLO pass: algsimp time: 2.5 s (2500000 us) (cum: 1)'),
          # Another program compiled on another thread meanwhile.
          line(9, 303, 'Running HLO pass pipeline on module jit_reset: simp'),
          line(9, 176, 'HLO pass: algsimp time: 40 s (40000000 us)'),
          line(7, 176, 'HLO pass: algsimp time: 500 ms (500000 us)'),
          line(7, 176, 'HLO pass: dce time: 20 us (20 us)'),
          line(7, 303, 'Running HLO pass pipeline on module jit_rollout: fuse'),
          line(7, 176, 'HLO pass: fusion time: 1.5 min (90000000 us)'),
          'I1130 04:31:08.39 7 gpu_compiler.cc:2345] HLO pass: x time: 9 s',
      ]
  )
  assert compile_time.xla_passes(log, 'jit_rollout') == {
      'fuse: fusion': 90.0,
      'simp: algsimp': 3.0,
      'simp: dce': 0.00002,
  }
  assert compile_time.xla_passes(log, 'jit_rollout', n=1) == {
      'fuse: fusion': 90.0
  }
  assert compile_time.xla_passes(log, 'jit_reset') == {'simp: algsimp': 40.0}


def test_xla_phases_match_what_this_xla_prints(tmp_path):
  script = tmp_path / 'compile.py'
  script.write_text(
      'import jax, jax.numpy as jnp\n'
      'def program(x):\n'
      '  return jnp.sin(x) * 2\n'
      'jax.jit(program).lower(1.0).compile()\n'
  )
  done = subprocess.run(
      [sys.executable, str(script)],
      check=True,
      capture_output=True,
      text=True,
      env=dict(os.environ, **compile_time.XLA_TIMER_ENV),
  )
  phases = compile_time.xla_phases(done.stderr, 'jit_program')
  assert set(phases) == {'xla_hlo_passes_s', 'xla_backend_s'}, done.stderr
  assert all(0 < s < 60 for s in phases.values())
  # Its passes, each within its compile's time.
  passes = compile_time.xla_passes(done.stderr, 'jit_program', n=1000)
  assert any(name.endswith(': algsimp') for name in passes), passes
  assert 0 < max(passes.values()) <= sum(phases.values())
