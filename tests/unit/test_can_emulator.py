"""The controller emulator: protocol answers, firmware watchdog, each injected fault, CLI."""
from __future__ import annotations

import itertools

import can
import numpy as np
import pytest
from suite_waits import wait_until

from valve_driver_pkg.emulator import (ControllerEmulator, ControllerState, EmulatorConfig,
                                       EmulatorFault, EmulatorRemote, parse_fault_spec)
from valve_driver_pkg.emulator.controller import UNKNOWN_INJECTED_ID
from valve_driver_pkg.emulator.emulator_main import apply_effects, main
from valve_driver_pkg.errors import FrameRejected
from valve_driver_pkg.protocol import (COMMAND, DRIVE, PERIOD, PRESSURE, STATUS, TELEMETRY,
                                       TELEMETRY_MEAN, BusCondition, DriveMode, ValveCodec,
                                       parse_error_frame)
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
                corrupt: bool = False, mode: DriveMode | None = None) -> None:
        signals = {'Duty': duty, 'PwmFrequency': freq, 'Enable': enable, 'ClearFaults': clear,
                   'HostId': 1}
        if mode is not None:
            signals['DriveMode'] = int(mode)
        msg = self.codec.encode(COMMAND, signals, self.counter)
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
    assert rig.emu.command.duty == pytest.approx(0.4)
    assert rig.emu.stats['commands_rejected'] == 1


def test_frozen_command_counter_is_ignored(rig) -> None:
    rig.command(0.4)
    rig.counter = (rig.counter - 1) & 0xF          # repeat the previous counter
    rig.command(0.9)
    assert rig.emu.command.duty == pytest.approx(0.4)
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


# --- the drive mode comes from the frames --------------------------------------------------------
def _by_name(rig: Rig) -> dict[str, list]:
    """Every frame waiting, decoded and grouped by message name (in sending order)."""
    out: dict[str, list] = {}
    for msg in rig.frames():
        found = None if msg.is_error_frame else rig.codec.classify(msg.arbitration_id)
        if found is not None:
            out.setdefault(found[0], []).append(rig.codec.decode(msg))
    return out


@pytest.mark.parametrize('mode', [DriveMode.BENCH, DriveMode.NORMAL])
def test_bench_mode_gives_the_coil_the_unchopped_supply_normal_mode_chops(mode) -> None:
    rig = Rig(command_timeout_s=0.0)
    try:
        rig.command(1.0, 50.0, mode=mode)
        rig.emu.step(0.1)
        frames = _by_name(rig)
    finally:
        rig.close()
    late = slice(25, None)   # from 25 ms: past the boost and the first period start
    volts = [f.signals['CoilVoltage'] for f in frames[TELEMETRY][late]]
    means = [f.signals['CoilVoltageMean'] for f in frames[TELEMETRY_MEAN][late]]
    amps = [f.signals['CoilCurrent'] for f in frames[TELEMETRY][late]]
    drive = frames[DRIVE][-1].signals
    assert drive['DriveModeActive'] == mode
    assert drive['SupplyVoltageMeasured'] == pytest.approx(24.0)
    if mode is DriveMode.BENCH:
        assert all(v == pytest.approx(24.0, abs=0.005) for v in volts + means)
        assert min(amps) > 2.0 * ElectronicsConfig().holding_current_a   # no current control
        assert (drive['HoldingCurrent'], drive['CapacitorVoltage']) == (0.0, 0.0)
        assert rig.stepper.electronics.current_control is False
    else:
        # the chopper holds the current: its 20 kHz edges sit on the 1 kHz sampling grid,
        # so the interval means (not the samples) show the chopping
        assert max(means) < 0.5 * 24.0
        assert max(amps) < 1.5 * ElectronicsConfig().holding_current_a
        assert drive['HoldingCurrent'] == pytest.approx(ElectronicsConfig().holding_current_a)
        assert drive['CapacitorVoltage'] == pytest.approx(24.0)


