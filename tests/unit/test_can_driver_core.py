"""The CAN driver core with the controller emulator on python-can's virtual bus.

* equivalence: duty command -> frame -> emulator -> telemetry -> valve state equals what the
  simulator computes (a ValveStepper fed the same commands) within the protocol's
  quantisation (deterministic: the emulator's model time is stepped by the test);
* each fault and its documented reaction (real time, emulator in a thread);
* command clamping, the duty watchdog, lifecycle of the bus, recovery of a lost bus;
* fuzz: random frames into the receive path; nothing escapes, every frame is counted.
"""
from __future__ import annotations

import gc
import itertools
import math
import sys
import threading
import time

import can
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from suite_waits import SCHEDULING_ALLOWANCE_S, wait_until

from valve_driver_pkg.canbus import TcpLoopbackBus, TcpLoopbackHub
from valve_driver_pkg.driver import CanDriverCore, DriverConfig, Level
from valve_driver_pkg.emulator import ControllerEmulator, EmulatorConfig, EmulatorFault
from valve_driver_pkg.errors import BusOpenError
from valve_driver_pkg.protocol import ValveCodec
from valve_model_pkg.model import (ElectronicsConfig, ValveStepper, load_parameters,
                                   orifice_mass_flow)
from valve_model_pkg.model.sample import ValveSample

PARAMS = load_parameters()
PERIOD_S = 0.001
_channels = itertools.count()


def mass_flow(x: float, supply: float, output: float) -> float:
    return float(orifice_mass_flow(x, supply, output, PARAMS))


@pytest.fixture(autouse=True)
def no_open_virtual_channels():
    """Every test closes the virtual buses it opened; GIL hand-off as in the programs."""
    interval = sys.getswitchinterval()
    sys.setswitchinterval(0.0005)   # what valve_can_driver and the emulator set (README)
    gc.collect()
    gc.freeze()                     # as the programs do after start-up: short GC pauses
    yield
    gc.unfreeze()
    sys.setswitchinterval(interval)
    from can.interfaces import virtual
    assert not virtual.channels, f'virtual channels left open: {list(virtual.channels)}'


class LiveRig:
    """Driver core + emulator running in real time on a private virtual channel."""

    def __init__(self, emulator: dict | None = None, **driver) -> None:
        self.channel = f'core_test_{next(_channels)}'
        self.emu_bus = can.Bus(interface='virtual', channel=self.channel)
        self.emu = ControllerEmulator(self.emu_bus, ValveStepper(PARAMS, ElectronicsConfig()),
                                      EmulatorConfig(**(emulator or {})), fault_seed=3)
        self.states: list[ValveSample] = []
        self.level_changes: list[tuple[float, dict]] = []
        driver.setdefault('command_timeout_s', 0.0)
        self.core = CanDriverCore(DriverConfig(interface='virtual', channel=self.channel,
                                               **driver),
                                  mass_flow=mass_flow, on_state=self.states.append,
                                  on_diagnostics_changed=self._on_diag)
        self.emu.start()
        try:
            self.core.open()
            self.core.activate()
            wait_until(lambda: len(self.states) > 20, what='valve states')
        except BaseException:
            self.close()
            raise

    def _on_diag(self) -> None:
        self.level_changes.append((time.monotonic(), self.levels()))

    def levels(self) -> dict:
        return {r.name: r.level for r in self.core.report()}

    def level(self, name: str) -> Level:
        return self.levels()[name]

    def status(self, name: str):
        return next(r for r in self.core.report() if r.name == name)

    def close(self) -> None:
        self.core.close()
        self.emu.stop()
        self.emu_bus.shutdown()


@pytest.fixture
def live():
    rig = LiveRig()
    yield rig
    rig.close()


