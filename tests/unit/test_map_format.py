"""The versioned duty-map file: writing, reading, and refusing bad or foreign files."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from valve_model_pkg.maps import (FORMAT_NAME, FORMAT_VERSION, DutyMap, MapFormatError,
                                  MapParameterMismatchError, default_map_path, load_map,
                                  parameters_hash)
from valve_model_pkg.maps.synthetic import linear_map
from valve_model_pkg.model import load_parameters


@pytest.fixture(scope='module')
def dmap() -> DutyMap:
    return linear_map()


def _write(path: Path, data: object) -> Path:
    path.write_text(json.dumps(data), encoding='utf-8')
    return path


def test_round_trip(tmp_path: Path, dmap: DutyMap) -> None:
    path = dmap.save(tmp_path / 'm.json')
    back = DutyMap.load(path)
    np.testing.assert_allclose(back.position_fraction, dmap.position_fraction, atol=1e-7)
    np.testing.assert_array_equal(back.duty, dmap.duty)
    np.testing.assert_array_equal(back.supply_pressures_pa, dmap.supply_pressures_pa)
    np.testing.assert_array_equal(back.pwm_frequencies_hz, dmap.pwm_frequencies_hz)
    assert back.parameters_sha256 == dmap.parameters_sha256
    assert back.parameters == load_parameters().to_dict()
    data = json.loads(path.read_text())
    assert data['format'] == FORMAT_NAME and data['format_version'] == FORMAT_VERSION
    assert data['parameters_sha256'] == parameters_hash(load_parameters())
    # every curve records its dead band and saturation
    first = data['curves'][0]
    assert set(first['features']) >= {'dead_band_duty', 'opening_duty', 'saturation_duty',
                                      'effective_width'}


def test_file_is_compact(tmp_path: Path, dmap: DutyMap) -> None:
    text = dmap.save(tmp_path / 'm.json').read_text()
    # lists of numbers stay on one line: a few lines per curve, not one per value
    assert text.count('\n') < 40 * len(json.loads(text)['curves']) + 150


@pytest.mark.parametrize('mutate, reason', [
    (lambda d: d.update(format='something/else'), 'not a duty map'),
    (lambda d: d.update(format_version=99), 'unsupported format_version 99'),
    (lambda d: d.pop('grid'), "missing key 'grid'"),
    (lambda d: d['grid'].update(duty=[0.0, 0.5]), 'duty must run from 0 to 1'),
    (lambda d: d['grid'].update(pwm_frequency_hz=[50.0, 20.0]), 'strictly ascending'),
    (lambda d: d['curves'].pop(), 'curves must be a list of 8 curves'),
    (lambda d: d['curves'][1]['position_fraction'].pop(), 'has 100 values'),
    (lambda d: d['curves'][2].update(position_fraction=[2.0] * 101), r'outside \[0, 1\]'),
    (lambda d: d['curves'][0]['position_fraction'].__setitem__(3, 'x'), 'non-number'),
    (lambda d: d['curves'][0].update(supply_pressure_pa=1.0), 'curves are frequency-major'),
    (lambda d: d['parameters']['valve'].update(coil_resistance_ohm=15.0),
     'parameters_sha256 does not match'),
    (lambda d: d['parameters']['valve'].pop('spool_mass_kg'), 'invalid parameter set'),
])
def test_malformed_files_are_refused_with_file_and_reason(tmp_path: Path, dmap: DutyMap,
                                                          mutate, reason: str) -> None:
    data = dmap.to_json_dict()
    mutate(data)
    path = _write(tmp_path / 'bad.json', data)
    with pytest.raises(MapFormatError, match=reason) as info:
        DutyMap.load(path)
    assert str(path) in str(info.value)


def test_missing_and_non_json_files(tmp_path: Path) -> None:
    with pytest.raises(MapFormatError, match='no such map file') as info:
        DutyMap.load(tmp_path / 'nope.json')
    assert 'nope.json' in str(info.value)
    bad = tmp_path / 'broken.json'
    bad.write_text('{"format": "valve_suite/duty_map",\n "grid": [1, 2,,]}')
    with pytest.raises(MapFormatError, match=r'not valid JSON \(line 2'):
        DutyMap.load(bad)
    with pytest.raises(MapFormatError, match='top level is list'):
        DutyMap.load(_write(tmp_path / 'list.json', [1, 2]))


def test_map_for_other_parameters_is_refused(dmap: DutyMap) -> None:
    other = load_parameters().replace(coil_resistance_ohm=15.0, damping_n_s_per_m=0.3)
    with pytest.raises(MapParameterMismatchError) as info:
        dmap.check_parameters(other, 'the_map.json', 'my_valve.yaml')
    text = str(info.value)
    assert 'the_map.json' in text and 'other valve parameters' in text
    assert 'coil_resistance_ohm = 13.0 in the map, 15.0 in my_valve.yaml' in text
    assert 'damping_n_s_per_m' in text
    dmap.check_parameters(load_parameters())   # the same set passes


def test_frequency_and_pressure_lookup(dmap: DutyMap) -> None:
    assert dmap.frequency_index(50.0) == 1
    with pytest.raises(KeyError, match='100 Hz is not in the map'):
        dmap.frequency_index(100.0)
    np.testing.assert_array_equal(dmap.curve(50.0, 4e5), dmap.position_fraction[1, 2])


def test_shipped_map_loads_and_matches_the_paper_parameters() -> None:
    path = default_map_path()
    assert path.name == 'valve_map.json'
    shipped = load_map()          # default = the shipped file
    shipped.check_parameters(load_parameters())
    assert path.stat().st_size < 120_000
    # the required grid at least: 0..100 % in 1 % steps, 0/2/4/6 bar, 20/50/100/200 Hz
    assert np.max(np.diff(shipped.duty)) <= 0.01 + 1e-12
    assert {0.0, 2e5, 4e5, 6e5} <= set(shipped.supply_pressures_pa.tolist())
    assert {20.0, 50.0, 100.0, 200.0} <= set(shipped.pwm_frequencies_hz.tolist())
    assert shipped.electronics['current_control'] and shipped.electronics['negative_voltage']
    assert shipped.steady_state['tolerance'] > 0
