"""benchmarks/resume_compare.py on run folders written here."""

import csv
import json
import os

import pytest

from mjx_composer.training import trainer

import resume_compare  # benchmarks/resume_compare.py


def _run(root, name, returns, task='reach', resumed_from=None):
  """A run folder with one evaluation row per 100 steps."""
  path = os.path.join(root, name)
  os.makedirs(path)
  with open(os.path.join(path, 'config.json'), 'w') as f:
    json.dump({'task': task}, f)
  with open(os.path.join(path, 'metrics.csv'), 'w', newline='') as f:
    writer = csv.DictWriter(f, fieldnames=trainer.CSV_FIELDS)
    writer.writeheader()
    for i, value in enumerate(returns):
      row = dict.fromkeys(trainer.CSV_FIELDS, 0.0)
      writer.writerow(row | {'step': 100 * i, 'eval_return': value})
  if resumed_from is not None:
    with open(os.path.join(path, 'summary.json'), 'w') as f:
      json.dump({'resumed_from_step': resumed_from}, f)
  return path


def test_compares_each_evaluation_after_the_resume(tmp_path, capsys):
  resumed = _run(tmp_path, 'resumed', [0, 1, 5, 6, 9], resumed_from=200)
  a = _run(tmp_path, 'a', [0, 2, 3, 4, 8])
  b = _run(tmp_path, 'b', [0, 1, 2, 7])  # cut short at step 300
  out = tmp_path / 'out.json'
  png = tmp_path / 'out.png'
  resume_compare.main(
      [resumed, '--baselines', a, b, '--out', str(out), '--plot', str(png)]
  )
  record = json.loads(out.read_text())
  assert record['resumed_from_step'] == 200
  assert [r['step'] for r in record['comparison']] == [300, 400]
  first, last = record['comparison']
  assert first['resumed_return'] == 6
  assert (first['baseline_min'], first['baseline_max']) == (4, 7)
  assert first['baseline_mean'] == pytest.approx(5.5)
  assert first['inside_range'] and first['baseline_runs'] == 2
  assert last['baseline_runs'] == 1 and not last['inside_range']
  assert png.stat().st_size > 0
  assert '1 of 2 evaluations' in capsys.readouterr().out


def test_a_resumed_run_without_summary_needs_its_step(tmp_path, capsys):
  resumed = _run(tmp_path, 'resumed', [0, 1, 5])
  a = _run(tmp_path, 'a', [0, 2, 3])
  args = [resumed, '--baselines', a, '--out', str(tmp_path / 'o.json')]
  with pytest.raises(SystemExit):
    resume_compare.main(args)
  assert '--resumed-from STEP' in capsys.readouterr().err
  resume_compare.main(args + ['--resumed-from', '100'])
  record = json.loads((tmp_path / 'o.json').read_text())
  assert [r['step'] for r in record['comparison']] == [200]


def test_runs_of_another_task_are_refused(tmp_path, capsys):
  resumed = _run(tmp_path, 'resumed', [0, 1], resumed_from=0)
  other = _run(tmp_path, 'other', [0, 1], task='push')
  with pytest.raises(SystemExit):
    resume_compare.main([resumed, '--baselines', other, '--out', 'x.json'])
  assert "trained 'push', not 'reach'" in capsys.readouterr().err