# --- equivalence with the simulator ------------------------------------------------------------
def test_valve_state_matches_the_simulator_within_quantisation() -> None:
    channel = f'core_test_{next(_channels)}'
    emu_bus = can.Bus(interface='virtual', channel=channel)
    emu = ControllerEmulator(emu_bus, ValveStepper(PARAMS, ElectronicsConfig()),
                             EmulatorConfig(command_timeout_s=0.0))
    reference = ValveStepper(PARAMS, ElectronicsConfig())   # what valve_simulator runs
    reference.set_pressures(400_000.0, 0.0)
    states: list[ValveSample] = []
    arrived = threading.Condition()

    def on_state(sample: ValveSample) -> None:
        with arrived:
            states.append(sample)
            arrived.notify()

    core = CanDriverCore(DriverConfig(interface='virtual', channel=channel,
                                      command_timeout_s=0.0),
                         mass_flow=mass_flow, on_state=on_state)
    mass_flow(1e-4, 400_000.0, 0.0)   # load the compiled orifice equation (seconds) now
    core.open()
    core.activate()
    expected = []
    k = 0
    try:
        for duty, freq, duration_s in [(0.25, 50.0, 0.1), (0.5, 50.0, 0.1), (0.75, 100.0, 0.08),
                                       (0.3333, 40.0, 0.1), (0.0, 50.0, 0.05)]:
            core.set_command(duty, freq)
            wait_until(lambda: (emu.command.enabled, emu.command.duty,
                                emu.command.pwm_frequency_hz)
                       == (True, pytest.approx(duty, abs=1e-9), pytest.approx(freq)),
                       what=f'duty {duty} at the emulator', step=lambda: emu.poll(0.01))
            reference.set_command(duty, freq)
            for _ in range(round(duration_s / PERIOD_S)):
                t = k * PERIOD_S
                emu.step(t)
                reference.advance_to(t)
                expected.append(reference.sample())
                k += 1
                with arrived:
                    assert arrived.wait_for(lambda: len(states) >= len(expected),
                                            SCHEDULING_ALLOWANCE_S), 'valve state'
                emu.poll(0.0)
    finally:
        core.close()
        emu_bus.shutdown()
    assert len(states) == len(expected) == 430
    # Quantisation of the protocol (DBC scale / 2) plus float rounding.
    tolerances = {'coil_current_a': 1e-4 + 1e-9, 'coil_voltage_v': 0.005 + 1e-9,
                  'spool_position_m': 5e-9 + 1e-13, 'position_avg_m': 5e-9 + 1e-13,
                  'duty': 5e-5, 'pwm_frequency_hz': 0.05, 'supply_pressure_pa': 25.0,
                  'output_pressure_pa': 25.0,
                  'mass_flow_kg_s': mass_flow(5e-9, 400_000.0, 0.0) + 1e-12}
    for field, tol in tolerances.items():
        ref_field = 'mass_flow_kg_s' if field == 'mass_flow_kg_s' else field
        worst = max(abs(getattr(s, field) - getattr(r, ref_field))
                    for s, r in zip(states, expected))
        assert worst <= tol, f'{field}: worst difference {worst!r} > {tol!r}'
    assert all(s.position_measured for s in states)
    assert max(s.coil_current_a for s in states) > 0.5      # the valve really switched


# --- faults and reactions ------------------------------------------------------------------------
def test_telemetry_silence_is_an_error_and_recovers(live) -> None:
    """Frames really missing (silence beyond the documented timeout) -> ERROR, then OK.

    No wall-clock deadline: the reaction time is the driver's own measurement and is
    checked against the rule (never before the timeout); the rule itself is checked on
    simulated time in test_can_telemetry_health.py.
    """
    timeout = live.core.config.telemetry_timeout_s
    assert timeout == pytest.approx(0.1)          # 50 periods at 1 kHz, at least 100 ms
    live.emu.inject(EmulatorFault.SILENT)        # until cleared: the ERROR lasts until then
    wait_until(lambda: live.level('telemetry') is Level.ERROR,
               timeout + SCHEDULING_ALLOWANCE_S, 'telemetry ERROR')
    status = live.status('telemetry')
    assert 'telemetry stopped' in status.message
    assert status.values['loss_reason'] == 'silence'
    assert status.values['lost_after_s'] > timeout    # declared only after the timeout
    live.emu.inject(EmulatorFault.SILENT, active=False)
    wait_until(lambda: live.level('telemetry') is not Level.ERROR,
               timeout + SCHEDULING_ALLOWANCE_S, 'telemetry back')
    count = len(live.states)
    wait_until(lambda: len(live.states) > count + 20, what='states flowing again')
    assert live.core.counters['telemetry_losses'] == 1


