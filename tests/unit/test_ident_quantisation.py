"""Coarse instruments: a quantised current is a normal record.

The noise model counts the quantisation: a rounding error uniform over one step has the
variance LSB^2 / 12, so ``sigma^2 = noise^2 + LSB^2 / 12``. The step reaches the
Measurement from the record's header (``current_lsb_a``, written by ``valve_import``) or
from the grid its values lie on. Records of the independent truth model (tests/datagen)
quantised to 8 bits (16 mA steps): a clean one is answered ``none`` with its intervals
wider than those of the same record unquantised, an effect well above the steps is named
(three quick identification runs, shared: marked slow).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from datagen.cache import step_dataset
from datagen.exports import scope_trace, write_rigol
from datagen.truth import TruthValve
from valve_model_pkg.cli.import_record import main as valve_import
from valve_model_pkg.errors import MeasurementFormatError
from valve_model_pkg.identification import IdentifySettings, identify, read_measurements
from valve_model_pkg.identification.measurement import Measurement, with_current_lsb
from valve_model_pkg.identification.sensitivity import noise_estimate

LSB_A = 0.016


def _rl_current(n: int = 4000, rate_hz: float = 50e3) -> np.ndarray:
    """A smooth coil current: 24 V on 13 ohm, tau 7 ms [A]."""
    t = np.arange(n) / rate_hz
    return 24.0 / 13.0 * (1.0 - np.exp(-t / 7e-3))


@pytest.mark.parametrize('noise_over_lsb', [0.0, 0.1, 0.3, 1.0, 3.0])
def test_the_noise_model_is_the_noise_plus_a_twelfth_of_the_squared_step(
        noise_over_lsb: float) -> None:
    clean = _rl_current()
    rng = np.random.default_rng(3)
    sigma = noise_over_lsb * LSB_A
    measured = np.round((clean + rng.normal(0.0, sigma, clean.size)) / LSB_A) * LSB_A
    est = noise_estimate(measured - clean, LSB_A)
    expected = math.sqrt(sigma ** 2 + LSB_A ** 2 / 12.0)
    # never below (rounding would read as structure), conservative by at most a quarter
    # where the noise half-dithers the steps, right where it dithers them fully
    assert 0.97 * expected <= est.std_a <= (1.3 if noise_over_lsb < 1.0 else 1.1) * expected
    if noise_over_lsb == 0.0:
        assert est.quantisation_share > 0.7
    if noise_over_lsb >= 3.0:
        assert est.quantisation_share < 0.02


def test_without_the_step_the_noise_of_a_clean_quantised_record_is_missed() -> None:
    clean = _rl_current()
    residual = np.round(clean / LSB_A) * LSB_A - clean
    rounding_rms = LSB_A / math.sqrt(12.0)
    assert noise_estimate(residual).std_a < 0.5 * rounding_rms
    assert noise_estimate(residual, LSB_A).std_a >= rounding_rms


def _measurement(current: np.ndarray, **metadata: str) -> Measurement:
    t = np.arange(current.size) / 50e3
    return Measurement(source='bench/step.csv', t_s=t, voltage_v=np.full(t.size, 24.0),
                       current_a=current, supply_pressure_pa=4e5, experiment='step',
                       metadata=dict(metadata))


def test_the_step_comes_from_the_header_else_from_the_grid_of_the_values() -> None:
    quantised = np.round(_rl_current() / LSB_A) * LSB_A
    found = with_current_lsb(_measurement(quantised))
    assert found.current_lsb_a == pytest.approx(LSB_A, rel=1e-6)
    assert any('grid of 16 mA' in n for n in found.notes)
    stated = with_current_lsb(_measurement(quantised, current_lsb_a='0.012'))
    assert stated.current_lsb_a == pytest.approx(0.012)
    assert any('header current_lsb_a' in n for n in stated.notes)
    none_found = with_current_lsb(_measurement(
        quantised, current_resolution='no quantisation grid found in the samples'))
    assert none_found.current_lsb_a == 0.0
    noisy = _rl_current() + np.random.default_rng(1).normal(0.0, 3e-3, 4000)
    assert with_current_lsb(_measurement(noisy)).current_lsb_a == 0.0


def test_too_few_distinct_values_leave_the_step_unknown() -> None:
    five_levels = np.repeat(np.arange(5) * LSB_A, 800)
    m = with_current_lsb(_measurement(five_levels))
    assert m.current_lsb_a == 0.0
    assert any('only 5 distinct values' in n for n in m.notes)


def test_a_header_step_that_is_no_positive_number_is_refused_naming_it() -> None:
    with pytest.raises(MeasurementFormatError, match=r'bench/step.csv.*current_lsb_a.*-1'):
        with_current_lsb(_measurement(_rl_current(), current_lsb_a='-1'))


def test_an_8bit_rigol_export_brings_its_step_to_the_measurement(tmp_path: Path) -> None:
    export = tmp_path / 'NewFile1.csv'
    write_rigol(export, scope_trace(TruthValve(), dt_s=10e-6, noise_a=1e-3, seed=2),
                current_lsb_a=LSB_A)
    record = tmp_path / 'step.csv'
    assert valve_import([str(export), '--voltage', 'CH1', '--current', 'CH2',
                         '--current-scale', '10', '--supply-pressure-pa', '4e5',
                         '--decimate', '1', '-o', str(record), '--quiet']) == 0
    (m,) = read_measurements([record])
    assert m.current_lsb_a == pytest.approx(LSB_A, rel=0.02)
    assert any('header current_lsb_a' in n for n in m.notes)


# --- identification of quantised step records ---------------------------------------------
@pytest.fixture(scope='module')
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """One quick identification per record: clean, quantised and unquantised (one draw of
    the noise), and quantised with eddy currents. The unquantised record is judged only by
    its baseline's intervals, which the diagnosis does not touch: it runs without one.

    The tests that judge them share one xdist group: a slow test is a work unit of its
    own (tests/conftest.py), and units on two workers would each build this fixture.
    """
    base = tmp_path_factory.mktemp('quantised')
    out = {}
    for key, effect, lsb, diagnose in (('quantised', 'none', LSB_A, True),
                                       ('unquantised', 'none', 0.0, False),
                                       ('eddy', 'eddy_current', LSB_A, True)):
        truth = step_dataset(base, seed=1, effect=effect, noise_a=0.5e-3, lsb_a=lsb)
        out[key] = identify(truth['fit'], truth['validate'],
                            IdentifySettings(quick=True, seed=1, diagnose=diagnose))
    return out


@pytest.mark.slow
@pytest.mark.xdist_group('quantised_runs')
def test_a_clean_quantised_record_is_answered_none(runs: dict) -> None:
    ident = runs['quantised']
    assert ident.diagnosis.effect == 'none'
    assert not ident.diagnosis.unexplained_structure
    sens = ident.baseline.sensitivity
    assert sens.current_lsb_a
    assert all(v == pytest.approx(LSB_A) for v in sens.current_lsb_a.values())
    # the noise is 0.5 mA, the rounding 4.6 mA RMS: most of the variance is rounding (the
    # differences of the residual see part of the rounding as noise: conservative)
    assert sens.quantisation_share > 0.5
    assert any('quantised in steps of 16 mA' in n for n in sens.notes)


@pytest.mark.slow
@pytest.mark.xdist_group('quantised_runs')
def test_the_intervals_widen_with_the_quantisation(runs: dict) -> None:
    coarse = runs['quantised'].baseline.sensitivity.ci95_pct
    fine = runs['unquantised'].baseline.sensitivity.ci95_pct
    for name in ('coil_resistance_ohm', 'equivalent_gap_m', 'stroke_m'):
        assert coarse[name] > 2.0 * fine[name], name


@pytest.mark.slow
@pytest.mark.xdist_group('quantised_runs')
def test_an_effect_well_above_the_quantisation_is_named(runs: dict) -> None:
    assert runs['eddy'].diagnosis.effect == 'eddy_current'
