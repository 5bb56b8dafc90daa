"""Bench ``pwm`` records through the drive electronics: where they start and how their
current is compared (identification/pwm_compare.py).

* A record cut out of running operation (the second half of a split record) starts with
  current in the coil; the model starts at rest, so its first periods are left out of the
  errors, and a clean record of the suite's simulator split in halves is fitted to well
  below 2 % NRMSE on its held-out half, sample by sample (100 kHz follows the 20 kHz
  chopper). That record comes from ``valve_simulate`` on purpose: the test judges whether
  identification reproduces the suite's own simulator, as the demo's bag is judged.
* A record whose samples cannot follow the chopper's phase (the independent generator's
  20 kHz PI chopper or its clocked hysteresis regulator, sampled at 20 kHz) is compared in
  interval means, and the report says so; a leakage inductance (20 mH, the generator's
  size) is then named through the chopper, and a clean record is answered ``none``.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from datagen.cache import pwm_dataset
from valve_model_pkg.cli.identify import main as identify_main
from valve_model_pkg.identification.csv_reader import read_csv
from valve_model_pkg.identification.measurement import DriveInput, Measurement
from valve_model_pkg.identification.pwm_compare import (
    COMPARISON_KEY, SAMPLES_PER_CHOPPER_PERIOD, chopper_followed, interval_means,
    pwm_comparison, starts_in_motion,
)
from valve_model_pkg.model import ElectronicsConfig

NOISE_A = 3e-3


def _pwm_measurement(rate_hz: float, current: np.ndarray | None = None,
                     t0: float = 0.0) -> Measurement:
    """A 60 ms pwm record at ``rate_hz``: main PWM 50 Hz, duty 0.4, from ``t0``."""
    n = int(round(0.06 * rate_hz))
    t = t0 + np.arange(n) / rate_hz
    drive = DriveInput.from_periods([t0, t0 + 0.02, t0 + 0.04], [0.4] * 3, [50.0] * 3, 24.0)
    i = np.full(n, 0.5) if current is None else current
    return Measurement(source='synthetic.csv', t_s=t, voltage_v=drive.main_pwm_level(t),
                       current_a=i, supply_pressure_pa=4e5, experiment='pwm', drive=drive)


def test_interval_means_are_block_means_over_the_intervals_they_end() -> None:
    rate = 20e3
    n = int(round(0.06 * rate))
    rng = np.random.default_rng(3)
    cur = rng.normal(0.5, 0.01, n)
    cur[7] = np.nan
    m = interval_means(_pwm_measurement(rate, cur), 0.5e-3)
    assert m.sampling == 'interval_mean' and m.current_lsb_a == 0.0
    assert m.t_s.size == n // 10
    # each mean ends half a sample after its last sample: the intervals tile the record
    assert np.allclose(np.diff(m.t_s), 0.5e-3)
    assert m.t_s[0] == pytest.approx(9.5 / rate)
    assert m.current_a[0] == pytest.approx(np.nanmean(cur[:10]))
    assert m.current_a[5] == pytest.approx(np.mean(cur[50:60]))
    # the first interval only opens the comparison
    assert not m.valid[0] and m.valid[1:].all()
    assert m.metadata[COMPARISON_KEY] == 'interval_means'
    assert np.all(m.voltage_v[(m.t_s > 0.001) & (m.t_s < 0.007)] == 24.0)


def test_the_chopper_is_followed_only_with_enough_samples_per_period() -> None:
    pi = ElectronicsConfig()
    assert chopper_followed(_pwm_measurement(SAMPLES_PER_CHOPPER_PERIOD
                                             * pi.chopper_frequency_hz), pi)
    assert not chopper_followed(_pwm_measurement(50e3), pi)
    assert pwm_comparison(_pwm_measurement(100e3)).sampling == 'instant'
    assert pwm_comparison(_pwm_measurement(20e3)).sampling == 'interval_mean'
    # a record of another kind is left as it is
    step = Measurement(source='s.csv', t_s=np.arange(100) * 1e-5, voltage_v=np.ones(100),
                       current_a=np.zeros(100), supply_pressure_pa=4e5, experiment='step')
    assert pwm_comparison(step) is step


def test_a_record_cut_from_running_operation_leaves_out_its_first_periods() -> None:
    rate = 100e3
    n = int(round(0.06 * rate))
    running = _pwm_measurement(rate, np.full(n, 0.14), t0=0.1)
    assert starts_in_motion(running)
    m = pwm_comparison(running)
    assert m.exclude_before_s == pytest.approx(0.1 + 0.06)
    assert any('in motion' in note for note in m.notes)
    cur = np.concatenate((np.zeros(10), np.full(n - 10, 0.5)))
    at_rest = pwm_comparison(_pwm_measurement(rate, cur))
    assert not starts_in_motion(at_rest) and at_rest.exclude_before_s == 0.0


@pytest.fixture(scope='module')
def clean_halves(tmp_path_factory) -> tuple[Path, Path]:
    """A clean 0.2 s pwm record of valve_simulate (100 kHz, electronics on) in halves."""
    from valve_model_pkg.cli.simulate import main as simulate_main
    d = tmp_path_factory.mktemp('pwm_halves')
    whole = d / 'whole.csv'
    assert simulate_main(['--experiment', 'pwm', '--duration', '0.2', '-o', str(whole),
                          '--no-plot', '-q']) == 0
    lines = whole.read_text(encoding='utf-8').splitlines()
    head = next(k for k, line in enumerate(lines) if not line.startswith('#')) + 1
    body = lines[head:]
    half = len(body) // 2
    fit, val = d / 'fit.csv', d / 'validate.csv'
    fit.write_text('\n'.join(lines[:head] + body[:half]) + '\n', encoding='utf-8')
    val.write_text('\n'.join(lines[:head] + body[half:]) + '\n', encoding='utf-8')
    return fit, val


def test_the_held_out_half_starts_in_motion(clean_halves: tuple[Path, Path]) -> None:
    fit, val = (pwm_comparison(read_csv(p)) for p in clean_halves)
    assert not starts_in_motion(fit) and fit.exclude_before_s == 0.0
    assert starts_in_motion(val) and val.exclude_before_s > val.t_s[0]
    assert fit.sampling == val.sampling == 'instant'


def test_a_coil_voltage_sampled_in_step_with_the_chopper_is_not_a_bare_coil_input(
        tmp_path: Path) -> None:
    # at 20 kHz every sample of the 20 kHz chopper falls in its on-time: the column reads
    # 24 V throughout the hold while the current is held at 0.5 A
    from valve_model_pkg.cli.simulate import main as simulate_main
    path = tmp_path / 'pwm20k.csv'
    assert simulate_main(['--experiment', 'pwm', '--duration', '0.06', '--sample-rate',
                          '20000', '-o', str(path), '--no-plot', '-q']) == 0
    m = read_csv(path)
    assert m.through_electronics
    assert any('miss the chopper' in n for n in m.notes)
    assert pwm_comparison(m).sampling == 'interval_mean'


def _identify(fit: Path, val: Path, out: Path, *extra: str) -> dict:
    assert identify_main(['--fit', str(fit), '--validate', str(val), '-o', str(out),
                          '--no-plots', '--quiet', *extra]) == 0
    return json.loads((out / 'report.json').read_text(encoding='utf-8'))


@pytest.mark.slow
def test_a_clean_pwm_record_split_in_halves_is_fitted_below_2_pct(
        clean_halves: tuple[Path, Path], tmp_path: Path) -> None:
    rep = _identify(*clean_halves, tmp_path / 'rep', '--no-diagnosis')
    assert rep['baseline']['validation']['nrmse_pct'] < 2.0
    assert rep['current_comparison']['kind'] == 'samples'
    assert 'sample by sample' in (tmp_path / 'rep' / 'report.md').read_text(encoding='utf-8')


def _generated(base: Path, effect: str, electronics: str | None) -> tuple[Path, Path]:
    fit = pwm_dataset(base, seed=21, effect=effect, noise_a=NOISE_A, duration_s=0.4,
                      electronics=electronics)
    val = pwm_dataset(base, seed=22, effect=effect, noise_a=NOISE_A, duration_s=0.3,
                      electronics=electronics)
    return Path(fit['file']), Path(val['file'])


@pytest.mark.slow
def test_leakage_through_the_chopper_is_named(tmp_path: Path) -> None:
    # the generator's PI chopper close to the suite's driver (20 kHz, sampled at 20 kHz)
    rep = _identify(*_generated(tmp_path, 'leakage_inductance', 'suite_like'),
                    tmp_path / 'rep')
    assert rep['current_comparison']['kind'] == 'interval_means'
    assert rep['diagnosis']['effect'] == 'leakage_inductance'
    assert rep['augmented']['validation']['rmse'] < 0.8 * rep['baseline']['validation']['rmse']
    assert 'interval means' in (tmp_path / 'rep' / 'report.md').read_text(encoding='utf-8')


@pytest.mark.slow
def test_a_clean_generated_pwm_record_is_answered_none(tmp_path: Path) -> None:
    # the generator's own driver: a clocked hysteresis regulator, sampled at its clock
    rep = _identify(*_generated(tmp_path, 'none', None), tmp_path / 'rep')
    assert rep['current_comparison']['kind'] == 'interval_means'
    assert rep['diagnosis']['effect'] == 'none'
