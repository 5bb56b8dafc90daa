"""The drive electronics description file (ElectronicsConfig from and to YAML)."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from valve_model_pkg.errors import ParameterError
from valve_model_pkg.model import (
    ElectronicsConfig, InputTrace, ValveParameters, load_electronics, simulate_trace_batch,
)

EXAMPLES = Path(__file__).resolve().parents[2] / 'valve_model_pkg' / 'config' / 'electronics'


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / 'driver.yaml'
    path.write_text(text, encoding='utf-8')
    return path


def test_the_examples_cover_every_form_and_the_default_example_is_the_default() -> None:
    configs = {p.name: load_electronics(p) for p in sorted(EXAMPLES.glob('*.yaml'))}
    assert configs['paper_default.yaml'] == ElectronicsConfig()
    used = {name: {getattr(c, name) for c in configs.values()}
            for name in ('peak_end', 'hold', 'hold_decay', 'release')}
    assert used['peak_end'] == {'dip', 'dip_rise', 'threshold', 'timer'}
    assert used['hold'] == {'pi', 'hysteresis', 'pwm'}
    assert used['hold_decay'] == {'freewheel', 'diode', 'fast'}
    assert used['release'] >= {'capacitor', 'capacitor_peak', 'zener', 'diode'}


@pytest.mark.parametrize('name', sorted(p.name for p in EXAMPLES.glob('*.yaml')))
def test_each_example_drives_the_valve_open_and_closed(name: str) -> None:
    e = load_electronics(EXAMPLES / name)
    res = simulate_trace_batch(ValveParameters(), InputTrace.pwm_commands([0.0], 0.4, 50.0),
                               np.arange(1, 41) * 1e-3, electronics=e).run(0)
    stroke = ValveParameters().stroke_m
    assert res.n_forced_steps == 0
    assert res.spool_position_m[6] == stroke and res.spool_position_m[19] == 0.0


@pytest.mark.parametrize('name', sorted(p.name for p in EXAMPLES.glob('*.yaml')))
def test_to_yaml_reads_back_to_the_same_config(name: str, tmp_path: Path) -> None:
    e = load_electronics(EXAMPLES / name)
    text = e.to_yaml(tmp_path / 'out.yaml')
    assert (tmp_path / 'out.yaml').read_text(encoding='utf-8') == text
    assert load_electronics(tmp_path / 'out.yaml') == e
    assert ElectronicsConfig.from_yaml(tmp_path / 'out.yaml') == e


def test_top_level_keys_and_an_electronics_block_are_the_same(tmp_path: Path) -> None:
    flat = load_electronics(_write(tmp_path, 'hold: hysteresis\nhysteresis_band_a: 20e-3\n'))
    assert flat == ElectronicsConfig(hold='hysteresis', hysteresis_band_a=0.02)
    block = load_electronics(_write(tmp_path, 'electronics:\n  hold: hysteresis\n'
                                              '  hysteresis_band_a: 20e-3\n'))
    assert block == flat
    assert load_electronics(_write(tmp_path, '# nothing set\n')) == ElectronicsConfig()


@pytest.mark.parametrize('text, line, pieces', [
    ('electronics:\n  hold: pi\n  chopper_hz: 20000\n', 3, ["'chopper_hz'", '20000']),
    ('hold: pi\nrelease: varistor\n', 2, ['release', "'varistor'", 'zener']),
    ('peak_current_a: fast\n', 1, ['peak_current_a', "'fast'", 'number']),
    ('zener_voltage_v: -5\n', 1, ['zener_voltage_v', '-5', 'positive']),
    ('negative_voltage: 1\n', 1, ['negative_voltage', '1', 'true or false']),
])
def test_a_bad_key_or_value_is_refused_in_one_line_naming_file_line_key_and_value(
        tmp_path: Path, text: str, line: int, pieces: list[str]) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(ParameterError) as info:
        load_electronics(path)
    message = str(info.value)
    assert '\n' not in message
    assert message.startswith(f'{path}:{line}: ')
    for piece in pieces:
        assert piece in message


@pytest.mark.parametrize('text, match', [
    ('electronics:\n  hold: pi\nvalve: x\n', "unknown key 'valve' beside the electronics"),
    ('- hold\n', 'a mapping of settings'),
    ('hold: [pi\n', 'not valid YAML'),
    ('hold: pi\nhold: pwm\n', "duplicate key 'hold'"),
])
def test_a_file_that_is_not_a_description_is_refused(tmp_path: Path, text: str,
                                                     match: str) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(ParameterError, match=match) as info:
        load_electronics(path)
    assert str(path) in str(info.value)


def test_a_missing_file_raises_file_not_found(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        load_electronics(tmp_path / 'none.yaml')


def test_from_dict_refuses_unknown_keys_and_to_dict_reads_back() -> None:
    e = ElectronicsConfig(release='zener', zener_voltage_v=40.0)
    assert ElectronicsConfig.from_dict(e.to_dict()) == e
    assert e.to_dict() == dataclasses.asdict(e)
    with pytest.raises(ParameterError, match="unknown electronics setting 'dip_detection'"):
        ElectronicsConfig.from_dict({'dip_detection': True})