def test_a_mode_change_while_driving_waits_for_the_period_start() -> None:
    rig = Rig(command_timeout_s=0.0)
    try:
        rig.command(1.0, 50.0)                      # normal; periods start every 20 ms
        rig.emu.step(0.031)
        rig.frames()
        rig.command(1.0, 50.0, mode=DriveMode.BENCH)
        assert rig.emu.mode_requested is DriveMode.BENCH
        assert rig.emu.mode_active is DriveMode.NORMAL   # duty 1 in force: not yet
        rig.emu.step(0.0395)
        assert rig.emu.mode_active is DriveMode.NORMAL
        before = _by_name(rig)
        rig.emu.step(0.045)
        assert rig.emu.mode_active is DriveMode.BENCH   # switched at the 40 ms period start
        after = _by_name(rig)
    finally:
        rig.close()
    assert all(f.signals['DriveModeActive'] == 0 for f in before.get(DRIVE, []))
    # reported at once (before the 41 ms telemetry), not only with the 10 Hz heartbeat
    assert [f.signals['DriveModeActive'] for f in after[DRIVE]] == [1]
    means = [f.signals['CoilVoltageMean'] for f in after[TELEMETRY_MEAN]]   # 40 .. 45 ms
    assert all(v == pytest.approx(24.0, abs=0.005) for v in means[1:])
    assert max(f.signals['CoilVoltageMean'] for f in before[TELEMETRY_MEAN]) < 12.0  # chopped


def test_a_mode_change_at_duty_0_acts_at_once_and_never_energises() -> None:
    rig = Rig(command_timeout_s=0.0)
    try:
        rig.emu.step(0.013)
        rig.command(0.0, 50.0, mode=DriveMode.BENCH)
        assert rig.emu.mode_active is DriveMode.BENCH    # at once: duty 0 is in force
        rig.emu.step(0.1)
        telemetry = rig.decoded(TELEMETRY)
        assert all(f.signals['CoilCurrent'] == 0.0 and f.signals['CoilVoltage'] == 0.0
                   for f in telemetry)
        rig.command(0.0, 50.0, mode=DriveMode.NORMAL)
        assert rig.emu.mode_active is DriveMode.NORMAL
        assert rig.stepper.electronics == ElectronicsConfig()
    finally:
        rig.close()


@pytest.mark.parametrize('mode', [DriveMode.BENCH, DriveMode.NORMAL])
def test_duty_0_switches_off_at_once_in_either_mode(mode) -> None:
    rig = Rig(command_timeout_s=0.0)
    try:
        rig.command(1.0, 50.0, mode=mode)
        rig.emu.step(0.05)
        on = rig.decoded(TELEMETRY)[-1].signals
        rig.command(0.0, 50.0, mode=mode)             # mid-period (periods at 40, 60 ms)
        rig.emu.step(0.051)
        off = rig.decoded(TELEMETRY)[-1].signals     # 1 ms later
    finally:
        rig.close()
    assert off['CoilCurrent'] < on['CoilCurrent']
    if mode is DriveMode.BENCH:
        assert off['CoilVoltage'] == 0.0             # no capacitor: the coil freewheels
    else:
        assert off['CoilVoltage'] < -1.0             # the capacitor's release pulse


def test_the_drivers_drive_mode_reaches_the_emulator() -> None:
    """drive_mode of the driver -> ValveCommand.DriveMode -> the emulator's electronics, and
    the emulator's ValveDrive back into the driver's controller diagnostics."""
    from valve_driver_pkg.driver import CanDriverCore, DriverConfig

    channel = f'emu_test_{next(_channels)}'
    emu_bus = can.Bus(interface='virtual', channel=channel)
    stepper = ValveStepper(PARAMS, ElectronicsConfig())
    emu = ControllerEmulator(emu_bus, stepper, EmulatorConfig(command_timeout_s=0.0))
    core = CanDriverCore(DriverConfig(interface='virtual', channel=channel,
                                      drive_mode='bench', command_timeout_s=0.0))

    def poll_until(predicate, what: str) -> None:
        wait_until(predicate, what=what, step=lambda: emu.poll(0.05))

    try:
        assert core.drive_mode == 'bench'
        core.open()
        core.activate()
        core.set_command(1.0, 50.0)
        poll_until(lambda: emu.mode_requested is DriveMode.BENCH, 'a bench command')
        emu.step(0.06)
        assert emu.mode_active is DriveMode.BENCH
        assert stepper.sample().coil_voltage_v == pytest.approx(24.0)
        wait_until(lambda: core.report()[3].values.get('drive_mode') == 'bench',
                   what='a ValveDrive at the driver')
        values = core.report()[3].values
        assert values['drive_mode_requested'] == 'bench'
        assert values['holding_current_a'] == 0.0
        assert core.set_drive_mode('normal') == 'bench'
        poll_until(lambda: emu.mode_requested is DriveMode.NORMAL, 'a normal command')
        emu.step(0.085)                              # the 80 ms period start
        assert emu.mode_active is DriveMode.NORMAL
        assert stepper.electronics.current_control is True
        with pytest.raises(ValueError, match='turbo'):
            core.set_drive_mode('turbo')
        assert core.drive_mode == 'normal'
    finally:
        core.close()
        emu_bus.shutdown()
    with pytest.raises(ValueError, match="'turbo'.*'normal', 'bench'"):
        DriverConfig(drive_mode='turbo')


