"""Identification through drive electronics of several forms: given (``--electronics``) or
chosen by the data (identification/electronics_family.py).

The records come from the independent truth model (tests/datagen), driven through forms of
its own electronics family (tests/datagen/electronics.py). The slow tests run one
identification each (``--quick``, no effect diagnosis).
"""
from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from datagen.cache import ELECTRONICS_PAIR_NOISE_A, electronics_pair, operation_dataset
from suite_electronics import TIMER_HYSTERESIS_ZENER_YAML
from valve_model_pkg.cli.identify import _parser, settings_from_args
from valve_model_pkg.cli.identify import main as identify_main
from valve_model_pkg.errors import ParameterError
from valve_model_pkg.identification import IdentifySettings, identify, write_report
from valve_model_pkg.identification import drive as drive_module
from valve_model_pkg.identification.drive import (
    COMPARATOR_CLOCKS_HZ, FORM_CONSTANTS, GRID_FINE_PAIRS, HYSTERESIS_BANDS_A,
    HYSTERESIS_HOLD_OFFSETS_A, form_constants, hysteresis_grid, search_constants,
)
from valve_model_pkg.identification import electronics_family
from valve_model_pkg.identification.electronics_family import (
    HOLD_OPTIONS, PEAK_OPTIONS, RELEASE_OPTIONS, FormFit, describe_form,
)
from valve_model_pkg.identification.measurement import window
from valve_model_pkg.identification.pipeline import read_inputs
from valve_model_pkg.identification.problem import FitData
from valve_model_pkg.model import ElectronicsConfig, load_electronics
from valve_model_pkg.model.electronics import HOLD_FORMS, PEAK_ENDS, RELEASES
from valve_model_pkg.model.parameters import load_parameters

NOISE_A = ELECTRONICS_PAIR_NOISE_A


def test_every_form_of_the_model_has_its_constants_and_words() -> None:
    parts = {'peak_end': PEAK_ENDS, 'hold': HOLD_FORMS, 'release': RELEASES}
    assert set(FORM_CONSTANTS) == {(p, f) for p, forms in parts.items() for f in forms}
    cfg = ElectronicsConfig(peak_end='dip_rise', hold='hysteresis', release='zener')
    assert form_constants(cfg) == ['dip_threshold_a', 'rise_threshold_a',
                                   'holding_current_a', 'hysteresis_band_a',
                                   'zener_voltage_v']
    assert form_constants(cfg.replace(negative_voltage=False), 'release') == []
    text = describe_form(ElectronicsConfig(peak_end='dip_rise', hold_decay='fast',
                                           release='capacitor_peak'))
    assert text == 'dip_rise peak end, PI hold with fast decay, capacitor (peak-charged) release'
    # the screen offers every form of each part
    assert {o['peak_end'] for o in PEAK_OPTIONS} == set(PEAK_ENDS)
    assert {o['hold'] for o in HOLD_OPTIONS} == set(HOLD_FORMS)
    assert {o['release'] for o in RELEASE_OPTIONS} == set(RELEASES)


def test_settings_read_the_description_file(tmp_path: Path) -> None:
    path = tmp_path / 'drv.yaml'
    path.write_text(TIMER_HYSTERESIS_ZENER_YAML, encoding='utf-8')
    s = IdentifySettings(electronics=str(path))
    assert s.electronics == load_electronics(path)
    assert s.electronics.hold == 'hysteresis'
    bad = tmp_path / 'bad.yaml'
    bad.write_text('electronics:\n  hold: bang_bang\n', encoding='utf-8')
    with pytest.raises(ParameterError, match=r'bad\.yaml:2.*hold'):
        IdentifySettings(electronics=str(bad))


def test_command_line_refuses_a_bad_electronics_file(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture) -> None:
    fit, _ = electronics_pair(tmp_path, 'timer_hysteresis_zener')
    bad = tmp_path / 'bad.yaml'
    bad.write_text('electronics:\n  zener_voltage_v: -3\n', encoding='utf-8')
    code = identify_main(['--fit', fit, '--electronics', str(bad), '--quiet',
                          '--out', str(tmp_path / 'o')])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and 'bad.yaml:2' in err[0]
    with pytest.raises(SystemExit) as exc:
        identify_main(['--fit', fit, '--fit-electronics', '--out', str(tmp_path / 'o')])
    assert exc.value.code == 2


@pytest.mark.parametrize('argv, expected', [([], None), (['--choose-electronics'], True),
                                            (['--choose-electronics', 'always'], True),
                                            (['--choose-electronics', 'never'], False),
                                            (['--choose-electronics', 'auto'], None)])