def test_counter_jumps_are_counted(live) -> None:
    live.emu.inject(EmulatorFault.DROP_TELEMETRY, probability=0.2)   # until cleared
    wait_until(lambda: live.core.counters['counter_jumps'] > 5
               and 'counter jumps' in live.status('telemetry').message,
               what='counter jumps, reported')
    live.emu.inject(EmulatorFault.CLEAR_ALL)
    assert live.core.counters['frames_lost'] >= live.core.counters['counter_jumps']
    live.core.close()   # no frame in flight between the two counts below
    # every lost frame is handed on with the sample after it (the means' interval)
    lost = [s.samples_lost_before for s in live.states]
    assert sum(lost) == live.core.counters['frames_lost'] and max(lost) >= 1


def test_checksum_failures_are_rejected_and_counted(live) -> None:
    live.emu.inject(EmulatorFault.CORRUPT_CHECKSUM, probability=0.3)   # until cleared
    wait_until(lambda: live.core.counters['rejected_checksum'] > 10
               and 'checksum' in live.status('telemetry').message,
               what='checksum rejects, reported')
    live.emu.inject(EmulatorFault.CLEAR_ALL)
    status = live.status('telemetry')
    assert status.values['rejected_total'] >= status.values['rejected_checksum']


def test_frozen_counter_is_an_error(live) -> None:
    live.emu.inject(EmulatorFault.FREEZE_COUNTER)
    wait_until(lambda: live.core.counters['rejected_counter_frozen'] >= 3, what='frozen frames')
    # The WARN before the limit also names 'counter_frozen': wait for the ERROR itself.
    wait_until(lambda: 'counter frozen at' in live.status('telemetry').message,
               what='frozen message')
    assert live.level('telemetry') is Level.ERROR
    live.emu.inject(EmulatorFault.FREEZE_COUNTER, active=False)
    wait_until(lambda: live.level('telemetry') is not Level.ERROR, what='recovery')


def test_wrong_lengths_and_unknown_ids_are_rejected_and_counted(live) -> None:
    # until cleared: how many frames a fixed window holds depends on the machine's load
    live.emu.inject(EmulatorFault.WRONG_LENGTH, probability=0.2)
    live.emu.inject(EmulatorFault.UNKNOWN_ID, probability=0.5)
    wait_until(lambda: live.core.counters['rejected_wrong_length'] > 5
               and live.core.counters['rejected_unknown_id'] > 5
               and live.level('CAN bus') is Level.WARN, what='rejections, CAN bus WARN')
    live.emu.inject(EmulatorFault.CLEAR_ALL)
    assert live.status('telemetry').values['rejected_wrong_length'] > 5


def test_error_passive_is_a_warning_until_error_active(live) -> None:
    live.emu.inject(EmulatorFault.ERROR_PASSIVE)
    wait_until(lambda: live.level('CAN bus') is Level.WARN, what='WARN')
    assert 'error passive' in live.status('CAN bus').message
    live.emu.inject(EmulatorFault.ERROR_PASSIVE, active=False)
    wait_until(lambda: live.status('CAN bus').values['condition'] == 'error_active',
               what='error active')
    assert live.core.counters['error_passive_events'] == 1


def test_bus_off_is_an_error_and_the_driver_recovers(live) -> None:
    live.emu.inject(EmulatorFault.BUS_OFF)       # until cleared: the ERROR lasts until then
    wait_until(lambda: live.level('CAN bus') is Level.ERROR, what='bus ERROR')
    assert 'bus-off' in live.status('CAN bus').message
    live.emu.inject(EmulatorFault.BUS_OFF, active=False)
    wait_until(lambda: live.level('CAN bus') is Level.OK, what='bus OK')
    wait_until(lambda: live.level('telemetry') is not Level.ERROR, what='telemetry back')
    assert live.core.counters['bus_off_events'] == 1
    assert live.core.counters['bus_recoveries'] >= 1


