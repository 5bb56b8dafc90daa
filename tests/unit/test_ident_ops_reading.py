"""Operational and pwm records for identification: reading, PWM grid, hold-out,
refusals of records whose kind contradicts their content. Fast: no identification run."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from valve_model_pkg.dataformat import write_table
from valve_model_pkg.errors import MeasurementFormatError
from valve_model_pkg.identification import IdentifySettings
from valve_model_pkg.identification.csv_reader import read_csv
from valve_model_pkg.identification.measurement import hold_out
from valve_model_pkg.identification.pwm_grid import DISCARD_MIN_S, drive_from_in_force
from valve_model_pkg.identification.pipeline import prepare_files
from valve_model_pkg.model import InputTrace, load_parameters, simulate_trace_batch


def _ops(tmp_path: Path, *, phase: float = 0.0073, rest: bool = True, T: float = 0.5,
         name: str = 'ops.csv') -> tuple[Path, np.ndarray]:
    """A record of the suite's own model: duty steps every 0.1 s at 50 Hz, 1 kHz means."""
    t_cmd, duty, freq = [0.0], [0.0 if rest else 0.5], [1.0 / phase]
    s = phase
    while s < T:
        d = 0.0 if (rest and s < 0.04) else [0.3, 0.6, 0.45][int(s / 0.1) % 3]
        t_cmd.append(s - 1e-6)
        duty.append(d)
        freq.append(50.0)
        s += 0.02
    trace = InputTrace.pwm_commands(t_cmd, duty, freq, 24.0)
    t = np.arange(1, int(round(T * 1000)) + 1) * 1e-3
    res = simulate_trace_batch(load_parameters(), trace, t, sampling='interval_mean',
                               supply_pressure_pa=4e5)
    starts = np.array(t_cmd[1:]) + 1e-6
    k = np.searchsorted(starts, t, side='right') - 1
    d_in = np.where(k >= 0, np.array(duty[1:])[np.clip(k, 0, None)], duty[0])
    path = write_table(tmp_path / name, {
        'experiment': 'operation', 'supply_voltage_v': 24, 'sample_rate_hz': 1000,
        'current_averaging': 'interval_mean', 'supply_pressure_pa': 400000},
        {'t': t, 'duty': d_in, 'pwm_frequency_hz': np.full(t.size, 50.0),
         'current': res.coil_current_a[0]})
    return path, res.coil_current_a[0]


def test_operation_record_reads_as_electronics_with_the_period_grid(tmp_path: Path) -> None:
    path, _ = _ops(tmp_path)
    m = read_csv(path)
    assert m.through_electronics and m.sampling == 'interval_mean'
    assert m.exclude_before_s == m.t_s[0]          # starts at rest: every sample compared
    # the first period start lies in the 1 ms the duty change allows; the range is kept
    first = m.drive.period_starts_s[m.drive.period_duty > 0][0]
    assert 0.047 < first <= 0.048
    lo, hi = m.drive.phase_range_s
    assert lo < 0 < hi and hi - lo <= 1e-3 + 1e-9
    assert m.voltage_v.max() == 24.0                # main PWM level for the residual phases


def test_the_model_reproduces_the_record_once_the_grid_is_placed(tmp_path: Path) -> None:
    """With the grid shifted to the truth the suite's own record is reproduced exactly."""
    path, cur = _ops(tmp_path)
    m = read_csv(path)
    first = m.drive.period_starts_s[0]
    shifted = m.drive.shifted(0.0073 - first)
    res = simulate_trace_batch(load_parameters(), InputTrace.pwm_commands(
        shifted.t_s, shifted.duty, shifted.pwm_frequency_hz, shifted.supply_voltage_v),
        m.t_s, sampling='interval_mean', supply_pressure_pa=4e5)
    assert np.max(np.abs(res.coil_current_a[0] - cur)) < 1e-6


