"""benchmarks/sensor_share.py: what the sensors are of one `mjx.step`."""

import json
import os
import sys

sys.path.insert(
    0, os.path.join(os.path.dirname(os.path.dirname(__file__)), 'benchmarks')
)
import sensor_share  # pylint: disable=g-import-not-at-top,wrong-import-position


def test_the_reach_model_with_and_without_its_sensors(tmp_path, monkeypatch):
  out = tmp_path / 'share.json'
  monkeypatch.setattr(
      sys,
      'argv',
      [
          'sensor_share.py',
          '--task',
          'reach',
          '--worlds',
          '2',
          '--repeats',
          '1',
          '--out',
          str(out),
      ],
  )
  sensor_share.main()
  (row,) = json.loads(out.read_text())['results']
  assert row['sensors'] == 4
  with_sensors, without = row['with_sensors'], row['without_sensors']
  # The disabled sensor stage leaves its code out of the program.
  assert without['jaxpr_eqns'] < with_sensors['jaxpr_eqns']
  assert without['hlo_instructions'] < with_sensors['hlo_instructions']
  assert 0 < row['share_of_jaxpr'] < 1
  assert with_sensors['seconds_per_call'] > 0