def test_controller_fault_is_reported() -> None:
    rig = LiveRig()
    try:
        rig.core.set_command(0.5, 50.0)
        rig.emu.inject(EmulatorFault.OVERCURRENT)
        wait_until(lambda: rig.level('controller') is Level.ERROR, what='controller ERROR')
        assert 'Overcurrent' in rig.status('controller').message
    finally:
        rig.close()


# --- commands ------------------------------------------------------------------------------------
@pytest.mark.parametrize('duty, freq, accepted, sent, clamped', [
    (0.5, 50.0, True, (0.5, 50.0), False),
    (1.5, 50.0, True, (1.0, 50.0), True),
    (-0.2, 50.0, True, (0.0, 50.0), True),
    (0.5, 5000.0, True, (0.5, 1000.0), True),
    (0.5, 0.01, True, (0.5, 0.1), True),
    (0.5, 0.0, True, (0.5, 50.0), False),           # 0 keeps the frequency in force
    (math.nan, 50.0, False, (0.0, 50.0), False),
    (math.inf, 50.0, False, (0.0, 50.0), False),
    (0.5, -10.0, False, (0.0, 50.0), False),
    (0.5, math.nan, False, (0.0, 50.0), False),
])
def test_commands_are_clamped_or_rejected_never_sent_raw(live, duty, freq, accepted, sent,
                                                         clamped) -> None:
    result = live.core.set_command(duty, freq)
    assert (result.accepted, result.clamped) == (accepted, clamped)
    assert live.core.command == pytest.approx(sent)
    wait_until(lambda: (live.emu.command.duty, live.emu.command.pwm_frequency_hz)
               == pytest.approx(sent), what='command at the controller')
    counters = live.core.counters
    assert counters['commands_clamped'] == int(clamped)
    assert counters['commands_rejected'] == int(not accepted)
    if clamped or not accepted:
        assert live.level('commands') is Level.WARN
        assert 'clamped' in result.message or 'rejected' in result.message


def test_watchdog_commands_duty_zero() -> None:
    # The watchdog on a clock the test moves (as a node on simulation time has it): the
    # duty is seen at the controller before the silence begins, however loaded the machine.
    rig = LiveRig(command_timeout_s=0.5)
    clock_s = [100.0]
    rig.core.host_command.watchdog_clock = lambda: clock_s[0]
    try:
        rig.core.set_command(0.6, 50.0)
        wait_until(lambda: rig.emu.output_duty == pytest.approx(0.6), what='duty at controller')
        assert rig.level('commands') is not Level.WARN
        clock_s[0] += 0.6                                # silence beyond the timeout
        wait_until(lambda: rig.level('commands') is Level.WARN, what='watchdog')
        assert rig.core.command == (0.0, 50.0)
        assert 'watchdog' in rig.status('commands').message
        wait_until(lambda: rig.emu.output_duty == 0.0, what='duty 0 at the controller')
        assert rig.core.counters['watchdog_trips'] == 1
        rig.core.set_command(0.4, 50.0)                  # a new command releases it
        wait_until(lambda: rig.emu.output_duty == pytest.approx(0.4), what='released')
    finally:
        rig.close()


def test_watchdog_on_the_nodes_clock_counts_its_time_not_the_wall() -> None:
    # A driver on simulation time: a held simulation sends no commands because no time
    # passes; however long the hold lasts on the wall clock, it is no silence.
    from valve_driver_pkg.driver.diagnostics import Tally
    from valve_driver_pkg.driver.host_command import HostCommand
    lock = threading.Condition(threading.RLock())
    host = HostCommand(DriverConfig(command_timeout_s=2.0), lock, Tally(), 1.0, 1000.0)
    sim_s = [10.0]
    host.watchdog_clock = lambda: sim_s[0]
    with lock:
        host.activate()
    assert host.set_command(0.6, 50.0).accepted
    assert not host.check_watchdog(time.monotonic() + 3600.0)   # an hour of wall time
    sim_s[0] = 11.9
    assert not host.check_watchdog(time.monotonic())
    assert host.command == (0.6, 50.0)
    sim_s[0] = 12.1                                  # 2.1 s of simulation time, no command
    assert host.check_watchdog(time.monotonic())
    assert host.command == (0.0, 50.0)
    host.set_command(0.4, 50.0)                      # a command releases it
    assert host.command == (0.4, 50.0)


