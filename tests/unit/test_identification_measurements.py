"""Measured-data input of the identification: CSV format, rosbag2 bags, refusals."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from suite_paths import REPO_ROOT
from valve_model_pkg.errors import MeasurementFormatError
from valve_model_pkg.identification.bag_reader import VALVE_STATE_TYPE, read_bag
from valve_model_pkg.identification.csv_reader import read_csv, write_csv
from valve_model_pkg.identification.readers import read_measurements

HEADER = ('# experiment: step\n# valve: bench valve 7\n# supply_pressure_pa: 400000\n'
          '# output_pressure_pa: 0\n# sample_rate_hz: 50000\n')


def _rows(n: int = 20, dt: float = 2e-5) -> str:
    return ''.join(f'{k * dt:.6g},{0.0 if k == 0 else 24.0},{0.001 * k:.4f}\n'
                   for k in range(n))


def _write(tmp_path: Path, text: str, name: str = 'm.csv') -> Path:
    p = tmp_path / name
    p.write_text(text, encoding='utf-8')
    return p


def test_reads_the_documented_example(tmp_path: Path) -> None:
    p = _write(tmp_path, HEADER + 't,voltage,current\n' + _rows())
    m = read_csv(p)
    assert m.n_samples == 20
    assert m.supply_pressure_pa == 400000.0
    assert m.experiment == 'step'
    assert m.metadata['valve'] == 'bench valve 7'
    np.testing.assert_allclose(m.sample_rate_hz, 50e3, rtol=1e-6)
    assert m.voltage_v[1] == 24.0
    assert m.n_missing_values == 0 and m.n_gaps == 0


def test_optional_and_unknown_columns_and_metadata_are_kept(tmp_path: Path) -> None:
    body = ''.join(f'{k * 2e-5:.6g},24,{0.01 * k},{1e-5 * k},7\n' for k in range(12))
    p = _write(tmp_path, HEADER + '# operator: alice\nt,voltage,current,position,extra\n' + body)
    m = read_csv(p)
    assert m.metadata['operator'] == 'alice'
    assert m.position_m is not None and m.position_m[3] == pytest.approx(3e-5)
    assert any('extra' in n for n in m.notes)


@pytest.mark.parametrize('text, line, reason', [
    (HEADER + 't,voltage\n' + '0,0\n' * 12, 6, r"lacks required column\(s\) \['current'\]"),
    (HEADER + 't,voltage,current\n' + _rows(5) + '1e-4,24\n' + _rows(10, 1e-3)[20:],
     12, 'expected 3 fields'),
    (HEADER + 't,voltage,current\n' + _rows(5) + '1e-4,24,abc\n', 12, "'abc' is not a number"),
    (HEADER + 't,voltage,current\n' + _rows(12) + '1e-4,24,0.1\n', 19, 'does not increase'),
    (HEADER + 't,voltage,current\n-1e-5,0,0\n' + _rows(12), 7, 'is negative'),
    (HEADER + 't,voltage,current\n' + _rows(5) + '1e-4,,0.1\n', 12, "'voltage' has no value"),
    (HEADER.replace('400000', 'four bar') + 't,voltage,current\n' + _rows(), 3,
     "'four bar' is not a number"),
    (HEADER + 't,voltage,current\n' + _rows(5) + '\n' + _rows(12)[60:], 12,
     'empty line inside the data'),
    (HEADER + 't,voltage,current\n' + _rows(5) + '# late: 1\n', 12, 'after the header'),
    (HEADER + 't,voltage,current\n' + _rows(3), None, 'at least 10 are needed'),
    (HEADER + 't,voltage,current\n' + _rows(5) + '1e-4,24,inf\n', 12, 'is not finite'),
    (HEADER + 't,t,current\n' + _rows(), 6, 'duplicate columns'),
])
def test_malformed_files_are_refused_with_file_line_reason(tmp_path: Path, text: str,
                                                           line: int | None,
                                                           reason: str) -> None:
    p = _write(tmp_path, text)
    with pytest.raises(MeasurementFormatError, match=reason) as info:
        read_csv(p)
    assert info.value.path == str(p)
    assert info.value.line == line
    assert str(p) in str(info.value)


def test_flow_map_and_non_utf8_are_refused(tmp_path: Path) -> None:
    p = _write(tmp_path, '# experiment: flow_map\nduty,flow_fraction\n' + '0.5,0.5\n' * 12)
    with pytest.raises(MeasurementFormatError, match='flow_map'):
        read_csv(p)
    q = tmp_path / 'bad.csv'
    q.write_bytes(HEADER.encode() + b't,voltage,current\n0,0,\xff\n')
    with pytest.raises(MeasurementFormatError, match='UTF-8') as info:
        read_csv(q)
    assert info.value.line == 7


def test_missing_values_and_gaps_are_kept_and_reported_not_dropped(tmp_path: Path) -> None:
    rows = _rows(30).splitlines()
    rows[7] = rows[7].rsplit(',', 1)[0] + ','        # empty current
    rows[9] = rows[9].rsplit(',', 1)[0] + ',nan'     # explicit nan
    del rows[15:17]                                  # two rows missing: a gap in t
    p = _write(tmp_path, HEADER + 't,voltage,current\n' + '\n'.join(rows) + '\n')
    m = read_csv(p)
    assert m.n_samples == 28                          # every row present in the file kept
    assert m.n_missing_values == 2 and math.isnan(m.current_a[7])
    assert m.n_gaps == 1
    assert any('without a current value' in n and '[14, 16]' in n for n in m.notes)
    assert any('gaps' in n for n in m.notes)


def test_write_csv_round_trip(tmp_path: Path) -> None:
    t = np.arange(50) * 1e-4
    i = np.linspace(0, 1, 50)
    i[4] = np.nan
    p = write_csv(tmp_path / 'x.csv', t, np.full(50, 15.0), i,
                  {'experiment': 'step', 'supply_pressure_pa': 3e5})
    m = read_csv(p)
    np.testing.assert_allclose(m.t_s, t)
    assert m.n_missing_values == 1 and m.supply_pressure_pa == 3e5


#: ValveState as the interface package defines it (comments and blank lines dropped).
VALVE_STATE_MSG = '\n'.join(
    ' '.join(ln.split('#')[0].split())
    for ln in (REPO_ROOT / 'valve_msgs' / 'msg' / 'ValveState.msg').read_text().splitlines()
    if ln.split('#')[0].strip()) + '\n'


def test_no_message_definition_is_pasted_into_the_identification() -> None:
    """Bags are decoded with the definitions they embed or the built valve_msgs, never
    with a copy of a .msg file kept in the identification's code."""
    pkg = REPO_ROOT / 'valve_model_pkg' / 'valve_model_pkg' / 'identification'
    for path in pkg.glob('*.py'):
        text = path.read_text(encoding='utf-8')
        assert 'float64 coil_current' not in text and 'std_msgs/Header header' not in text, \
            path.name


