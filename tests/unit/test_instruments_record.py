"""The record an import writes: the step found, the decimation rule, pwm/operation records,
and valve_identify's handling of exports given without channels.

Signals here are written out analytically (an RL coil, a PWM): the rules of the importer,
not the valve's physics, are under test.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from valve_model_pkg import dataformat
from valve_model_pkg.cli.identify import main as valve_identify
from valve_model_pkg.cli.import_record import main as valve_import
from valve_model_pkg.instruments import infer_lsb
from valve_model_pkg.instruments.record import find_step


def _plain(path: Path, t: np.ndarray, v: np.ndarray, i: np.ndarray) -> Path:
    rows = [f'{a:.9g};{b:.9g};{c:.9g}' for a, b, c in zip(t, v, i)]
    path.write_text('\n'.join(['Zeit (s);U (V);I (A)'] + rows) + '\n', encoding='utf-8')
    return path


def _rl(t: np.ndarray, tau_s: float, volts: float = 24.0, ohm: float = 12.0) -> np.ndarray:
    return np.where(t >= 0.0, volts / ohm * (1.0 - np.exp(-np.maximum(t, 0.0) / tau_s)), 0.0)


def test_the_step_is_found_after_a_short_pre_trigger() -> None:
    v = np.full(100_000, 24.0)
    v[:40] = 0.0  # 0.04 % of the record before the step
    v[5000] = 0.0  # a one-sample glitch later is not a step
    step = find_step(v)
    assert step is not None and step.index == 40
    assert step.before_v == 0.0 and step.after_v == 24.0
    assert find_step(np.full(1000, 12.0) + 0.1 * np.sin(np.arange(1000))) is None


def test_the_lsb_is_found_through_a_three_digit_print() -> None:
    # 8-bit codes of 1.6 mV printed with three significant digits (as a Rigol does): above
    # 0.1 V the print rounds to 1 mV, so adjacent levels print 1 or 2 mV apart and the
    # largest value is off the grid by up to 0.3 steps
    codes = np.random.default_rng(4).integers(0, 100, 20_000)
    printed = np.array([float(f'{x:.2e}') for x in codes * 1.6e-3])
    res = infer_lsb(printed)
    assert res is not None and res.lsb == pytest.approx(1.6e-3, rel=0.01)
    assert infer_lsb(np.random.default_rng(5).normal(0.5, 0.1, 20_000)) is None


def test_auto_decimation_keeps_a_fast_rise(tmp_path: Path) -> None:
    t = np.arange(-200, 4000) * 1e-6          # 1 MHz
    tau = 0.1e-3                              # rise 10-90 % = tau ln 9 = 0.22 ms
    path = _plain(tmp_path / 'log.csv', t, np.where(t >= 0, 24.0, 0.0), _rl(t, tau))
    out = tmp_path / 'rec.csv'
    assert valve_import([str(path), '--voltage', 'u', '--current', 'I', '--time', 'zeit',
                         '-o', str(out)]) == 0
    meta = dataformat.read_trace(out).metadata
    # min(20 us, 0.22 ms / 100) = 2.2 us: blocks of 2 samples of 1 us.
    assert meta['decimation'].startswith('2 (auto')
    assert 'rise 10-90 % 0.00022' in meta['decimation']


def test_an_operation_record_gets_duty_and_frequency_from_the_pwm(tmp_path: Path) -> None:
    t = np.arange(0, 200_000) * 1e-6          # 0.2 s at 1 MHz, 50 Hz PWM
    phase = (t % 0.02) / 0.02
    duty = np.where(t < 0.1, 0.3, 0.6)
    v = np.where(phase < duty, 24.0, 0.0)
    path = _plain(tmp_path / 'pwm.csv', t, v, 0.5 * v / 24.0)
    out = tmp_path / 'op.csv'
    assert valve_import([str(path), '--voltage', 'U', '--current', 'I', '--experiment',
                         'operation', '--supply-pressure-pa', '4e5', '--decimate', '100',
                         '-o', str(out)]) == 0
    rec = dataformat.read_operation(out)
    assert rec.supply_voltage_v == pytest.approx(24.0)
    inside = (rec.t_s > 0.005) & (rec.t_s < 0.095)
    np.testing.assert_allclose(rec.duty[inside], 0.3, atol=2e-6 / 0.02)
    late = (rec.t_s > 0.105) & (rec.t_s < 0.18)
    np.testing.assert_allclose(rec.duty[late], 0.6, atol=2e-6 / 0.02)
    np.testing.assert_allclose(rec.pwm_frequency_hz[inside | late], 50.0, rtol=1e-4)


def test_a_pwm_record_keeps_the_main_pwm_voltage(tmp_path: Path) -> None:
    t = np.arange(0, 50_000) * 2e-6
    v = np.where((t % 0.01) < 0.004, 24.0, 0.0)
    path = _plain(tmp_path / 'pwm.csv', t, v, 0.2 * v / 24.0)
    out = tmp_path / 'pwm_rec.csv'
    assert valve_import([str(path), '--voltage', 'U', '--current', 'I', '--experiment',
                         'pwm', '--decimate', '1', '-o', str(out)]) == 0
    rec = dataformat.read_trace(out)
    assert rec.experiment == 'pwm'
    np.testing.assert_array_equal(rec.voltage_v, v)


def test_valve_identify_names_the_channels_an_export_needs(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    t = np.arange(-100, 2000) * 20e-6
    path = _plain(tmp_path / 'log.csv', t, np.where(t >= 0, 24.0, 0.0), _rl(t, 7e-3))
    code = valve_identify(['--fit', str(path), '-o', str(tmp_path / 'report'), '--quick'])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert err[0].startswith(f'valve_identify: error: {path}: is a plain CSV with a header '
                             'row export; give --voltage CH and --current CH')
    assert 'U (V)' in err[0] and 'I (A)' in err[0]