def test_a_record_in_motion_discards_its_first_periods(tmp_path: Path) -> None:
    path, _ = _ops(tmp_path, rest=False)
    m = read_csv(path)
    assert m.exclude_before_s >= DISCARD_MIN_S
    assert any('starts in motion' in n for n in m.notes)
    assert not m.valid[m.t_s < DISCARD_MIN_S].any()


def test_a_single_record_holds_out_its_last_30_percent(tmp_path: Path) -> None:
    path, _ = _ops(tmp_path)
    m = read_csv(path)
    files = prepare_files([m], [], IdentifySettings())
    fit, val = files.fit, files.validation
    assert len(fit) == 1 and len(val) == 1 and 'held out' in files.notes[0]
    split = m.t_s[0] + 0.7 * (m.t_s[-1] - m.t_s[0])
    assert fit[0].t_s[-1] <= split + 1e-12
    assert not val[0].valid[val[0].t_s < split].any() and val[0].valid[-1]
    f, v = hold_out(m, 0.3, fit_window_s=0.1)
    assert f.t_s[-1] <= 0.101


def test_in_force_commands_latch_at_the_reconstructed_starts() -> None:
    t = np.arange(1, 201) * 1e-3
    duty = np.where(t > 0.0123, 0.5, 0.0)     # change seen at 13 ms: a start in (12, 13]
    drive, notes = drive_from_in_force(t, duty, np.full(t.size, 100.0), 24.0)
    starts = drive.period_starts_s[drive.period_duty > 0]
    assert 0.012 < starts[0] <= 0.013
    np.testing.assert_allclose(np.diff(starts[:5]), 0.01)
    assert all(c < s for c, s in zip(drive.t_s[1:], starts))   # given before their start


def test_a_pwm_command_in_a_step_file_is_refused(tmp_path: Path) -> None:
    t = np.arange(2000) * 2e-5
    v = np.where((t % 4e-3) < 2e-3, 24.0, 0.0)
    path = write_table(tmp_path / 's.csv', {'experiment': 'step', 'supply_pressure_pa': 4e5},
                       {'t': t, 'voltage': v, 'current': np.full(t.size, 0.3)})
    with pytest.raises(MeasurementFormatError, match="'step'.*PWM command"):
        read_csv(path)


def test_a_chopper_in_a_bare_coil_step_is_refused(tmp_path: Path) -> None:
    t = np.arange(1000) * 2e-5                  # 20 ms at 24 V, current held at 0.5 A
    i = np.minimum(t * 200.0, 0.5)
    path = write_table(tmp_path / 'c.csv', {'experiment': 'step', 'supply_pressure_pa': 4e5},
                       {'t': t, 'voltage': np.full(t.size, 24.0), 'current': i})
    with pytest.raises(MeasurementFormatError, match='current chopper'):
        read_csv(path)


def test_a_pwm_record_without_coil_voltage_runs_the_electronics(tmp_path: Path) -> None:
    from valve_model_pkg.cli.simulate import main
    out = tmp_path / 'pwm.csv'
    assert main(['--experiment', 'pwm', '--duration', '0.06', '--sample-rate', '20000',
                 '-o', str(out), '--no-plot', '-q']) == 0
    text = out.read_text().splitlines()
    header = [i for i, ln in enumerate(text) if not ln.startswith('#')][0]
    cols = text[header].split(',')
    keep = [cols.index(c) for c in ('t', 'voltage', 'current')]
    rows = [','.join(r.split(',')[k] for k in keep) for r in text[header + 1:]]
    bare = tmp_path / 'main_only.csv'
    bare.write_text('\n'.join(text[:header] + ['t,voltage,current'] + rows) + '\n')
    m = read_csv(bare)
    assert m.through_electronics
    np.testing.assert_allclose(m.drive.period_starts_s[:3], [0.0, 0.02, 0.04], atol=1e-9)
    np.testing.assert_allclose(m.drive.period_duty[:2], 0.4, atol=1e-3)
