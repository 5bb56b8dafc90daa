"""The driver core's parts: defaults written once, pure diagnostics, read-only getters."""
from __future__ import annotations

import dataclasses
import time

from valve_driver_pkg.driver import CanDriverCore, DriverConfig, Level, diagnose
from valve_driver_pkg.protocol import TELEMETRY, ValveCodec


def test_every_setting_has_a_description_and_a_range_holding_its_default() -> None:
    for field in dataclasses.fields(DriverConfig):
        assert field.metadata['description'], field.name
        if isinstance(field.default, (int, float)) and not isinstance(field.default, bool):
            low, high = field.metadata['range']
            assert low <= field.default <= high, field.name


def test_report_changes_nothing_and_diagnose_is_pure() -> None:
    core = CanDriverCore(DriverConfig(interface='virtual', channel='parts_test'))
    core.open()
    try:
        core.activate()
        codec = ValveCodec(0)
        for counter in range(5):
            core.handle_frame(codec.encode(TELEMETRY, {
                'CoilCurrent': 0.1, 'CoilVoltage': 24.0, 'SpoolPosition': 1e-4, 'Enabled': 1,
                'PositionValid': 1, 'FaultActive': 0, 'CommandTimeout': 0}, counter))
        before = core.counters
        snapshot = core.snapshot()
        for _ in range(3):
            core.report()
        assert core.counters == before
        first, second = diagnose(snapshot), diagnose(snapshot)
        assert first == second
        assert [r.name for r in first] == ['CAN bus', 'telemetry', 'commands', 'controller']
    finally:
        core.close()
    assert [r.level for r in diagnose(core.snapshot())] == [Level.STALE] * 4


def test_telemetry_lost_snapshot_is_an_error() -> None:
    core = CanDriverCore(DriverConfig(interface='virtual', channel='parts_test_2'))
    snapshot = dataclasses.replace(core.snapshot(), closed=False, telemetry_lost=True,
                                   now=time.monotonic())
    telemetry = diagnose(snapshot)[1]
    assert telemetry.level is Level.ERROR and 'telemetry stopped' in telemetry.message
