"""valve_simulate: CSV in the shared format, PNG, paper figures read back, input errors."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from valve_model_pkg.cli.simulate import main

STROKE_M = 0.33e-3
PKG_ROOT = Path(__file__).resolve().parents[2] / 'valve_model_pkg'


def read_csv(path: Path) -> tuple[dict[str, str], list[str], np.ndarray]:
    meta: dict[str, str] = {}
    lines = path.read_text(encoding='utf-8').splitlines()
    k = 0
    while lines[k].startswith('#'):
        key, _, value = lines[k][1:].partition(':')
        meta[key.strip()] = value.strip()
        k += 1
    header = lines[k].split(',')
    data = np.array([[float(v) for v in line.split(',')] for line in lines[k + 1:]])
    return meta, header, data


def _stroke_figures(data: np.ndarray) -> tuple[float, float, float]:
    t, i, x = data[:, 0], data[:, 2], data[:, 3]
    start = t[np.argmax(x > 0.0)]
    end_k = int(np.argmax(x >= 0.999 * STROKE_M))
    k0 = int(np.argmax(x > 0.0))
    return float(start), float(t[end_k]), float(i[k0:end_k + 1].max())


def test_step_24v_reproduces_fig4_from_csv(tmp_path: Path, capsys) -> None:
    out = tmp_path / 'fig4.csv'
    assert main(['--experiment', 'step', '--voltage', '24', '--out', str(out)]) == 0
    meta, header, data = read_csv(out)
    assert header == ['t', 'voltage', 'current', 'position']
    assert meta['experiment'] == 'step'
    assert float(meta['supply_pressure_pa']) == 4.0e5
    assert float(meta['sample_rate_hz']) == 1.0e5
    assert np.all(np.diff(data[:, 0]) > 0) and data[0, 0] == 0.0
    start, end, peak = _stroke_figures(data)
    assert 2.0e-3 <= start <= 3.0e-3
    assert end == pytest.approx(3.7e-3, rel=0.10)
    assert peak == pytest.approx(0.64, rel=0.05)
    assert (tmp_path / 'fig4.png').stat().st_size > 10_000
    err = capsys.readouterr().err
    assert 'stroke ends' in err and 'Traceback' not in err


def test_step_15v_opens_later_with_smaller_peak(tmp_path: Path) -> None:
    figs = {}
    for volts in ('24', '15'):
        out = tmp_path / f's{volts}.csv'
        assert main(['--voltage', volts, '--supply-bar', '4', '--out', str(out),
                     '--no-plot', '-q']) == 0
        figs[volts] = _stroke_figures(read_csv(out)[2])
        assert not (tmp_path / f's{volts}.png').exists()
    assert figs['15'][1] > figs['24'][1] + 1e-3
    assert figs['15'][2] < figs['24'][2]


def test_pwm_writes_duty_and_mass_flow(tmp_path: Path) -> None:
    out = tmp_path / 'fig6.csv'
    assert main(['--experiment', 'pwm', '--duty', '0.4', '--pwm-frequency', '50',
                 '--duration', '0.06', '--sample-rate', '50000', '--out', str(out)]) == 0
    meta, header, data = read_csv(out)
    # the measured-data format's pwm record: voltage = main PWM input, coil_voltage = coil
    assert header == ['t', 'voltage', 'coil_voltage', 'current', 'position', 'duty',
                      'mass_flow']
    assert meta['experiment'] == 'pwm' and float(meta['pwm_frequency_hz']) == 50.0
    assert np.all(data[:, 5] == 0.4)
    assert data[:, 6].max() > 0.0 and data[:, 6].min() >= 0.0
    t, i = data[:, 0], data[:, 3]
    hold = (t > 0.046) & (t < 0.048)
    np.testing.assert_allclose(i[hold], 0.5, rtol=0.05)
    assert data[:, 2].min() < -20.0  # the capacitor pulse, at the coil terminals
    on = np.mod(t + 1e-12, 0.02) < 0.4 * 0.02
    np.testing.assert_array_equal(data[:, 1], np.where(on, 24.0, 0.0))  # main PWM input
    assert (tmp_path / 'fig6.png').exists()


def test_pwm_mass_flow_uses_the_mean_over_the_last_complete_period(tmp_path: Path) -> None:
    """The suite's per-period moving average (as the simulator node publishes it): the
    mean position over the last complete PWM period, 0 before the first period ends."""
    from valve_model_pkg.model import PeriodAverager, load_parameters, orifice_mass_flow

    out = tmp_path / 'avg.csv'
    assert main(['--experiment', 'pwm', '--duty', '0.4', '--pwm-frequency', '50',
                 '--duration', '0.07', '--sample-rate', '20000', '--out', str(out),
                 '--no-plot', '-q']) == 0
    meta, _, data = read_csv(out)
    t, x, flow = data[:, 0], data[:, 4], data[:, 6]
    assert np.all(flow[t < 0.02 - 1e-9] == 0.0)
    # constant inside each period, changing only at period ends
    for k in range(1, 3):
        inside = (t >= 0.02 * k + 1e-9) & (t < 0.02 * (k + 1) - 1e-9)
        assert np.ptp(flow[inside]) == 0.0
    # the streaming averager on the written positions gives the same means
    avg = PeriodAverager(0.02)
    streamed = np.array([avg.update(tt, xx) for tt, xx in zip(t, x)])
    expected = orifice_mass_flow(streamed, float(meta['supply_pressure_pa']),
                                 float(meta['output_pressure_pa']), load_parameters())
    np.testing.assert_allclose(flow, expected, rtol=1e-6, atol=1e-12)
    assert flow[-1] > 0.0


def test_no_capacitor_option(tmp_path: Path) -> None:
    out = tmp_path / 'nc.csv'
    assert main(['--experiment', 'pwm', '--no-capacitor', '--duration', '0.02',
                 '--out', str(out), '--no-plot', '-q']) == 0
    meta, header, data = read_csv(out)
    assert meta['capacitor'] == 'false'
    assert data[:, header.index('coil_voltage')].min() == 0.0


def test_electronics_file_sets_the_drive(tmp_path: Path) -> None:
    """A reduced-voltage hold: the mean hold current is V_supply * duty / R."""
    out = tmp_path / 'pwm.csv'
    driver = PKG_ROOT / 'config' / 'electronics' / 'reduced_pwm_hold.yaml'
    assert main(['--experiment', 'pwm', '--duty', '1', '--duration', '0.1',
                 '--electronics', str(driver), '--out', str(out), '--no-plot', '-q']) == 0
    meta, header, data = read_csv(out)
    assert meta['electronics'] == str(driver)
    t, i = data[:, 0], data[:, header.index('current')]
    last = t > 0.09  # 10 ms: 200 whole chopper periods
    assert i[last].mean() == pytest.approx(24.0 * 0.3 / 13.0, rel=0.01)
    # a step through the same drive: the timer's 5 ms of supply, then the chopper
    assert main(['--electronics', str(driver), '--out', str(out), '--no-plot', '-q']) == 0
    _, header, data = read_csv(out)
    volts = data[:, header.index('voltage')]
    assert np.all(volts[data[:, 0] < 5e-3 - 1e-9] == 24.0)
    assert np.any(volts[data[:, 0] > 5e-3] == 0.0)


def test_a_bad_electronics_file_exits_2_naming_file_line_and_key(tmp_path: Path,
                                                                 capsys) -> None:
    bad = tmp_path / 'driver.yaml'
    bad.write_text('electronics:\n  hold: pi\n  release: varistor\n')
    assert main(['--electronics', str(bad), '--out', str(tmp_path / 'x.csv')]) == 2
    err = capsys.readouterr().err
    assert f"{bad}:3: release must be one of" in err and "'varistor'" in err
    assert 'Traceback' not in err


@pytest.mark.parametrize('argv, message', [
    (['--duty', '1.5', '--experiment', 'pwm'], 'duty must be in [0, 1], got 1.5'),
    (['--duration', '-1'], '--duration must be positive'),
    (['--voltage', 'abc'], "argument --voltage: not a number: 'abc'"),
    (['--voltage', 'nan'], 'must be finite'),
    (['--experiment', 'ramp'], "invalid choice: 'ramp'"),
    (['--params', '/nonexistent/valve.yaml'], 'No such file'),
    (['--supply-bar', '4', '--supply-pressure', '4e5'], 'not allowed with argument'),
    (['--pwm-frequency', '0', '--experiment', 'pwm'], 'pwm_frequency_hz must be positive'),
])
def test_bad_input_exits_2_with_a_message(tmp_path: Path, capsys, argv: list[str],
                                          message: str) -> None:
    try:
        code = main(argv + ['--out', str(tmp_path / 'x.csv'), '--no-plot'])
    except SystemExit as exc:  # argparse
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err
    assert message in err
    assert 'Traceback' not in err


def test_bad_parameter_file_is_reported(tmp_path: Path, capsys) -> None:
    bad = tmp_path / 'bad.yaml'
    src = (PKG_ROOT / 'config' / 'valve.yaml').read_text()
    bad.write_text(src.replace('spool_mass_kg: 0.027', 'spool_mass_kg: -0.027'))
    assert main(['--params', str(bad), '--out', str(tmp_path / 'x.csv')]) == 2
    assert 'spool_mass_kg must be positive, got -0.027' in capsys.readouterr().err


def test_console_entry_runs_as_a_process(tmp_path: Path) -> None:
    code = ('import sys; sys.path.insert(0, %r); from valve_model_pkg.cli.simulate import '
            'main; sys.exit(main())' % str(PKG_ROOT))
    bad = subprocess.run([sys.executable, '-c', code, '--duty', '7', '--experiment', 'pwm',
                          '--out', str(tmp_path / 'y.csv')], capture_output=True, text=True)
    assert bad.returncode == 2
    assert 'Traceback' not in bad.stderr and 'duty must be in [0, 1]' in bad.stderr