def test_deactivate_commands_duty_zero_and_disables(live) -> None:
    live.core.set_command(0.7, 50.0)
    wait_until(lambda: live.emu.output_duty == pytest.approx(0.7), what='duty at controller')
    assert live.core.deactivate()
    wait_until(lambda: live.emu.output_duty == 0.0 and not live.emu.command.enabled,
               what='disabled')
    sent = live.core.counters['command_frames_sent']
    count = len(live.states)
    # Evidence on the controller's clock: 50 telemetry frames received are 50 ms, five
    # command periods in which an active driver would have sent frames and states.
    received = live.core.counters['telemetry_frames']
    wait_until(lambda: live.core.counters['telemetry_frames'] >= received + 50,
               what='50 more telemetry frames')
    assert live.core.counters['command_frames_sent'] == sent      # traffic stopped
    assert len(live.states) == count                               # no states while inactive


def test_pressures_reach_the_controller(live) -> None:
    assert live.core.set_pressures(250_000.0, 30_000.0)
    assert not live.core.set_pressures(math.nan, None)
    wait_until(lambda: live.emu.stepper.sample().supply_pressure_pa == 250_000.0,
               what='pressure at the controller')
    wait_until(lambda: live.states[-1].supply_pressure_pa == 250_000.0, what='state pressure')
    assert live.states[-1].output_pressure_pa == 30_000.0


# --- bus lifecycle -------------------------------------------------------------------------------
def test_close_is_idempotent_and_open_failure_is_clean() -> None:
    core = CanDriverCore(DriverConfig(interface='tcp_loopback', channel='127.0.0.1:1',
                                      open_timeout_s=0.1))
    with pytest.raises(BusOpenError, match='tcp_loopback:127.0.0.1:1'):
        core.open()
    assert not core.is_open
    core.close()
    core.close()
    core = CanDriverCore(DriverConfig(interface='virtual', channel='core_close'))
    core.open()
    core.close()
    core.close()
    assert [r.level for r in core.report()] == [Level.STALE] * 4


def test_driver_reopens_a_lost_bus_and_recovers() -> None:
    hub = TcpLoopbackHub('127.0.0.1:0').start()
    port = hub.port
    emu_bus = TcpLoopbackBus(hub.channel)
    emu = ControllerEmulator(emu_bus, ValveStepper(PARAMS, ElectronicsConfig()),
                             EmulatorConfig(command_timeout_s=0.0)).start()
    states: list = []
    core = CanDriverCore(DriverConfig(interface='tcp_loopback', channel=hub.channel,
                                      reopen_period_s=0.05, command_timeout_s=0.0),
                         on_state=states.append)
    try:
        core.open()
        core.activate()
        wait_until(lambda: len(states) > 50, what='states')
        emu.stop()
        emu_bus.shutdown()
        hub.close()                                          # the bus goes away
        wait_until(lambda: core.report()[0].level is Level.ERROR, what='bus ERROR')
        assert 'bus failed' in core.report()[0].message
        hub = TcpLoopbackHub(f'127.0.0.1:{port}').start()   # ... and comes back
        emu_bus = TcpLoopbackBus(hub.channel)
        emu = ControllerEmulator(emu_bus, ValveStepper(PARAMS, ElectronicsConfig()),
                                 EmulatorConfig(command_timeout_s=0.0)).start()
        count = len(states)
        wait_until(lambda: len(states) > count + 50, what='states after the bus returned')
        assert core.report()[0].level is Level.OK
        assert core.counters['bus_reopens'] >= 1 and core.counters['bus_failures'] == 1
    finally:
        core.close()
        emu.stop()
        emu_bus.shutdown()
        hub.close()