def _write_bag(path: Path, *, embed_definition: bool, n: int = 40, frame: str = 'v1',
               extra_frame: str | None = None, stamps: bool = True, pwm: bool = False,
               with_mean: bool = True) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    text = VALVE_STATE_MSG if with_mean else '\n'.join(
        ln for ln in VALVE_STATE_MSG.splitlines() if '_mean' not in ln) + '\n'
    store.register(get_types_from_msg(text, VALVE_STATE_TYPE))
    State = store.types[VALVE_STATE_TYPE]
    Header = store.types['std_msgs/msg/Header']
    Time = store.types['builtin_interfaces/msg/Time']
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conn = w.add_connection('/valve/state', VALVE_STATE_TYPE, typestore=store,
                                msgdef='' if not embed_definition else None)
        seq = 0
        for k in range(n):
            if k == 20:
                seq += 3  # three messages lost
            frames = [frame] + ([extra_frame] if extra_frame else [])
            for fr in frames:
                t_ns = 1_000_000_000 + k * 1_000_000
                extra = {'coil_current_mean': 0.01 * k,
                         'coil_voltage_mean': 0.0} if with_mean else {}
                msg = State(
                    header=Header(stamp=Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9)
                                  if stamps else Time(sec=0, nanosec=0), frame_id=fr),
                    sequence=seq, coil_voltage=24.0 if k >= 2 else 0.0,
                    coil_current=0.01 * k if k != 7 else float('nan'),
                    spool_position=0.0, spool_velocity=0.0, spool_position_avg=0.0,
                    mass_flow=0.0, duty=(0.4 if k >= 25 else 0.0) if pwm else 1.0,
                    pwm_frequency=50.0 if pwm else 0.0, supply_pressure=4e5,
                    output_pressure=0.0, source=0, position_measured=False, **extra)
                w.write(conn, t_ns, store.serialize_cdr(msg, VALVE_STATE_TYPE))
            seq += 1


