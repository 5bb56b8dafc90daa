"""The main PWM grid's phase is placed for each model (identification/phase.py).

An operational record bounds its main PWM period starts only to the telemetry interval;
the eddy path's current step at each edge moves the phase that fits best. The records come
from the independent truth model (tests/datagen) through the generator's
timer_hysteresis_zener form, given to the suite as its description.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from datagen.cache import operation_dataset
from suite_electronics import TIMER_HYSTERESIS_ZENER_YAML
from valve_model_pkg.identification import IdentifySettings, identify
from valve_model_pkg.identification.phase import (
    PHASE_RESOLUTION_S, AmountPhases, best_phase, phase_shifts, place, placed,
)
from valve_model_pkg.identification.pipeline import read_inputs
from valve_model_pkg.identification.problem import FitData, baseline_space, effect_space
from valve_model_pkg.model import load_electronics
from valve_model_pkg.model.parameters import load_parameters

#: The generator's eddy-current resistance [ohm] (tests/datagen/generate.py).
EDDY_OHM = 250.0


def _record(tmp_path: Path, effect: str, noise_a: float = 0.0, seed: int = 11,
            duration_s: float = 0.8) -> str:
    return str(operation_dataset(tmp_path, seed=seed, effect=effect, noise_a=noise_a,
                                 duration_s=duration_s, electronics='timer_hysteresis_zener',
                                 valve_seed=11)['file'])


def _electronics(tmp_path: Path) -> Path:
    path = tmp_path / 'thz.yaml'
    path.write_text(TIMER_HYSTERESIS_ZENER_YAML, encoding='utf-8')
    return path


def _data(tmp_path: Path, effect: str) -> FitData:
    path = _electronics(tmp_path)
    settings = IdentifySettings(electronics=str(path))
    inputs = read_inputs([_record(tmp_path, effect)], [], settings, None, lambda s: None)
    data = FitData(inputs.fit)
    data.electronics = load_electronics(path)
    return data


def test_each_model_is_judged_on_its_own_grid(tmp_path: Path) -> None:
    data = _data(tmp_path, 'eddy_current')
    # the generator's valve is the packaged parameter set
    truth = load_parameters().replace(eddy_conductance_s=1.0 / EDDY_OHM)
    without = load_parameters()
    shift_truth = phase_shifts(data, truth)[0]
    shift_without = phase_shifts(data, without)[0]
    # the eddy path's current step at each edge moves the best phase by a good part of
    # the 1 ms the record allows
    assert shift_truth - shift_without > 0.15e-3
    own = place(data, truth).errors(truth).rmse
    other = place(data, without).errors(truth).rmse
    assert own < 1e-3            # noise-free record: the truth on its own grid
    assert other > 10.0 * own    # ... and charged for the other model's grid
    assert other > place(data, without).errors(without).rmse   # worse than no eddy path


def test_a_search_around_an_expected_phase_finds_the_best(tmp_path: Path) -> None:
    # a placement searches a tenth of the range around the phase expected and goes to the
    # whole range when its best lies on that bracket's edge: a wrong expectation costs
    # runs, not the phase
    data = _data(tmp_path, 'eddy_current')
    truth = load_parameters().replace(eddy_conductance_s=1.0 / EDDY_OHM)
    m = data.full[0]
    lo, hi = m.drive.phase_range_s
    fine_step = (hi - lo) / 100.0   # the fine round: 11 trials over a tenth of the range
    whole = best_phase(m, truth, data.electronics)
    far = lo if whole - lo > hi - whole else hi
    assert abs(far - whole) > 0.3 * (hi - lo)
    for around in (whole + 2.0 * fine_step, far):
        found = best_phase(m, truth, data.electronics, around_s=around)
        assert abs(found - whole) <= fine_step + PHASE_RESOLUTION_S, around


def test_a_refit_places_the_grid_per_amount(tmp_path: Path) -> None:
    data = _data(tmp_path, 'eddy_current')
    base = load_parameters()
    phases = AmountPhases(data, 'eddy_conductance_s')
    for g in (0.0, 4e-3):
        phases.anchor(base.replace(eddy_conductance_s=g))
    s0 = phases.shifts_at(0.0)[0]
    s4 = phases.shifts_at(4e-3)[0]
    assert s0 == pytest.approx(phase_shifts(data, base)[0], abs=PHASE_RESOLUTION_S)
    mid = phases.shifts_at(2e-3)[0]
    assert mid == pytest.approx(0.5 * (s0 + s4), abs=PHASE_RESOLUTION_S)
    assert phases.shifts_at(-1.0)[0] == s0 and phases.shifts_at(1.0)[0] == s4
    # each row of a batch runs on the grid of its own amount
    ext = effect_space(baseline_space(base), 'eddy_current')
    rows = np.array([ext.to_unit(base.replace(eddy_conductance_s=g)) for g in (0.0, 4e-3)])
    cost = phases.objective(ext)(rows)
    for c, g in zip(cost, (0.0, 4e-3)):
        p = base.replace(eddy_conductance_s=g)
        own = placed(data, phases.shifts_at(g))
        assert c == pytest.approx(float(own.cost(p.to_vector()[None, :])[0]), rel=1e-12)
    # on the grid placed per amount the true amount fits best
    assert cost[1] < 0.2 * cost[0]


@pytest.mark.slow
def test_eddy_current_is_named_through_the_given_hysteresis_form(tmp_path: Path) -> None:
    # Placed once with the baseline, the grid charged the true eddy amount more than none:
    # the record was answered magnetic_saturation (high) through its own, given form.
    fit = _record(tmp_path, 'eddy_current', noise_a=3e-3, seed=11, duration_s=1.5)
    val = _record(tmp_path, 'eddy_current', noise_a=3e-3, seed=12, duration_s=1.2)
    ident = identify([fit], [val], IdentifySettings(
        electronics=str(_electronics(tmp_path)), quick=True,
        effects=['eddy_current', 'magnetic_saturation']))
    assert ident.diagnosis.effect == 'eddy_current'
    assert ident.augmented.params.eddy_conductance_s == pytest.approx(1.0 / EDDY_OHM,
                                                                      rel=0.1)
    assert ident.augmented.validation.rmse < 1.5 * 3e-3


def test_a_grid_moved_alone_looks_like_no_effect(tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    # the record's current replaced by the model's own on its grid moved by 40 us: the
    # residual on the unmoved grid is the phase's direction alone, which the phase fitted
    # with each model takes; without that direction the eddy path's signature matches it
    from valve_model_pkg.identification import diagnosis
    data = _data(tmp_path, 'none')
    params = load_parameters()
    moved = placed(data, [40e-6])
    cur = moved.simulate(params.to_vector()[None, :])[0][0][0]
    m = data.measurements[0]
    data = FitData([m.with_current(cur)])
    data.electronics = moved.electronics
    residuals = data.residuals(params)
    space = baseline_space(params)
    scores = diagnosis.score_signatures(space, data, params, residuals)
    assert max(abs(c) for c, _ in scores.values()) < 0.05
    monkeypatch.setattr(diagnosis, '_phase_columns', lambda *a: [])
    blind = diagnosis.score_signatures(space, data, params, residuals)
    assert max(abs(c) for c, _ in blind.values()) > 0.3
