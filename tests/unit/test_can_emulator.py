"""The controller emulator: protocol answers, firmware watchdog, each injected fault, CLI."""
from __future__ import annotations

import itertools

import can
import pytest

from valve_driver_pkg.emulator import (ControllerEmulator, ControllerState, EmulatorConfig,
                                       EmulatorFault, EmulatorRemote, parse_fault_spec)
from valve_driver_pkg.emulator.controller import UNKNOWN_INJECTED_ID
from valve_driver_pkg.emulator.emulator_main import apply_effects, main
from valve_driver_pkg.errors import FrameRejected
from valve_driver_pkg.protocol import (COMMAND, PERIOD, PRESSURE, STATUS, TELEMETRY,
                                       BusCondition, ValveCodec, parse_error_frame)
from valve_model_pkg.model import ElectronicsConfig, ValveStepper, load_parameters

PARAMS = load_parameters()
_channels = itertools.count()


class Rig:
    """An emulator and a host bus on a private virtual channel; model time set by hand."""

    def __init__(self, **config) -> None:
        channel = f'emu_test_{next(_channels)}'
        self.emu_bus = can.Bus(interface='virtual', channel=channel)
        self.host = can.Bus(interface='virtual', channel=channel)
        self.codec = ValveCodec(config.get('node_id', 0))
        self.stepper = ValveStepper(PARAMS, ElectronicsConfig())
        self.emu = ControllerEmulator(self.emu_bus, self.stepper, EmulatorConfig(**config),
                                      fault_seed=1)
        self.counter = 0

    def command(self, duty: float, freq: float = 50.0, enable: int = 1, clear: int = 0,
                corrupt: bool = False) -> None:
        msg = self.codec.encode(COMMAND, {'Duty': duty, 'PwmFrequency': freq,
                                          'Enable': enable, 'ClearFaults': clear,
                                          'HostId': 1},
                                self.counter)
        self.counter = (self.counter + 1) & 0xF
        if corrupt:
            msg.data[7] ^= 0xFF
        self.host.send(msg)
        self.emu.poll(0.5)

    def frames(self) -> list[can.Message]:
        out = []
        msg = self.host.recv(0.0)
        while msg is not None:
            out.append(msg)
            msg = self.host.recv(0.0)
        return out

    def decoded(self, name: str) -> list:
        out = []
        for msg in self.frames():
            if msg.is_error_frame or self.codec.classify(msg.arbitration_id) is None:
                continue
            if self.codec.classify(msg.arbitration_id)[0] == name:
                out.append(self.codec.decode(msg))
        return out

    def close(self) -> None:
        self.emu_bus.shutdown()
        self.host.shutdown()


@pytest.fixture
def rig():
    r = Rig()
    yield r
    r.close()


def test_telemetry_every_millisecond_and_status_at_10_hz(rig) -> None:
    rig.emu.step(0.2)
    frames = rig.frames()
    names = [rig.codec.classify(f.arbitration_id)[0] for f in frames]
    assert names.count(TELEMETRY) == 201           # t = 0, 1 ms, ..., 200 ms
    assert names.count(STATUS) == 3                # t = 0, 100 ms, 200 ms
    counters = [rig.codec.decode(f).counter for f in frames
                if rig.codec.classify(f.arbitration_id)[0] == TELEMETRY]
    assert counters[:18] == list(range(16)) + [0, 1]
    status = [rig.codec.decode(f) for f in frames
              if rig.codec.classify(f.arbitration_id)[0] == STATUS][-1]
    assert status.signals['ControllerState'] == ControllerState.INIT


def test_command_drives_the_model_and_is_reported() -> None:
    rig = Rig(command_timeout_s=0.0)
    rig.command(0.5, 50.0)
    rig.emu.step(0.1)
    telemetry = rig.decoded(TELEMETRY)
    assert max(t.signals['CoilCurrent'] for t in telemetry) > 0.3
    assert max(t.signals['SpoolPosition'] for t in telemetry) > 0.9 * PARAMS.stroke_m
    assert all(t.signals['Enabled'] == 1 and t.signals['PositionValid'] == 1
               for t in telemetry)
    rig.emu.step(0.2)
    period = rig.decoded(PERIOD)
    # Sent when the period average or the command in force changes, and every 100 ms;
    # in the periodic steady state the quantised average repeats, so only refreshes remain.
    assert 1 <= len(period) <= 4
    assert period[-1].signals['DutyActive'] == pytest.approx(0.5)
    assert period[-1].signals['PwmFrequencyActive'] == pytest.approx(50.0)
    sample = rig.stepper.sample()
    assert period[-1].signals['PositionAverage'] == pytest.approx(sample.position_avg_m,
                                                                  abs=5e-9)
    rig.close()