def test_adc_noise_is_on_the_reported_current_only() -> None:
    """--current-noise-a: the reported current and its interval mean carry the ADC's noise
    (seeded); the model's own current, which the overcurrent check reads, does not."""
    quiet, noisy = Rig(), Rig(current_noise_a=0.003, noise_seed=7)
    try:
        reported = {}
        for name, r in (('quiet', quiet), ('noisy', noisy)):
            r.emu.step(0.1)   # valve at rest: the coil current is exactly 0
            reported[name] = np.array([m.signals['CoilCurrentMean']
                                       for m in r.decoded(TELEMETRY_MEAN)])
        assert np.all(reported['quiet'] == 0.0)
        std = float(np.std(reported['noisy']))
        assert 0.002 < std < 0.004, std
        assert noisy.emu.stepper.sample().coil_current_a == 0.0
    finally:
        quiet.close()
        noisy.close()
    with pytest.raises(ValueError):
        EmulatorConfig(current_noise_a=-1e-3)


class _StallingHost:
    """The real-time clock of :meth:`ControllerEmulator.run` [s], advanced 1 ms a call,
    with a host that sends its duty command every 10 ms of that clock. At ``stall_at_s``
    the clock jumps by ``stall_s`` (the emulator's loop was descheduled); the host keeps
    sending through the stall unless ``host_stops``, and the frames wait in the bus."""

    def __init__(self, rig: Rig, stall_at_s: float, stall_s: float, host_stops: bool) -> None:
        self.rig, self.t, self.next_command_t = rig, 0.0, 0.0
        self.stall_at_s, self.stall_s, self.host_stops = stall_at_s, stall_s, host_stops

    def __call__(self) -> float:
        self.t += 1e-3
        if self.stall_at_s is not None and self.t >= self.stall_at_s:
            self.t += self.stall_s
            self.stall_at_s = None
            if self.host_stops:
                self.next_command_t = float('inf')
        while self.next_command_t <= self.t:
            self.rig.host.send(self.rig.codec.encode(
                COMMAND, {'Duty': 0.6, 'PwmFrequency': 50.0, 'Enable': 1, 'ClearFaults': 0,
                          'HostId': 1}, self.rig.counter))
            self.rig.counter = (self.rig.counter + 1) & 0xF
            self.next_command_t += 0.01
        return self.t


@pytest.mark.parametrize('host_stops', [False, True])
def test_a_stall_of_the_emulator_is_not_taken_for_silence_of_the_host(host_stops) -> None:
    rig = Rig()
    clock = _StallingHost(rig, stall_at_s=0.1, stall_s=0.3, host_stops=host_stops)
    rig.emu.run(duration_s=0.5, clock=clock)
    timeouts = [t.signals['CommandTimeout'] for t in rig.decoded(TELEMETRY)]
    assert rig.emu.stats['overruns'] > 0           # the stall is counted
    if host_stops:                                 # a host that stopped still trips it
        assert timeouts[-1] == 1 and rig.emu.output_duty == 0.0
    else:                                          # the commands waited in the bus
        assert not any(timeouts) and rig.emu.output_duty == pytest.approx(0.6)
    rig.close()
