"""Identification and closing the loop, on data from the independent truth model.

The data come from ``tests/datagen`` (its own model, integrated with solve_ivp, with every
listed effect in a form of its own and one effect outside the list), with bench noise
(0.5 % of full scale, 12-bit) and missing samples, on valve instances that differ from
Table 2. The identification runs with its reduced test effort (``IdentifySettings(quick=True)``).
The effect outside the list (``supply_ripple``) is checked in test_ident_unlisted.py, on the
one run of that case both files need.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from datagen.cache import dataset
from datagen.generate import LISTED_EFFECTS
from valve_model_pkg.identification import IdentifySettings, identify
from valve_model_pkg.identification.csv_reader import read_csv
from valve_model_pkg.identification.problem import equivalent_gap_m
from valve_model_pkg.model.parameters import load_parameters

# Truth-model field -> ValveParameters field, for the Table 2 comparison.
_TRUTH_FIELDS = {
    'coil_resistance_ohm': 'resistance_ohm', 'stroke_m': 'stroke_m',
    'core_area_m2': 'flux_area_m2', 'spring_pretension_m': 'pretension_m',
    'damping_n_s_per_m': 'damping_n_s_m', 'core_length_m': 'core_length_m',
    'total_air_gap_m': 'total_gap_m', 'relative_permeability': 'mu_r',
}


# Every test is one identification run of its own (12-45 s on 2 cores): pytest-xdist
# spreads them over its workers (tests/conftest.py).
pytestmark = pytest.mark.spread


@pytest.fixture(scope='module')
def data_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.getbasetemp() / 'valve-data'


def _run(truth: dict) -> object:
    # the front door reads the records from their paths
    return identify(truth['fit'], truth['validate'], IdentifySettings(quick=True))


def test_recovers_table2_from_a_noisy_24v_step_and_validates_at_15v(data_dir: Path) -> None:
    truth = dataset(data_dir, 'paper')
    fit = [read_csv(f) for f in truth['fit']]
    val = [read_csv(f) for f in truth['validate']]
    ident = identify(fit, val, IdentifySettings(quick=True, diagnose=False))
    p = ident.baseline.params
    sens = ident.baseline.sensitivity
    tv = truth['valve']
    # Every parameter the current is sensitive to comes back within 5 %.
    assert {'coil_resistance_ohm', 'stroke_m', 'core_area_m2',
            'spring_pretension_m'} <= set(sens.pinned)
    for name in sens.pinned:
        if name == 'equivalent_gap_m':
            true = tv['core_length_m'] / tv['mu_r'] + 2 * tv['total_gap_m']
            got = equivalent_gap_m(p)
        else:
            true, got = tv[_TRUTH_FIELDS[name]], getattr(p, name)
        assert got == pytest.approx(true, rel=0.05), name
    # The ones the data cannot pin down are named, not hidden.
    for name in ('damping_n_s_per_m', 'core_length_m', 'relative_permeability',
                 'total_air_gap_m'):
        assert name in sens.not_pinned
    assert sens.weak_directions
    # The 15 V step validates: its error is the bench noise.
    noise = truth['noise']['std_a']
    assert ident.baseline.validation.rmse < 1.15 * noise
    assert ident.baseline.fit.rmse < 1.15 * noise


@pytest.mark.parametrize('case', ['none'] + [e for e in LISTED_EFFECTS if e not in (
    'eddy_current', 'coil_heating')])
def test_diagnosis_names_the_effect_and_lowers_the_validation_error(data_dir: Path,
                                                                    case: str) -> None:
    truth = dataset(data_dir, case)
    ident = _run(truth)
    d = ident.diagnosis
    if case == 'none':
        assert d.effect == 'none'
        assert ident.augmented.params == ident.baseline.params
        return
    assert d.effect == case, [c.to_json() for c in d.candidates]
    assert ident.augmented.validation.rmse < ident.baseline.validation.rmse
    assert d.confidence in ('high', 'medium')


def test_coil_heating_needs_and_finds_the_long_record(data_dir: Path) -> None:
    truth = dataset(data_dir, 'coil_heating')
    assert any('long' in f for f in truth['fit'])
    ident = _run(truth)
    assert ident.diagnosis.effect == 'coil_heating'
    assert ident.augmented.validation.rmse < ident.baseline.validation.rmse
    assert ident.augmented.params.thermal_resistance_k_per_w > 0.0


def test_command_line_writes_the_report_as_named(data_dir: Path, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture) -> None:
    from valve_model_pkg.cli.identify import main

    truth = dataset(data_dir, 'eddy_current')
    out = tmp_path / 'report'
    rc = main(['--fit', *truth['fit'], '--validate', *truth['validate'], '--out', str(out),
               '--quick'])
    assert rc == 0
    err = capsys.readouterr().err
    assert 'baseline' in err and 'diagnosis' in err          # progress was shown
    rep = json.loads((out / 'report.json').read_text())
    for block in ('baseline', 'augmented'):
        assert set(rep[block]['parameters']) >= set(_TRUTH_FIELDS)
        for role in ('fit', 'validation'):
            for key in ('iae', 'rmse', 'nrmse_pct'):
                assert math.isfinite(rep[block][role][key])
    d = rep['diagnosis']
    assert d['effect'] == 'eddy_current'
    assert d['evidence'] and len(d['candidates']) == len(LISTED_EFFECTS)
    assert all('validation_error_reduction_pct' in c for c in d['candidates'])
    assert rep['augmented']['validation']['rmse'] < rep['baseline']['validation']['rmse']
    # params.yaml closes the loop: the model loads it, with the effect switched on.
    p = load_parameters(out / 'params.yaml')
    assert p.eddy_conductance_s > 0.0
    assert p.coil_resistance_ohm == pytest.approx(
        rep['augmented']['parameters']['coil_resistance_ohm'])
    md = (out / 'report.md').read_text()
    assert 'eddy_current' in md and '.png' in md
    assert len(list(out.glob('*.png'))) == 2


def test_command_line_refuses_malformed_input(tmp_path: Path,
                                              capsys: pytest.CaptureFixture) -> None:
    from valve_model_pkg.cli.identify import main

    bad = tmp_path / 'bad.csv'
    bad.write_text('# supply_pressure_pa: 4e5\nt,voltage,current\n' + '0,0,0\n' * 5
                   + '1,x,0\n', encoding='utf-8')
    assert main(['--fit', str(bad), '--out', str(tmp_path / 'o')]) == 2
    assert f'{bad}:8' in capsys.readouterr().err
    nopress = tmp_path / 'nopress.csv'
    nopress.write_text('t,voltage,current\n' + ''.join(f'{k}e-5,24,0\n' for k in range(20)),
                       encoding='utf-8')
    assert main(['--fit', str(nopress), '--out', str(tmp_path / 'o')]) == 2
    assert 'supply_pressure_pa' in capsys.readouterr().err


def test_generator_is_independent_and_differs_from_table2(data_dir: Path) -> None:
    src = (Path(__file__).resolve().parents[1] / 'datagen' / 'truth.py').read_text()
    assert 'valve_model_pkg' not in src.replace('``valve_model_pkg``', '')
    truth = dataset(data_dir, 'none')
    tv = truth['valve']
    assert abs(tv['resistance_ohm'] / 13.0 - 1.0) > 1e-3
    rows = Path(truth['fit'][0]).read_text().splitlines()
    assert rows[0].startswith('# experiment: step')
    currents = np.array([float(r.split(',')[2]) for r in rows[8:] if r.split(',')[2]])
    lsb = 5.0 / 4096
    # 6 significant digits in the file: the codes come back to within 0.01 LSB
    np.testing.assert_allclose(currents / lsb, np.round(currents / lsb), atol=1e-2)