def test_pressure_frame_sets_the_model_pressures(rig) -> None:
    rig.host.send(rig.codec.encode(PRESSURE, {'SupplyPressure': 250_000.0,
                                              'OutputPressure': 20_000.0}, 0))
    rig.emu.poll(0.5)
    sample = rig.stepper.sample()
    assert (sample.supply_pressure_pa, sample.output_pressure_pa) == (250_000.0, 20_000.0)


def test_firmware_watchdog_closes_the_valve(rig) -> None:
    rig.command(0.6)
    rig.emu.step(0.05)
    rig.frames()
    rig.emu.step(0.2)                      # no command for 150 ms > 100 ms
    telemetry = rig.decoded(TELEMETRY)
    assert telemetry[-1].signals['CommandTimeout'] == 1
    assert telemetry[-1].signals['Enabled'] == 0
    assert rig.stepper.sample().duty == 0.0
    rig.command(0.6)                       # a valid command releases it
    rig.emu.step(0.25)
    assert rig.decoded(TELEMETRY)[-1].signals['CommandTimeout'] == 0


def test_disable_closes_without_a_timeout_fault(rig) -> None:
    rig.command(0.6)
    rig.command(0.6, enable=0)
    rig.emu.step(0.5)
    telemetry = rig.decoded(TELEMETRY)
    assert telemetry[-1].signals['CommandTimeout'] == 0
    assert rig.stepper.sample().duty == 0.0


def test_bad_command_checksum_is_ignored_and_flagged(rig) -> None:
    rig.command(0.4)
    rig.command(0.9, corrupt=True)
    rig.emu.step(0.1)
    status = rig.decoded(STATUS)[-1]
    assert status.signals['FaultCommandChecksum'] == 1
    assert rig.emu._duty == pytest.approx(0.4)
    assert rig.emu.stats['commands_rejected'] == 1


def test_frozen_command_counter_is_ignored(rig) -> None:
    rig.command(0.4)
    rig.counter = (rig.counter - 1) & 0xF          # repeat the previous counter
    rig.command(0.9)
    assert rig.emu._duty == pytest.approx(0.4)
    rig.emu.step(0.1)
    assert rig.decoded(STATUS)[-1].signals['FaultCommandCounter'] == 1


@pytest.mark.parametrize('fault', [EmulatorFault.SILENT, EmulatorFault.BUS_OFF])
def test_silent_and_bus_off_stop_all_traffic_then_resume(rig, fault) -> None:
    rig.emu.step(0.01)
    rig.frames()
    rig.emu.inject(fault, duration_s=0.05)
    rig.emu.step(0.04)
    during = rig.frames()
    data_frames = [f for f in during if not f.is_error_frame]
    assert data_frames == []
    errors = [parse_error_frame(f).condition for f in during if f.is_error_frame]
    assert errors == ([BusCondition.BUS_OFF] if fault is EmulatorFault.BUS_OFF else [])
    rig.emu.step(0.1)
    after = rig.frames()
    if fault is EmulatorFault.BUS_OFF:
        assert parse_error_frame(after[0]).condition is BusCondition.RESTARTED
    assert sum(1 for f in after if not f.is_error_frame) > 40


def test_drop_telemetry_keeps_counting(rig) -> None:
    rig.emu.inject(EmulatorFault.DROP_TELEMETRY, probability=0.5)
    rig.emu.step(0.999)
    telemetry = rig.decoded(TELEMETRY)
    assert 400 < len(telemetry) < 600
    jumps = sum(1 for a, b in zip(telemetry, telemetry[1:]) if (b.counter - a.counter) & 0xF != 1)
    assert jumps > 100


def test_corrupt_checksum(rig) -> None:
    rig.emu.inject(EmulatorFault.CORRUPT_CHECKSUM)
    rig.emu.step(0.01)
    telemetry = [f for f in rig.frames() if f.arbitration_id == 0x690]
    assert len(telemetry) == 11
    for frame in telemetry:
        with pytest.raises(FrameRejected, match='checksum'):
            rig.codec.decode(frame)


