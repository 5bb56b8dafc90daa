"""What the operation loop counts as a right diagnosis (loop.json `judgement`): the listed
effect itself; for an emulator form written independently of the candidates, the nearest
candidate or `unlisted`, never another listed effect; `none` for a valve without effect."""
from __future__ import annotations

from valve_bringup.bench_loop import NEAREST_CANDIDATE, expected_answers
from valve_model_pkg.model.parameters import EFFECTS, EMULATOR_EFFECTS


def test_every_emulator_form_maps_to_a_listed_candidate() -> None:
    assert set(NEAREST_CANDIDATE) == set(EMULATOR_EFFECTS)
    assert set(NEAREST_CANDIDATE.values()) <= set(EFFECTS)


def test_expected_answers() -> None:
    assert expected_answers('eddy_current') == ['eddy_current']
    assert expected_answers('none') == ['none']
    assert expected_answers('saturation_tanh') == ['magnetic_saturation', 'unlisted']
    assert 'eddy_current' not in expected_answers('saturation_tanh')