def test_when_the_data_choose_the_form(argv: list[str], expected: bool | None) -> None:
    args = _parser().parse_args(['--fit', 'f.csv', '-o', 'o'] + argv)
    assert settings_from_args(args).choose_electronics is expected


def test_a_forced_choice_and_a_given_form_exclude_each_other(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    fit, _ = electronics_pair(tmp_path, 'timer_hysteresis_zener')
    path = tmp_path / 'thz.yaml'
    path.write_text(TIMER_HYSTERESIS_ZENER_YAML, encoding='utf-8')
    for choice in ('always', 'never'):
        with pytest.raises(SystemExit) as exc:
            identify_main(['--fit', fit, '--electronics', str(path), '--choose-electronics',
                           choice, '--out', str(tmp_path / 'o')])
        assert exc.value.code == 2
        assert f'--choose-electronics {choice}' in capsys.readouterr().err


@pytest.mark.slow
def test_matching_description_fits_to_the_noise_where_the_paper_form_misses(
        tmp_path: Path) -> None:
    fit, val = electronics_pair(tmp_path, 'timer_hysteresis_zener')
    path = tmp_path / 'thz.yaml'
    path.write_text(TIMER_HYSTERESIS_ZENER_YAML, encoding='utf-8')
    out = tmp_path / 'given'
    ident = identify([fit], [val], IdentifySettings(electronics=str(path), quick=True,
                                                    diagnose=False))
    rep = write_report(ident, out, plots=False)
    given_rmse = rep['baseline']['validation']['rmse']
    assert given_rmse < 1.5 * NOISE_A
    assert rep['electronics_form']['form'] == describe_form(load_electronics(path))
    assert 'given' in rep['electronics_form']['source']
    assert 'timer peak end, hysteresis hold' in (out / 'report.md').read_text()
    # given constants are kept as they are, and the files beside the report reproduce the
    # validation error
    cfg = load_electronics(out / 'electronics.yaml')
    assert cfg == load_electronics(path)
    data = FitData(ident.val_files)
    data.electronics = cfg
    again = data.errors(load_parameters(out / 'params.yaml')).rmse
    assert again == pytest.approx(given_rmse, rel=1e-6)
    paper = identify([fit], [val], IdentifySettings(quick=True, diagnose=False,
                                                    choose_electronics=False))
    assert paper.baseline.validation.rmse > 3.0 * given_rmse


@pytest.mark.slow
def test_the_generators_default_circuit_is_fitted_to_the_noise(tmp_path: Path) -> None:
    # dip and rise, a hysteresis band of 20 mA clocked at 20 kHz with 0 V free-wheeling, a
    # capacitor charged while idle: the paper's form misses it by 4x the noise, and a
    # hysteresis hold from default constants does not find the clocked limit cycle
    fit, val = electronics_pair(tmp_path, 'generator_default')
    ident = identify([fit], [val], IdentifySettings(quick=True, diagnose=False,
                                                    choose_electronics=True))
    chosen = ident.drive.electronics
    assert (chosen.hold, chosen.hold_decay) == ('hysteresis', 'freewheel')
    assert chosen.release == 'capacitor'
    assert ident.electronics_source == 'chosen by the data: ' + describe_form(chosen)
    assert ident.baseline.validation.rmse < 1.5 * NOISE_A


@pytest.mark.slow
def test_the_data_choose_the_form(tmp_path: Path) -> None:
    # a current-threshold peak end, an open-loop 20 kHz PWM hold (duty 0.3, -0.7 V off)
    # and a freewheel diode: each of these alone, the other parts at the paper's driver,
    # fits worse than the paper's form, and a capacitor's two constants absorb a wrong
    # valve that the diode cannot; the paper's form misses these records by 50x the noise,
    # which lets the data choose the form without being asked (the default, auto)
    fit, val = electronics_pair(tmp_path, 'threshold_pwm_freewheel')
    ident = identify([fit], [val], IdentifySettings(quick=True, diagnose=False))
    trigger = ident.electronics_trigger
    assert trigger is not None and trigger['went_on'] == 'choice'
    assert trigger['paper_structured_a'] > 10.0 * NOISE_A          # the paper's form misfits
    assert trigger['chosen_structured_a'] < 1.0 * NOISE_A
    assert 'the data were let choose the form' in ident.notes[0]
    assert 'they chose current-threshold peak end' in ident.notes[0]
    fam = ident.family
    assert fam is not None and len(fam.forms) >= 3
    assert all(math.isfinite(f.search_cost) for f in fam.forms)
    chosen = ident.drive.electronics
    assert 'chosen by the data' in ident.electronics_source
    assert chosen.hold == 'pwm' and chosen.hold_decay in ('freewheel', 'diode')
    assert chosen.release == 'diode'
    assert 'open-loop PWM hold' in ident.electronics_source
    assert 'freewheel diode release' in ident.electronics_source
    assert ident.baseline.validation.rmse < 1.5 * NOISE_A


def test_the_hysteresis_grid_finds_a_set_point_off_the_middle_in_fewer_runs(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # a cost whose valley in clock x band holds at every set point and is deepest 6 mA
    # above the start's set point: the coarse stage finds the pair, the fine one the set
    # point, in fewer runs than every clock x band x set point
    base = ElectronicsConfig(hold='hysteresis', holding_current_a=0.5)
    clock, band, hold = 40e3, HYSTERESIS_BANDS_A[9], 0.506
    tried: list[ElectronicsConfig] = []

    def costs(data, raw, configs):
        tried.extend(configs)
        return np.array([abs(c.comparator_frequency_hz - clock) / 1e4
                         + abs(math.log(c.hysteresis_band_a / band))
                         + 100.0 * abs(c.holding_current_a - hold) for c in configs])
    monkeypatch.setattr(drive_module, '_costs', costs)
    found = hysteresis_grid(SimpleNamespace(drive_cache={}), load_parameters(), base)
    assert found.electronics.comparator_frequency_hz == clock
    assert found.electronics.hysteresis_band_a == band
    assert found.electronics.holding_current_a == pytest.approx(hold)
    pairs = len(set(COMPARATOR_CLOCKS_HZ) | {base.comparator_frequency_hz}) * len(
        HYSTERESIS_BANDS_A)
    assert len(tried) == 1 + pairs + GRID_FINE_PAIRS * (len(HYSTERESIS_HOLD_OFFSETS_A) - 1)
    assert len(tried) < pairs * len(HYSTERESIS_HOLD_OFFSETS_A)


def test_a_search_of_the_constants_asked_again_runs_nothing(tmp_path: Path) -> None:
    # the form choice asks for the same search from several stages: the data keep it
    rec = operation_dataset(tmp_path, seed=11, noise_a=NOISE_A, duration_s=0.3,
                            electronics='generator_default', valve_seed=11)
    inputs = read_inputs([str(rec['file'])], [], IdentifySettings(), None, lambda s: None)
    head = [window(m, 0.1) for m in inputs.fit]
    params = load_parameters()
    cfg = ElectronicsConfig(hold='hysteresis')   # a hold whose constants start on a grid

    def fresh() -> FitData:
        data = FitData(head)
        data.electronics = cfg
        return data
    data = fresh()
    first = search_constants(data, params, cfg, 10, grid=True)
    runs = data.simulations
    assert runs > len(HYSTERESIS_BANDS_A) * len(HYSTERESIS_HOLD_OFFSETS_A)   # the grid ran
    again = search_constants(data.serial(), params, cfg, 10, grid=True)   # a view shares it
    assert data.simulations == runs
    assert again == first
    other = fresh()
    assert search_constants(other, params, cfg, 10, grid=True) == first   # what a search gives
    assert other.simulations == runs


@pytest.mark.parametrize('told_apart', [True, False])
def test_the_choice_says_which_form_it_took_when_none_beat_the_prior(
        monkeypatch: pytest.MonkeyPatch, told_apart: bool) -> None:
    # no form beats the prior (the paper's driver, its capacitor at 1 V: at a search
    # bound); a Zener clamp the data cannot tell from it is plainer and is taken, and the
    # statement says so instead of "it is kept"
    fam = electronics_family
    valve = load_parameters()
    prior = FormFit(ElectronicsConfig(capacitor_voltage_v=1.0), valve, 1e-3, refined=True,
                    prior=True)
    zener = FormFit(ElectronicsConfig(release='zener'), valve, 1.1e-3, refined=True)
    assert prior.at_bound and not zener.at_bound
    monkeypatch.setattr(fam, '_judge', lambda f, fit, val: None)
    monkeypatch.setattr(fam, '_beats', lambda fit, val, ref, f: False)
    monkeypatch.setattr(fam, '_cannot_tell',
                        lambda fit, val, chosen, f: not told_apart and f is not chosen)
    chosen, _, text = fam.choose_form([prior, zener], None, None, 1)
    assert 'no form beat the prior one' in text
    if told_apart:
        assert chosen is prior and 'it is kept' in text and 'taken' not in text
    else:
        assert chosen is zener and 'it is kept' not in text
        assert text.startswith('drive electronics chosen by the data: ' + zener.name)
        assert f'{prior.name} has a constant at a search bound' in text