def test_freeze_counter(rig) -> None:
    rig.emu.step(0.003)
    rig.emu.inject(EmulatorFault.FREEZE_COUNTER)
    rig.emu.step(0.02)
    counters = [t.counter for t in rig.decoded(TELEMETRY)]
    assert len(set(counters[4:])) == 1


def test_wrong_length_and_unknown_id(rig) -> None:
    rig.emu.inject(EmulatorFault.WRONG_LENGTH)
    rig.emu.inject(EmulatorFault.UNKNOWN_ID)
    rig.emu.step(0.01)
    frames = rig.frames()
    telemetry = [f for f in frames if f.arbitration_id == 0x690]
    assert telemetry and all(len(f.data) == 6 for f in telemetry)
    assert sum(1 for f in frames if f.arbitration_id == UNKNOWN_INJECTED_ID) == len(telemetry)


def test_error_passive_on_and_off(rig) -> None:
    rig.emu.inject(EmulatorFault.ERROR_PASSIVE)
    rig.emu.step(0.01)
    rig.emu.inject(EmulatorFault.ERROR_PASSIVE, active=False)
    conditions = [parse_error_frame(f).condition for f in rig.frames() if f.is_error_frame]
    assert conditions == [BusCondition.ERROR_PASSIVE, BusCondition.ERROR_ACTIVE]


def test_overcurrent_latches_until_clear_faults(rig) -> None:
    rig.command(0.5)
    rig.emu.inject(EmulatorFault.OVERCURRENT)
    rig.emu.step(0.15)
    status = rig.decoded(STATUS)[-1].signals
    assert status['FaultOvercurrent'] == 1 and status['ControllerState'] == ControllerState.FAULT
    rig.command(0.5, clear=1)
    rig.emu.inject(EmulatorFault.OVERCURRENT, active=False)
    rig.emu.step(0.25)
    status = rig.decoded(STATUS)[-1].signals
    assert status['FaultOvercurrent'] == 0 and status['ControllerState'] == ControllerState.RUNNING


def test_control_frames_switch_faults() -> None:
    rig = Rig(fault_injection=True)
    try:
        _control_frames_switch_faults(rig)
    finally:
        rig.close()


def _control_frames_switch_faults(rig) -> None:
    remote = EmulatorRemote(rig.host, node_id=0)
    remote.inject(EmulatorFault.SILENT, duration_s=0.02)
    rig.emu.poll(0.5)
    assert rig.emu.faults.is_active(EmulatorFault.SILENT)
    rig.emu.step(0.03)
    assert not rig.emu.faults.is_active(EmulatorFault.SILENT)
    remote.inject(EmulatorFault.FREEZE_COUNTER)
    remote.clear()
    rig.emu.poll(0.5)
    rig.emu.poll(0.1)
    assert rig.emu.faults.snapshot() == {}


def test_control_frames_are_counted_and_ignored_without_fault_injection() -> None:
    r = Rig()                                        # the default: fault injection off
    try:
        EmulatorRemote(r.host).inject(EmulatorFault.SILENT)
        EmulatorRemote(r.host).inject(EmulatorFault.OVERCURRENT)
        r.emu.poll(0.5)
        assert not r.emu.faults.is_active(EmulatorFault.SILENT)
        assert not r.emu.faults.is_active(EmulatorFault.OVERCURRENT)
        assert r.emu.stats['control_frames_ignored'] == 2
        assert r.emu.stats['control_frames'] == 0
    finally:
        r.close()


def test_cli_fault_injection_flag_is_off_by_default() -> None:
    from valve_driver_pkg.emulator.emulator_main import build_parser
    assert build_parser().parse_args([]).fault_injection is False
    assert build_parser().parse_args(['--fault-injection']).fault_injection is True


def test_clear_faults_keeps_a_latch_whose_condition_persists(rig) -> None:
    rig.command(0.5)
    rig.emu.inject(EmulatorFault.OVERCURRENT, duration_s=0.3)   # the condition lasts 0.3 s
    rig.emu.step(0.15)
    rig.command(0.5, clear=1)                                    # too early: still present
    rig.emu.step(0.25)
    status = rig.decoded(STATUS)[-1].signals
    assert status['FaultOvercurrent'] == 1 and status['ControllerState'] == ControllerState.FAULT
    rig.emu.step(0.35)                                           # the condition has ended
    assert rig.decoded(STATUS)[-1].signals['FaultOvercurrent'] == 1   # latched until cleared
    rig.command(0.5, clear=1)
    rig.emu.step(0.45)
    status = rig.decoded(STATUS)[-1].signals
    assert status['FaultOvercurrent'] == 0 and status['ControllerState'] == ControllerState.RUNNING
    assert rig.emu.stats['fault_clears'] == 2


