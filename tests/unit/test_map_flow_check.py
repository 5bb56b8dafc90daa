"""Fig. 10: flow percentage = average-position percentage; valve_flow_check on flow_map files."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from valve_model_pkg.cli.flow_check import main as flow_check_main
from valve_model_pkg.maps import FlowMapFormatError, load_map
from valve_model_pkg.maps.flow_check import (compare_flow_map, map_flow_fraction,
                                             read_flow_map, write_flow_map)
from valve_model_pkg.model import ElectronicsConfig, ValveStepper, load_parameters

DUTIES = np.round(np.arange(0.0, 1.0001, 0.05), 10)


@pytest.fixture(scope='module')
def shipped():
    return load_map()


@pytest.fixture(scope='module')
def stepper_flows() -> np.ndarray:
    """Steady mass flow from the streaming model (its own eq. 12 on its period average),
    50 Hz, 4 bar into atmosphere: the paper's Fig. 10 experiment, simulated."""
    params = load_parameters()
    flows = []
    for d in DUTIES:
        st = ValveStepper(params, ElectronicsConfig(), duty=float(d), pwm_frequency_hz=50.0,
                          supply_pressure_pa=4e5, output_pressure_pa=0.0)
        st.advance_to(30 / 50.0 + 1e-6)     # 30 periods: far past the steady state (8)
        flows.append(st.sample().mass_flow_kg_s)
    return np.array(flows)


def test_choked_flow_percentage_equals_position_percentage(shipped, stepper_flows) -> None:
    """Choked at 4 bar into atmosphere: flow % from the model = x_avg % from the map."""
    assert (0.0 + 101325.0) / (4e5 + 101325.0) < 0.528     # choked
    flow_pct = stepper_flows / stepper_flows[-1]
    map_pct = map_flow_fraction(shipped, DUTIES, 50.0, 4e5)
    np.testing.assert_allclose(flow_pct, map_pct, atol=0.01)
    # and the map's x_avg at 100 % is the full stroke, so the two are also x_avg / x_max
    assert shipped.curve(50.0, 4e5)[-1] == pytest.approx(1.0)


def test_read_write_round_trip(tmp_path: Path) -> None:
    q = np.linspace(0.0, 1e-3, DUTIES.size)
    path = write_flow_map(tmp_path / 'f.csv', DUTIES, supply_pressure_pa=4e5,
                          pwm_frequency_hz=50.0, mass_flow_kg_s=q,
                          metadata={'valve': 'bench valve 7'})
    fm = read_flow_map(path)
    np.testing.assert_allclose(fm.duty, DUTIES)
    np.testing.assert_allclose(fm.flow_fraction, q / q[-1])
    assert fm.metadata['valve'] == 'bench valve 7' and fm.pwm_frequency_hz == 50.0


def test_comparison_of_a_noisy_bench_file(tmp_path: Path, shipped, stepper_flows) -> None:
    """A 'measured' file = the model's flow with 5 % more C_d and 0.5 % noise: the
    percentages agree to the noise, the absolute flow shows the C_d difference."""
    rng = np.random.default_rng(3)
    measured = 1.05 * stepper_flows * (1.0 + 0.005 * rng.standard_normal(DUTIES.size))
    path = write_flow_map(tmp_path / 'bench.csv', DUTIES, supply_pressure_pa=4e5,
                          pwm_frequency_hz=50.0, mass_flow_kg_s=np.maximum(measured, 0.0))
    res = compare_flow_map(shipped, read_flow_map(path))
    assert res.choked
    assert res.rms_error < 0.015 and res.max_abs_error < 0.03
    assert res.measured_full_flow_kg_s / res.predicted_full_flow_kg_s == pytest.approx(
        1.05, abs=0.02)
    table = res.table()
    assert 'overall: rms' in table and table.count('\n') == DUTIES.size + 3


def test_cli_reports_per_duty_and_overall(tmp_path: Path, capsys, stepper_flows) -> None:
    path = write_flow_map(tmp_path / 'bench.csv', DUTIES, supply_pressure_pa=4e5,
                          pwm_frequency_hz=50.0,
                          flow_fraction=stepper_flows / stepper_flows[-1])
    out_json = tmp_path / 'cmp.json'
    png = tmp_path / 'fig10.png'
    code = flow_check_main([str(path), '--json', str(out_json), '--plot', str(png),
                            '--max-rms-percent', '2'])
    text = capsys.readouterr().out
    assert code == 0, text
    assert ' 50.00 ' in text and 'overall: rms' in text
    data = json.loads(out_json.read_text())
    assert len(data['points']) == DUTIES.size and data['rms_error'] < 0.01
    assert png.stat().st_size > 10_000
    # a bad fit fails the threshold: exit code 1 (a failed check, not refused input)
    bad = write_flow_map(tmp_path / 'bad.csv', DUTIES, supply_pressure_pa=4e5,
                         pwm_frequency_hz=50.0, flow_fraction=DUTIES)
    assert flow_check_main([str(bad), '--max-rms-percent', '2']) == 1


