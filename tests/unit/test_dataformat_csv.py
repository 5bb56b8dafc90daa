"""The measured-data format: one reader and writer for every kind, one set of rules."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from valve_model_pkg import dataformat
from valve_model_pkg.dataformat import (DataFormatError, FlowMapRecord, OperationRecord,
                                        TraceRecord, read_flow_map, read_operation,
                                        read_record, read_trace, write_record, write_table)
from valve_model_pkg.errors import MeasurementFormatError
from valve_model_pkg.identification.csv_reader import read_csv
from valve_model_pkg.maps import FlowMapFormatError
from valve_model_pkg.maps import flow_check

PKG = Path(dataformat.__file__).resolve().parents[1]

OPERATION = ('# experiment: operation\n# valve: axis 2 valve A\n# supply_voltage_v: 24\n'
             '# sample_rate_hz: 1000\n# current_averaging: interval_mean\n'
             't,duty,pwm_frequency_hz,current,supply_pressure,output_pressure\n')


def _operation_rows(n: int = 60, rest: int = 25) -> str:
    return ''.join(f'{k * 1e-3:.3f},{0.0 if k < rest else 0.4},50,{0.01 * k:.3f},400000,0\n'
                   for k in range(n))


def _write(tmp_path: Path, text: str, name: str = 'r.csv') -> Path:
    p = tmp_path / name
    p.write_text(text, encoding='utf-8')
    return p


def test_reads_the_documented_operation_example(tmp_path: Path) -> None:
    p = _write(tmp_path, OPERATION + _operation_rows())
    rec = read_record(p)
    assert isinstance(rec, OperationRecord) and rec.kind == 'operation'
    assert rec.t_s.size == 60 and rec.duty[30] == 0.4
    np.testing.assert_array_equal(rec.pwm_frequency_hz, 50.0)
    np.testing.assert_array_equal(rec.supply_pressure_pa, 4e5)
    assert rec.supply_voltage_v == 24.0 and rec.current_averaging == 'interval_mean'
    assert rec.starts_at_rest and any('at rest' in n for n in rec.notes)
    assert read_operation(p).t_s.size == 60
    # 5 ms of duty 0 at 50 Hz is less than a period: the reader says it assumed motion
    moving = read_record(_write(tmp_path, OPERATION + _operation_rows(rest=5), 'm.csv'))
    assert not moving.starts_at_rest and any('in motion' in n for n in moving.notes)


def test_operation_pressures_come_from_metadata_without_columns(tmp_path: Path) -> None:
    text = ('# experiment: operation\n# supply_pressure_pa: 300000\n'
            't,duty,pwm_frequency_hz,current\n'
            + ''.join(f'{k * 1e-3:.3f},0.5,100,0.1\n' for k in range(12)))
    rec = read_record(_write(tmp_path, text))
    np.testing.assert_array_equal(rec.supply_pressure_pa, 3e5)
    np.testing.assert_array_equal(rec.output_pressure_pa, 0.0)


@pytest.mark.parametrize('kind', ['step', 'pwm', 'operation', 'flow_map'])
def test_every_kind_round_trips(tmp_path: Path, kind: str) -> None:
    t = np.arange(40) * 2e-5
    if kind == 'step':
        meta = {'experiment': 'step', 'supply_pressure_pa': 4e5, 'sample_rate_hz': 50e3}
        cols = {'t': t, 'voltage': np.where(t > 1e-4, 24.0, 0.0),
                'current': np.linspace(0, 0.5, 40), 'position': np.zeros(40)}
        cols['current'][3] = np.nan
    elif kind == 'pwm':
        meta = {'experiment': 'pwm', 'supply_pressure_pa': 4e5, 'pwm_frequency_hz': 50.0,
                'supply_voltage_v': 24.0}
        cols = {'t': t, 'voltage': np.full(40, 24.0), 'coil_voltage': np.full(40, 23.5),
                'current': np.linspace(0, 0.5, 40), 'duty': np.full(40, 0.4)}
    elif kind == 'operation':
        meta = {'experiment': 'operation', 'supply_voltage_v': 24.0,
                'current_averaging': 'interval_mean'}
        cols = {'t': t, 'duty': np.full(40, 0.3), 'pwm_frequency_hz': np.full(40, 100.0),
                'current': np.linspace(0, 0.5, 40), 'supply_pressure': np.full(40, 4e5)}
    else:
        meta = {'experiment': 'flow_map', 'supply_pressure_pa': 4e5, 'pwm_frequency_hz': 50.0}
        cols = {'duty': np.linspace(0, 1, 11), 'mass_flow': np.linspace(0, 1e-3, 11)}
    p = write_table(tmp_path / 'a.csv', meta, cols)
    rec = read_record(p)
    assert rec.experiment == kind
    assert isinstance(rec, {'step': TraceRecord, 'pwm': TraceRecord,
                            'operation': OperationRecord, 'flow_map': FlowMapRecord}[kind])
    got = rec.columns()
    assert set(got) == set(cols)
    for name, values in cols.items():
        np.testing.assert_allclose(got[name], values, rtol=1e-9, equal_nan=True)
    # and a record written back reads the same
    again = read_record(write_record(tmp_path / 'b.csv', rec))
    for name, values in again.columns().items():
        np.testing.assert_allclose(values, got[name], rtol=1e-9, equal_nan=True)
    assert again.metadata == rec.metadata


BAD = [
    # (text, line, key, value, reason)
    ('# experiment: steps\nt,voltage,current\n0,0,0\n', 1, 'experiment', 'steps',
     "'steps' is not one of"),
    ('# experiment: step\n# sample_rate_hz: -5\nt,voltage,current\n0,0,0\n', 2,
     'sample_rate_hz', '-5', 'must be positive'),
    ('# supply_pressure_pa: -200000\nt,voltage,current\n0,0,0\n', 1, 'supply_pressure_pa',
     '-200000', 'below vacuum'),
    ('# experiment: operation\n# current_averaging: median\nt,duty,pwm_frequency_hz,current\n'
     '0,0,50,0\n', 2, 'current_averaging', 'median', 'is not one of'),
    ('# experiment: step\n# experiment: pwm\nt,voltage,current\n0,0,0\n', 2, 'experiment',
     'pwm', 'given twice'),
    ('# experiment: pwm\nt,voltage,current,duty\n0,0,0,0.5\n1e-3,0,0,1.5\n', 4, 'duty', '1.5',
     'outside [0, 1]'),
    ('# experiment: operation\nt,duty,pwm_frequency_hz,current\n0,0,50,0\n1e-3,0,0,0\n', 4,
     'pwm_frequency_hz', '0', 'must be positive'),
    ('# experiment: operation\nt,duty,current\n0,0,0\n', 2, 'pwm_frequency_hz', None,
     'lacks required column'),
    ('# experiment: operation\nt,duty,pwm_frequency_hz,current\n0,abc,50,0\n', 3, 'duty',
     'abc', "'abc' is not a number"),
    ('# experiment: operation\nt,duty,pwm_frequency_hz,current\n0,,50,0\n', 3, 'duty', '',
     "'duty' has no value"),
    ('# experiment: flow_map\n# pwm_frequency_hz: 50\nduty,mass_flow\n0,0\n1,-1e-3\n', 5,
     'mass_flow', '-1e-3', 'is negative'),
]


@pytest.mark.parametrize('text, line, key, value, reason', BAD)
def test_refusals_name_file_line_key_and_value(tmp_path: Path, text: str, line: int,
                                               key: str, value: str | None,
                                               reason: str) -> None:
    p = _write(tmp_path, text)
    with pytest.raises(DataFormatError) as info:
        read_record(p)
    err = info.value
    assert reason in err.reason
    assert (err.path, err.line, err.key) == (str(p), line, key)
    if value is not None:
        assert err.value == value and (not value or repr(value) in str(err))
    assert str(err).startswith(f'{p}:{line}: ')


def test_both_consumers_apply_the_same_rules(tmp_path: Path) -> None:
    """One rule, one message: identification and flow check refuse alike."""
    dup = '# supply_pressure_pa: 4e5\n# supply_pressure_pa: 3e5\n'
    trace = _write(tmp_path, dup + 't,voltage,current\n' + '0,0,0\n' * 12, 't.csv')
    fmap = _write(tmp_path, '# experiment: flow_map\n' + dup + 'duty,flow_fraction\n0,0\n1,1\n',
                  'f.csv')
    with pytest.raises(MeasurementFormatError) as a:
        read_csv(trace)
    with pytest.raises(FlowMapFormatError) as b:
        flow_check.read_flow_map(fmap)
    same = "metadata key 'supply_pressure_pa' given twice (first on line {}, again as '3e5')"
    assert (a.value.reason, b.value.reason) == (same.format(1), same.format(2))
    assert (a.value.line, b.value.line) == (2, 3)
    # a blank line inside the data is refused by both readers
    gap = _write(tmp_path, '# experiment: flow_map\n# pwm_frequency_hz: 50\n'
                 '# supply_pressure_pa: 4e5\nduty,flow_fraction\n0,0\n\n1,1\n', 'g.csv')
    with pytest.raises(FlowMapFormatError, match='empty line inside the data'):
        flow_check.read_flow_map(gap)


def test_kind_readers_refuse_other_kinds(tmp_path: Path) -> None:
    op = _write(tmp_path, OPERATION + _operation_rows())
    with pytest.raises(DataFormatError, match='is an operation record'):
        read_trace(op)
    with pytest.raises(DataFormatError, match="expected 'flow_map'"):
        read_flow_map(op)
    with pytest.raises(DataFormatError, match="expected 'operation'"):
        read_operation(_write(tmp_path, 't,voltage,current\n0,0,0\n', 's.csv'))


def test_identification_reads_operation_records_and_pwm_through_the_electronics(
        tmp_path: Path) -> None:
    # operation records and pwm records without coil_voltage are identified with the
    # drive electronics in the loop
    op = _write(tmp_path, OPERATION + _operation_rows())
    m = read_csv(op)
    assert m.through_electronics and m.sampling == 'interval_mean'
    no_v = _write(tmp_path, OPERATION.replace('# supply_voltage_v: 24\n', '')
                  + _operation_rows(), 'nv.csv')
    with pytest.raises(MeasurementFormatError, match='supply_voltage_v'):
        read_csv(no_v)
    t = np.arange(20) * 1e-4
    pwm = write_table(tmp_path / 'p.csv', {'experiment': 'pwm', 'supply_pressure_pa': 4e5},
                      {'t': t, 'voltage': np.full(20, 24.0), 'current': np.zeros(20)})
    m = read_csv(pwm)
    assert m.through_electronics and any('drive electronics' in n for n in m.notes)


def test_valve_simulate_output_is_read_by_the_format_and_the_identification(
        tmp_path: Path) -> None:
    from valve_model_pkg.cli.simulate import main
    out = tmp_path / 'pwm.csv'
    assert main(['--experiment', 'pwm', '--duration', '0.03', '--sample-rate', '20000',
                 '-o', str(out), '--no-plot', '-q']) == 0
    rec = read_record(out)
    assert isinstance(rec, TraceRecord) and rec.experiment == 'pwm'
    assert rec.coil_voltage_v is not None and rec.coil_voltage_v.min() < -20.0
    assert set(np.unique(rec.voltage_v)) == {0.0, 24.0}
    assert rec.notes == () and rec.n_gaps == 0
    m = read_csv(out)
    # 20 kHz samples of the 20 kHz chopper all fall in its on-time: the coil_voltage column
    # reads 24 V while the current is held, so the electronics run from the main PWM
    assert m.through_electronics
    np.testing.assert_array_equal(m.voltage_v, rec.voltage_v)


@pytest.mark.parametrize('columns, match', [
    ({'t': [0.0], 'voltage': [0.0]}, 'missing'),
    ({'t': [0.0], 'voltage': [0.0], 'current': [0.0], 'speed': [1.0]}, 'unknown'),
    ({'t': [math.nan], 'voltage': [0.0], 'current': [0.0]}, "'t' has non-finite"),
    ({'t': [0.0, 1.0], 'voltage': [0.0], 'current': [0.0]}, 'shape'),
])
def test_the_writer_refuses_what_the_reader_would(tmp_path: Path, columns: dict,
                                                  match: str) -> None:
    with pytest.raises(ValueError, match=match):
        write_table(tmp_path / 'x.csv', {'experiment': 'step'}, columns)


def test_the_format_is_named_never_by_a_machine_path() -> None:
    for rel in ('dataformat/csv_format.py', 'dataformat/__init__.py', 'maps/flow_check.py',
                'identification/csv_reader.py', 'cli/simulate.py', 'cli/flow_check.py',
                'cli/identify.py'):
        text = (PKG / rel).read_text(encoding='utf-8')
        assert '/work/' not in text and '/home/' not in text, rel
