"""valve_map: writes the map file and Figs. 8/9, shows progress, refuses bad input."""
from __future__ import annotations

from pathlib import Path

import pytest

from valve_model_pkg.cli.map import main as valve_map
from valve_model_pkg.maps import DutyMap, default_map_path
from valve_model_pkg.model import load_parameters


def test_generates_a_small_map_with_figures(tmp_path: Path, capsys) -> None:
    out = tmp_path / 'maps' / 'small.json'
    code = valve_map(['-o', str(out), '--duty-step', '0.05', '--pressures-bar', '0', '4',
                      '--frequencies', '50', '100'])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    dmap = DutyMap.load(out)
    dmap.check_parameters(load_parameters())
    assert dmap.position_fraction.shape == (2, 2, 21)
    assert dmap.generator['program'] == 'valve_map'
    assert (tmp_path / 'maps' / 'fig8_pressures.png').stat().st_size > 10_000
    assert (tmp_path / 'maps' / 'fig9_frequencies.png').stat().st_size > 10_000
    # the summary names dead band, saturation and width of every curve; progress on stderr
    assert 'dead band' in captured.out and 'saturation' in captured.out
    assert '50 Hz: with pressure the range shifts up' in captured.out
    assert '100.0%' in captured.err and 'edge bisection' in captured.err


def test_show_reads_an_existing_map(tmp_path: Path, capsys) -> None:
    code = valve_map(['--show', str(default_map_path()), '--fig-dir', str(tmp_path)])
    text = capsys.readouterr().out
    assert code == 0
    assert '4 bar: with frequency the range narrows' in text
    assert (tmp_path / 'fig8_pressures.png').exists()


def test_the_map_of_another_drive(tmp_path: Path, capsys) -> None:
    """A slower release (a free-wheel diode) keeps the valve open longer: more opening."""
    out = tmp_path / 'diode.json'
    driver = tmp_path / 'driver.yaml'
    driver.write_text('release: diode\n')
    grid = ['--duty-step', '0.25', '--pressures-bar', '4', '--frequencies', '50',
            '--no-figures', '-q']
    assert valve_map(['-o', str(out), '--electronics', str(driver)] + grid) == 0
    assert valve_map(['-o', str(tmp_path / 'paper.json')] + grid) == 0
    diode, paper = DutyMap.load(out), DutyMap.load(tmp_path / 'paper.json')
    assert diode.electronics['release'] == 'diode'
    assert diode.generator['electronics_file'] == str(driver)
    assert diode.position_fraction[0, 0, 2] > paper.position_fraction[0, 0, 2] + 0.02
    capsys.readouterr()


@pytest.mark.parametrize('argv, message', [
    (['--electronics', '/nonexistent/driver.yaml'], 'driver.yaml'),
    (['--params', '/nonexistent/valve.yaml'], 'valve.yaml'),
    (['--duty-step', '0.03'], 'whole number'),
    (['--show', '/nonexistent/map.json'], 'no such map file'),
])
def test_bad_input_exits_2_with_the_reason(tmp_path: Path, capsys, argv: list[str],
                                           message: str) -> None:
    code = valve_map(['-o', str(tmp_path / 'm.json'), '--no-figures', '-q'] + argv)
    assert code == 2  # refused input (the CLI rule: 2 refused input, 1 failure inside)
    assert message in capsys.readouterr().err