@pytest.mark.parametrize('embed', [True, False])
def test_bag_reader_reads_the_state_topic(tmp_path: Path, embed: bool) -> None:
    bag = tmp_path / 'bag'
    try:
        _write_bag(bag, embed_definition=embed)
    except TypeError:
        pytest.skip('this rosbags version cannot write a connection without definition')
    m = read_bag(bag)
    assert m.n_samples == 40
    assert m.supply_pressure_pa == 4e5
    np.testing.assert_allclose(m.t_s[:3], [0.0, 1e-3, 2e-3], atol=1e-9)
    assert m.voltage_v[2] == 24.0
    assert m.n_missing_values == 1
    assert m.n_gaps == 1 and any('3 messages lost' in n for n in m.notes)
    assert any('coarse' in n for n in m.notes)
    assert m.position_m is None   # modelled, not measured
    assert read_measurements([bag])[0].n_samples == 40


def test_bag_reader_refusals(tmp_path: Path) -> None:
    bag = tmp_path / 'two'
    _write_bag(bag, embed_definition=True, extra_frame='v2')
    with pytest.raises(MeasurementFormatError, match='several valves'):
        read_bag(bag)
    assert read_bag(bag, valve='v2').n_samples == 40
    with pytest.raises(MeasurementFormatError, match="no topic '/other'"):
        read_bag(bag, topic='/other')
    with pytest.raises(MeasurementFormatError, match='cannot be opened'):
        read_bag(tmp_path / 'nothing')


def test_files_with_different_sample_rates_are_combined(tmp_path: Path) -> None:
    """A 50 kHz and a 5 kHz record of the same valve give the same error per second."""
    from valve_model_pkg.identification.problem import FitData
    from valve_model_pkg.model.parameters import ValveParameters

    params = ValveParameters()
    files = []
    for rate in (50e3, 5e3):
        t = np.arange(int(0.03 * rate)) / rate
        v = np.where(t >= 1e-3, 24.0, 0.0)
        m = write_csv(tmp_path / f'r{int(rate)}.csv', t, v, np.zeros_like(t),
                      {'experiment': 'step', 'supply_pressure_pa': 4e5,
                       'sample_rate_hz': rate})
        files.append(read_csv(m))
    data = FitData(files)
    sim = data.simulate(params.to_vector()[None, :])
    for m, (c, _) in zip(data.measurements, sim):
        # The model is simulated at its own step and sampled at each file's times.
        assert c.shape == (1, m.n_samples)
    # Same trace at both rates: the same mean absolute error (to the sampling error).
    mae = [v for v in data.errors(params.replace(coil_resistance_ohm=14.0)).mae_per_file
           .values()]
    assert mae[0] == pytest.approx(mae[1], rel=0.02)
    t5 = files[1].t_s
    np.testing.assert_allclose(sim[1][0][0], np.interp(t5, files[0].t_s, sim[0][0][0]),
                               atol=2e-4)


def test_pwm_bag_is_an_operation_record_and_needs_the_mean_current(tmp_path: Path) -> None:
    """A bag of the suite running PWM is read as an operational record."""
    bag = tmp_path / 'ops'
    _write_bag(bag, embed_definition=True, pwm=True, n=60)
    m = read_bag(bag)
    assert m.through_electronics and m.experiment == 'operation'
    assert m.sampling == 'interval_mean'
    np.testing.assert_allclose(m.current_a[:3], [0.0, 0.01, 0.02])
    assert any('24 V' in n for n in m.notes)
    old = tmp_path / 'old'
    _write_bag(old, embed_definition=True, pwm=True, n=60, with_mean=False)
    with pytest.raises(MeasurementFormatError, match="'coil_current_mean'"):
        read_bag(old)
