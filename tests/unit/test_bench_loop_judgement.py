"""What the operation loop counts as a right diagnosis (loop.json `judgement`): the listed
effect itself; for an emulator form written independently of the candidates, the nearest
candidate or `unlisted`, never another listed effect; `none` for a valve without effect.
And the loop's inputs: the valve in service, a refused discharge coefficient."""
from __future__ import annotations

import pytest

from valve_bringup.bench import DEFAULT_EFFECT_PARAMS
from valve_bringup.bench_loop import main
from valve_bringup.operation_loop import (NEAREST_CANDIDATE, OPERATION_EFFECT_PARAMS,
                                          expected_answers, write_plant_parameters)
from valve_model_pkg.model import load_parameters
from valve_model_pkg.model.parameters import EFFECTS, EMULATOR_EFFECTS


def test_every_emulator_form_maps_to_a_listed_candidate() -> None:
    assert set(NEAREST_CANDIDATE) == set(EMULATOR_EFFECTS)
    assert set(NEAREST_CANDIDATE.values()) <= set(EFFECTS)


def test_expected_answers() -> None:
    assert expected_answers('eddy_current') == ['eddy_current']
    assert expected_answers('none') == ['none']
    assert expected_answers('saturation_tanh') == ['magnetic_saturation', 'unlisted']
    assert 'eddy_current' not in expected_answers('saturation_tanh')


@pytest.mark.parametrize('value', ['nan', '0', '-0.5', '1.2', 'inf'])
def test_plant_discharge_coefficient_outside_0_1_is_refused_in_one_line(value, capsys,
                                                                        tmp_path) -> None:
    with pytest.raises(SystemExit) as exc:
        main(['--mode', 'operation', '--plant-discharge-coefficient', value,
              '--out', str(tmp_path / 'out')])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert '--plant-discharge-coefficient' in err[-1] and 'expected a number in (0, 1]' \
        in err[-1], err
    assert not (tmp_path / 'out').exists()


def test_an_unknown_effect_is_refused_in_one_line(capsys, tmp_path) -> None:
    with pytest.raises(SystemExit) as exc:
        main(['--effect', 'gremlins', '--out', str(tmp_path / 'out')])
    assert exc.value.code == 2
    assert "--effect 'gremlins'" in capsys.readouterr().err.strip().splitlines()[-1]
    assert not (tmp_path / 'out').exists()


def test_the_valve_in_service_differs_from_the_suite_only_in_its_discharge_coefficient(
        tmp_path) -> None:
    plant = write_plant_parameters(tmp_path / 'plant.yaml', 0.62)
    suite, loaded = load_parameters(), load_parameters(str(tmp_path / 'plant.yaml'))
    assert loaded == suite.replace(discharge_coefficient=0.62)
    assert plant.full_opening_area_m2 == pytest.approx(
        0.62 * suite.orifice_area_gradient_m * suite.stroke_m)
    assert plant.suite_full_opening_area_m2 / plant.full_opening_area_m2 == \
        pytest.approx(0.8 / 0.62)
    assert plant.to_json()['discharge_coefficient'] == 0.62


@pytest.mark.parametrize('mode, defaults', [('bench', DEFAULT_EFFECT_PARAMS),
                                            ('operation', OPERATION_EFFECT_PARAMS)])
def test_the_loops_injected_effects_lie_inside_the_identifications_search_range(
        mode, defaults) -> None:
    # A truth outside the range is fitted at the bound: the loop would then judge a misfit.
    for effect, items in defaults.items():
        bounds = EFFECTS[effect].bounds
        for item in items:
            name, value = item.split('=')
            low, high = bounds[name]
            assert low < float(value) < high, (mode, effect, name, value, (low, high))
