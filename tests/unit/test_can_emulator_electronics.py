"""The CAN emulator takes a drive electronics description file (``--electronics``)."""
from __future__ import annotations

from pathlib import Path

import pytest

from valve_driver_pkg.emulator.emulator_main import build_parser, make_stepper
from valve_model_pkg.errors import ParameterError
from valve_model_pkg.model import load_electronics

EXAMPLES = Path(__file__).resolve().parents[2] / 'valve_model_pkg' / 'config' / 'electronics'


def test_the_can_emulator_takes_the_description(tmp_path: Path) -> None:
    driver = EXAMPLES / 'hysteresis_freewheel_diode.yaml'
    stepper = make_stepper(build_parser().parse_args(['--electronics', str(driver)]))
    assert stepper.electronics == load_electronics(driver)
    bench = make_stepper(build_parser().parse_args(['--electronics', str(driver),
                                                    '--no-capacitor']))
    assert bench.electronics == load_electronics(driver).replace(negative_voltage=False)
    bad = tmp_path / 'driver.yaml'
    bad.write_text('hold: bang_bang\n', encoding='utf-8')
    with pytest.raises(ParameterError, match=f'{bad}:1: hold must be one of'):
        make_stepper(build_parser().parse_args(['--electronics', str(bad)]))