# --- fuzz ----------------------------------------------------------------------------------------
_CLASSIFIED = ('telemetry_frames', 'period_frames', 'status_frames', 'host_frames',
               'rejected_total', 'other_node_frames', 'error_frames')
_fuzz_codec = ValveCodec(0)


def _maybe_valid(data: bytes, arbitration_id: int) -> bytes:
    """Half the frames get a correct checksum, so the decoder's deeper checks are reached."""
    if len(data) == 8 and data[0] & 1:
        from valve_driver_pkg.protocol.codec import frame_checksum
        data = data[:7] + bytes([frame_checksum(arbitration_id, data)])
    return data


fuzz_frames = st.builds(
    lambda arbitration_id, data, ext, remote, error, fd: can.Message(
        arbitration_id=arbitration_id, data=_maybe_valid(data, arbitration_id),
        is_extended_id=ext, is_remote_frame=remote and not error and not fd,
        is_error_frame=error, is_fd=fd, check=False),
    arbitration_id=st.one_of(st.sampled_from([0x680, 0x690, 0x691, 0x6A0, 0x6B0, 0x6C0,
                                              0x6D0, 0x040, 0x004, 0x680 | 0x40]),
                             st.integers(0, 0x7FF)),
    data=st.one_of(st.binary(min_size=8, max_size=8), st.binary(max_size=64)),
    ext=st.booleans(), remote=st.booleans(), error=st.integers(0, 9).map(lambda n: n == 0),
    fd=st.integers(0, 9).map(lambda n: n == 0))


@pytest.fixture(scope='module')
def fuzz_core():
    core = CanDriverCore(DriverConfig(interface='virtual', channel='core_fuzz'),
                         mass_flow=mass_flow, on_state=lambda s: None)
    core.activate()   # states are built and handed on (no bus open, no traffic)
    yield core


@settings(max_examples=600, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(fuzz_frames, min_size=1, max_size=20))
def test_fuzz_receive_path_never_raises_and_counts_every_frame(fuzz_core, frames) -> None:
    before = sum(fuzz_core.counters[k] for k in _CLASSIFIED)
    for msg in frames:
        fuzz_core.handle_frame(msg)       # raises into the test if anything escapes
    after = sum(fuzz_core.counters[k] for k in _CLASSIFIED)
    assert after - before == len(frames)
    assert fuzz_core.counters['internal_errors'] == 0
    for report in fuzz_core.report():
        assert report.level in tuple(Level)


# --- clearing faults, a second host, stale and lost commands ------------------------------------
def test_clear_faults_clears_an_injected_overcurrent(live) -> None:
    live.core.set_command(0.5, 50.0)
    live.emu.inject(EmulatorFault.OVERCURRENT)
    wait_until(lambda: live.level('controller') is Level.ERROR, what='controller ERROR')
    status = live.status('controller')
    assert 'latched: Overcurrent' in status.message
    assert status.values['latched_faults'] == 'Overcurrent'
    result = live.core.clear_faults(timeout_s=2.0)
    assert result.success, result.message
    assert 'Overcurrent' in result.cleared and 'Overcurrent' not in result.still_active
    assert 'cleared: Overcurrent' in result.message
    wait_until(lambda: live.level('controller') is Level.OK, what='controller OK')
    assert live.core.counters['fault_clear_requests'] == 1
    assert live.emu.stats['fault_clears'] == 1


def test_clear_faults_reports_a_fault_whose_condition_persists(live) -> None:
    live.core.set_command(0.5, 50.0)
    live.emu.inject(EmulatorFault.OVERCURRENT, duration_s=30.0)   # the condition lasts
    wait_until(lambda: live.level('controller') is Level.ERROR, what='controller ERROR')
    result = live.core.clear_faults(timeout_s=2.0)
    assert not result.success
    assert result.still_active == ('Overcurrent',) and result.cleared == ()
    assert 'still active: Overcurrent' in result.message
    assert live.level('controller') is Level.ERROR


def test_clear_faults_on_a_closed_bus_says_so() -> None:
    core = CanDriverCore(DriverConfig(interface='virtual', channel='core_clear_closed'))
    result = core.clear_faults(0.1)
    assert not result.success and 'closed' in result.message