@pytest.mark.parametrize('text, where, reason', [
    ('# experiment: flow_map\n# supply_pressure_pa: 4e5\n# pwm_frequency_hz: 50\n'
     'duty,mass_flow\n0,0\n0.5,nan\n1,1e-3\n', ':6', 'not finite'),
    ('# experiment: flow_map\n# supply_pressure_pa: 4e5\n# pwm_frequency_hz: 50\n'
     'duty,mass_flow\n0,0\n0.6,1e-4\n0.5,2e-4\n1,1e-3\n', ':7', 'rows must ascend'),
    ('# experiment: flow_map\n# supply_pressure_pa: 4e5\n# pwm_frequency_hz: 50\n'
     'duty,pressure\n0,0\n1,1\n', ':4', 'needs a "mass_flow" or "flow_fraction"'),
    ('# experiment: step\n# supply_pressure_pa: 4e5\n# pwm_frequency_hz: 50\n'
     'duty,mass_flow\n0,0\n1,1e-3\n', '', "expected 'flow_map'"),
    ('# experiment: flow_map\n# supply_pressure_pa: 4e5\n'
     'duty,mass_flow\n0,0\n1,1e-3\n', '', 'pwm_frequency_hz missing'),
    ('# experiment: flow_map\n# supply_pressure_pa: 4e5\n# pwm_frequency_hz: 50\n'
     'duty,mass_flow\n0,0\n0.5,1e-3\n', '', 'needs a row at duty 1'),
    ('# experiment: flow_map\n# supply_pressure_pa: 4e5\n# pwm_frequency_hz: 50\n'
     'duty,mass_flow\n0,0\n0.5,1e-3,7\n1,1\n', ':6', '3 fields'),
])
def test_malformed_flow_map_files_name_file_line_and_problem(tmp_path: Path, capsys,
                                                             text: str, where: str,
                                                             reason: str) -> None:
    path = tmp_path / 'f.csv'
    path.write_text(text)
    with pytest.raises(FlowMapFormatError, match=reason) as info:
        read_flow_map(path)
    assert f'{path}{where}' in str(info.value)
    assert flow_check_main([str(path)]) == 2  # refused input
    assert reason.split('"')[0] in capsys.readouterr().err


def test_frequency_not_in_map_is_an_error(tmp_path: Path, capsys) -> None:
    path = write_flow_map(tmp_path / 'f.csv', DUTIES, supply_pressure_pa=4e5,
                          pwm_frequency_hz=75.0, flow_fraction=DUTIES)
    assert flow_check_main([str(path)]) == 2  # refused input
    assert '75 Hz is not in the map' in capsys.readouterr().err


def test_out_file_ending_in_json_keeps_the_comparison_meaning(tmp_path: Path,
                                                              stepper_flows) -> None:
    """``-o x.json`` writes the comparison only, as before ``-o DIR`` identified C_d*C_A."""
    path = write_flow_map(tmp_path / 'bench.csv', DUTIES, supply_pressure_pa=4e5,
                          pwm_frequency_hz=50.0, mass_flow_kg_s=stepper_flows)
    assert flow_check_main([str(path), '-o', str(tmp_path / 'cmp.json')]) == 0
    data = json.loads((tmp_path / 'cmp.json').read_text())
    assert len(data['points']) == DUTIES.size and data['rms_error'] < 0.01
    assert not (tmp_path / 'params.yaml').exists()
    # a directory: the identification, with the model's own flows giving the prior back
    assert flow_check_main([str(path), '-o', str(tmp_path / 'cal')]) == 0
    ident = json.loads((tmp_path / 'cal' / 'flow_identified.json').read_text())
    assert ident['ratio_to_prior'] == pytest.approx(1.0, abs=0.01)
    assert {'comparison.json', 'map.json', 'params.yaml'} <= {
        p.name for p in (tmp_path / 'cal').iterdir()}