def test_an_injected_overcurrent_event_is_cleared_at_once(rig) -> None:
    rig.command(0.5)
    rig.emu.inject(EmulatorFault.OVERCURRENT)                   # an event: latched until clear
    rig.emu.step(0.15)
    rig.command(0.5, clear=1)
    rig.emu.step(0.25)
    status = rig.decoded(STATUS)[-1].signals
    assert status['FaultOvercurrent'] == 0 and status['ControllerState'] == ControllerState.RUNNING
    assert not rig.emu.faults.is_active(EmulatorFault.OVERCURRENT)


def test_the_host_ids_of_commands_are_remembered(rig) -> None:
    rig.command(0.2)
    msg = rig.codec.encode(COMMAND, {'Duty': 0.8, 'PwmFrequency': 50.0, 'Enable': 1,
                                     'ClearFaults': 0, 'HostId': 9}, rig.counter)
    rig.counter += 1
    rig.host.send(msg)
    rig.emu.poll(0.5)
    assert set(rig.emu.host_ids) == {1, 9}


def test_other_node_ids_are_ignored() -> None:
    r = Rig(node_id=3)
    try:
        ValveCodec(4)
        r.host.send(ValveCodec(4).encode(COMMAND, {'Duty': 0.9, 'PwmFrequency': 50.0,
                                                   'Enable': 1, 'ClearFaults': 0,
                                                   'HostId': 1}, 0))
        r.emu.poll(0.5)
        assert r.emu.stats['commands'] == 0
        r.command(0.3)
        assert r.emu.stats['commands'] == 1
        r.emu.step(0.0)
        assert 0x690 + 3 in [f.arbitration_id for f in r.frames()]
    finally:
        r.close()


@pytest.mark.parametrize('text, expected', [
    ('silent', (EmulatorFault.SILENT, 0.0, 0.0, 1.0)),
    ('bus_off:2:0.5', (EmulatorFault.BUS_OFF, 2.0, 0.5, 1.0)),
    ('DROP_TELEMETRY:1:0:0.1', (EmulatorFault.DROP_TELEMETRY, 1.0, 0.0, 0.1)),
])
def test_fault_spec_parsing(text: str, expected: tuple) -> None:
    assert parse_fault_spec(text) == expected


@pytest.mark.parametrize('text', ['nonsense', 'silent:x', 'silent:1:2:3:4', 'silent:-1',
                                  'drop_telemetry:0:0:2'])
def test_bad_fault_specs_are_refused(text: str) -> None:
    with pytest.raises(ValueError):
        parse_fault_spec(text)


def test_effect_option_switches_an_effect_on() -> None:
    heated = apply_effects(PARAMS, ['coil_heating'], ['thermal_resistance_k_per_w=80'])
    assert heated.thermal_resistance_k_per_w == 80.0
    assert heated.active_effects() == ('coil_heating',)
    default = apply_effects(PARAMS, ['end_stop_bounce'], [])
    assert default.restitution_coefficient == pytest.approx(0.45)
    assert apply_effects(PARAMS, [], []) == PARAMS


@pytest.mark.parametrize('effects, values, match', [
    (['no_such_effect'], [], 'unknown effect'),
    ([], ['thermal_resistance_k_per_w=80'], 'not a parameter of the effects'),
    (['coil_heating'], ['thermal_resistance_k_per_w'], 'FIELD=VALUE'),
    (['coil_heating'], ['thermal_resistance_k_per_w=hot'], 'not a number'),
])
def test_bad_effect_options_are_refused(effects, values, match) -> None:
    with pytest.raises(ValueError, match=match):
        apply_effects(PARAMS, effects, values)


def test_program_runs_on_a_virtual_bus_and_stops(capsys) -> None:
    code = main(['--interface', 'virtual', '--channel', 'emu_main_test', '--duration-s', '0.2',
                 '--effect', 'coil_heating', '--fault', 'drop_telemetry:0.05:0.05:0.5'])
    assert code == 0
    out = capsys.readouterr().out
    assert 'valve_controller_emulator ready: virtual emu_main_test node 0' in out


def test_program_refuses_bad_arguments() -> None:
    assert main(['--interface', 'virtual', '--channel', 'x', '--effect', 'nope']) == 2
    assert main(['--interface', 'virtual', '--channel', 'x', '--fault', 'nope']) == 2
