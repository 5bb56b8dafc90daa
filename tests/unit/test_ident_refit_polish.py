"""The refit's polish on the whole fit window (pipeline.polish_candidate): the baseline, its
effect off, is a point of every candidate's model, so a refit never reports a fit-window
cost above the baseline's when the off value lies within the effect's search bounds."""
from __future__ import annotations

import numpy as np
import pytest

from valve_model_pkg.identification import pipeline
from valve_model_pkg.identification.pipeline import IdentifySettings, polish_candidate
from valve_model_pkg.identification.problem import (ParameterBound, ParameterSpace,
                                                    baseline_space, effect_space)
from valve_model_pkg.model.parameters import EFFECTS, load_parameters

#: The cost's floor at the search window's optimum [A] (a synthetic objective).
FOUND_A = 0.05


def _polish(monkeypatch: pytest.MonkeyPatch, effect: str, baseline_cost: float,
            ext: ParameterSpace | None = None):
    base = load_parameters()
    ext = ext or effect_space(baseline_space(base), effect)
    found = ext.params(np.full(ext.size, 0.6))   # the search window's optimum, amount on
    u_found = ext.to_unit(found)
    monkeypatch.setattr(pipeline, 'place', lambda data, params: data)
    monkeypatch.setattr(pipeline, 'unit_objective', lambda space, data: (
        lambda u: FOUND_A + np.sum((np.atleast_2d(u) - u_found) ** 2, axis=1)))
    return base, found, polish_candidate(ext, None, found, base,
                                         IdentifySettings(refit_polish_iterations=20),
                                         baseline_cost)


def test_a_refit_the_fit_window_refuses_gives_way_to_the_baseline(
        monkeypatch: pytest.MonkeyPatch) -> None:
    base, _, (params, cost, how) = _polish(monkeypatch, 'end_stop_bounce', 0.04)
    assert params is base and cost == 0.04
    assert params.restitution_coefficient == EFFECTS['end_stop_bounce'].neutral[
        'restitution_coefficient']
    assert 'the baseline, the effect off, is the refit' in how and '0.05' in how


def test_a_refit_below_the_baseline_stands(monkeypatch: pytest.MonkeyPatch) -> None:
    _, found, (params, cost, how) = _polish(monkeypatch, 'end_stop_bounce', 0.06)
    assert cost == pytest.approx(FOUND_A) and how == ''
    assert params.restitution_coefficient == pytest.approx(found.restitution_coefficient)


def test_an_off_value_outside_the_bounds_is_not_taken(monkeypatch: pytest.MonkeyPatch) -> None:
    # an effect searched from above its off value: the baseline is not a point of its model
    space = baseline_space(load_parameters())
    ext = ParameterSpace(space.base, space.bounds + (
        ParameterBound('restitution_coefficient', 0.1, 0.9, log=False),), space.hold)
    _, _, (params, cost, how) = _polish(monkeypatch, 'end_stop_bounce', 0.04, ext)
    assert cost == pytest.approx(FOUND_A) and how == ''
    assert params.restitution_coefficient >= 0.1