def test_a_second_host_on_the_same_node_is_an_error_for_both(live) -> None:
    other = CanDriverCore(DriverConfig(interface='virtual', channel=live.channel,
                                       command_timeout_s=0.0,
                                       host_id=(live.core.scheduler.host_id + 1) % 16))
    try:
        other.open()
        other.activate()
        other.set_command(0.8, 50.0)
        live.core.set_command(0.2, 50.0)
        for core in (live.core, other):
            wait_until(lambda: next(r for r in core.report() if r.name == 'commands').level
                       is Level.ERROR, what='second host ERROR')
            status = next(r for r in core.report() if r.name == 'commands')
            assert 'another host' in status.message
            assert core.counters['foreign_command_frames'] > 0
        assert live.status('commands').values['foreign_host_id'] == other.scheduler.host_id
    finally:
        other.close()


def test_own_echoed_frames_are_not_a_second_host() -> None:
    channel = f'core_test_{next(_channels)}'
    bus = can.Bus(interface='virtual', channel=channel, receive_own_messages=True)
    core = CanDriverCore(DriverConfig(interface='virtual', channel=channel,
                                      command_timeout_s=0.0),
                         bus_factory=lambda *a, **k: bus)
    try:
        core.open()
        core.activate()
        for i in range(20):
            core.set_command(i / 20.0, 50.0)
            wait_until(lambda: core.counters['commands_on_bus'] > i, what=f'command {i} sent')
        wait_until(lambda: core.counters['host_frames'] >= 20, what='echoed frames')
        assert core.counters['foreign_command_frames'] == 0
        assert next(r for r in core.report() if r.name == 'commands').level is not Level.ERROR
    finally:
        core.close()


def test_stale_commands_are_counted_and_reported() -> None:
    # the limit at its largest (10 s), so that a fresh command is not stale however late
    # the I/O thread runs on a loaded machine; the stale one is stamped 20 s ago
    live = LiveRig(stale_command_s=10.0)
    try:
        live.core.set_command(0.3, 50.0, age_s=0.0)
        wait_until(lambda: live.core.counters['commands_on_bus'] == 1,
                   what='command on the bus')
        assert live.core.counters['stale_commands'] == 0
        live.core.set_command(0.4, 50.0, age_s=20.0)
        wait_until(lambda: live.core.counters['stale_commands'] == 1, what='stale command')
        status = live.status('commands')
        assert status.level is Level.WARN and 'stale commands' in status.message
        assert status.values['max_command_age_s'] >= 20.0
    finally:
        live.close()


def test_sequence_gaps_are_lost_commands_per_source(live) -> None:
    for seq in (1, 2, 5):
        live.core.set_command(0.1, 50.0, sequence=seq, source='a')
    for seq in (7, 8):
        live.core.set_command(0.1, 50.0, sequence=seq, source='b')
    live.core.set_command(0.1, 50.0, sequence=3, source='a')
    counters = live.core.counters
    assert counters['commands_lost'] == 2
    assert counters['commands_out_of_order'] == 1
    assert 'commands lost' in live.status('commands').message


def test_every_command_is_accounted_for(live) -> None:
    for i in range(3000):
        live.core.set_command((i % 100) / 100.0, 50.0 if i % 7 else math.nan)
    wait_until(lambda: not live.core.scheduler.urgent(), what='commands sent')

    def accounted() -> bool:
        c = live.core.counters
        return c['commands_rejected'] + c['commands_on_bus'] + c['commands_superseded'] == 3000
    wait_until(accounted, what='every command accounted for')
    assert live.core.counters['commands_received'] == 3000


def test_frequency_limits_are_the_suite_constants(live) -> None:
    from valve_model_pkg.interface import MAX_PWM_FREQUENCY_HZ, MIN_PWM_FREQUENCY_HZ
    assert live.core.set_command(0.5, 1e-3).pwm_frequency_hz == MIN_PWM_FREQUENCY_HZ
    assert live.core.set_command(0.5, 1e6).pwm_frequency_hz == MAX_PWM_FREQUENCY_HZ
