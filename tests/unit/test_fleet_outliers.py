"""The fleet's outlier rule (robust z-score), on hand-made values and a hand-made table."""
from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from valve_model_pkg.fleet import MIN_VALVES, THRESHOLD, ValveJob, flag_outliers, robust_z
from valve_model_pkg.fleet.table import fleet_rows, write_table

PARAMS = ('coil_resistance_ohm', 'stroke_m', 'core_area_m2')


def test_robust_z_is_the_modified_z_score_and_ignores_nan() -> None:
    x = np.array([1.0, 2.0, 3.0, 4.0, 100.0, np.nan])
    z = robust_z(x)
    # median 3, MAD 1: z = 0.6745 (x - 3) / 1
    assert z[:5] == pytest.approx(0.6745 * (x[:5] - 3.0))
    assert math.isnan(z[5])
    # MAD 0 (more than half equal): the mean absolute deviation stands in.
    z0 = robust_z([5.0, 5.0, 5.0, 5.0, 7.0])
    assert z0 == pytest.approx([0, 0, 0, 0, 2.0 / (1.253314 * 0.4)])
    assert list(robust_z([2.0] * 6)) == [0.0] * 6


def test_one_valve_far_off_is_flagged_with_the_parameter_and_its_z() -> None:
    rng = np.random.default_rng(3)
    n = 12
    # Each parameter spread evenly over +-2 % (shuffled), the fleet's ordinary scatter.
    values = {p: list(1.0 + 0.02 * rng.permutation(np.linspace(-1.0, 1.0, n)))
              for p in PARAMS}
    values['stroke_m'][7] = 1.5            # 50 % off, the rest within a few %
    verdicts = flag_outliers(values)
    assert [v.flag for v in verdicts].count('yes') == 1
    bad = verdicts[7]
    assert bad.flag == 'yes' and 'stroke_m' in bad.reason
    assert 'coil_resistance_ohm' not in bad.reason
    assert bad.z['stroke_m'] > THRESHOLD
    assert all(v.flag == 'no' and v.reason == '' for k, v in enumerate(verdicts) if k != 7)
    # A parameter the valve's data do not pin down does not flag it.
    usable = {p: [True] * n for p in PARAMS}
    usable['stroke_m'][7] = False
    assert flag_outliers(values, usable=usable)[7].flag == 'no'
    # A stricter threshold flags more, a looser one none.
    assert flag_outliers(values, threshold=1e9)[7].flag == 'no'


def test_too_few_valves_cannot_tell() -> None:
    values = {'stroke_m': [1.0, 1.0, 1.0, 9.0]}
    assert MIN_VALVES == 5
    verdicts = flag_outliers(values)
    assert {v.flag for v in verdicts} == {'cannot tell'}
    assert 'fewer than 5' in verdicts[3].reason
    assert flag_outliers({'stroke_m': [1.0, 1.01, 0.99, 1.0, 9.0]})[4].flag == 'yes'
    # NaN (a valve without a value) does not count towards the five.
    assert flag_outliers({'stroke_m': [1.0, 1.01, 0.99, math.nan, 9.0]})[4].flag == \
        'cannot tell'


def _row(vid: str, r: float, stroke: float, status: str = 'ok') -> dict:
    job = ValveJob(vid, (f'/data/{vid}/fit.csv',), (f'/data/{vid}/val.csv',))
    if status != 'ok':
        return {'valve_id': vid, 'status': status, 'reason': 'refused input: x',
                'duration_s': 0.1, 'fit_files': job.fit[0], 'validation_files': '',
                'output': ''}
    return {'valve_id': vid, 'status': 'ok', 'reason': '', 'effect': 'none',
            'confidence': 'high', 'unexplained_structure': False, 'fit_rmse_a': 0.01,
            'coil_resistance_ohm': r, 'coil_resistance_ohm_ci95_low': r * 0.99,
            'coil_resistance_ohm_ci95_high': r * 1.01,
            'stroke_m': stroke, 'stroke_m_ci95_low': stroke * 0.9,
            'stroke_m_ci95_high': stroke * 1.1,
            'core_length_m': 0.11, 'core_length_m_ci95_low': math.nan,
            'core_length_m_ci95_high': math.nan,
            '_searched': ['coil_resistance_ohm', 'stroke_m'],
            'duration_s': 2.0, 'fit_files': job.fit[0], 'validation_files': job.validate[0],
            'output': f'valves/{vid}'}


def test_hand_made_table_flags_the_far_valve_and_writes_csv_and_parquet(tmp_path) -> None:
    strokes = [300e-6, 303e-6, 297e-6, 301e-6, 299e-6, 302e-6, 450e-6]
    rows = [_row(f'V{k}', 12.0 + 0.05 * k, s) for k, s in enumerate(strokes)]
    rows.append(_row('V9', 0, 0, status='failed'))
    rows = fleet_rows(rows)
    flags = {r['valve_id']: r['outlier'] for r in rows}
    assert flags == {'V0': 'no', 'V1': 'no', 'V2': 'no', 'V3': 'no', 'V4': 'no', 'V5': 'no',
                     'V6': 'yes', 'V9': ''}
    assert 'stroke_m = 0.00045' in rows[6]['outlier_reason']
    assert rows[6]['stroke_m_z'] > THRESHOLD and 'core_length_m_z' not in rows[6]
    write_table(rows, tmp_path)
    with open(tmp_path / 'fleet.csv', newline='') as fh:
        back = list(csv.DictReader(fh))
    cols = list(back[0])
    assert cols[:3] == ['valve_id', 'status', 'reason']
    i = cols.index('stroke_m')
    assert cols[i:i + 4] == ['stroke_m', 'stroke_m_ci95_low', 'stroke_m_ci95_high',
                             'stroke_m_z']
    assert back[6]['outlier'] == 'yes' and float(back[6]['stroke_m']) == 450e-6
    assert back[7]['status'] == 'failed' and back[7]['stroke_m'] == ''
    assert back[0]['core_length_m_ci95_low'] == ''         # not pinned down: no interval
    pq = pytest.importorskip('pyarrow.parquet')
    table = pq.read_table(tmp_path / 'fleet.parquet')
    assert table.column_names == cols
    assert table.column('outlier').to_pylist()[6] == 'yes'
    assert table.column('stroke_m').to_pylist()[7] is None
    assert str(table.schema.field('stroke_m').type) == 'double'


def test_fewer_than_five_identified_valves_cannot_tell_in_the_table(tmp_path) -> None:
    rows = fleet_rows([_row(f'V{k}', 12.0, 300e-6 * (1 + k)) for k in range(4)])
    assert {r['outlier'] for r in rows} == {'cannot tell'}
