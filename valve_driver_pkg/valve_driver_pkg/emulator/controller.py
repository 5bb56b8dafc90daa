"""The controller firmware stand-in: runs the valve model and answers the CAN protocol.

:class:`ControllerEmulator` is ROS-free and clock-agnostic. It can be driven

* step by step from a test (``handle(msg)`` / ``poll()`` then ``step(t_s)``; the model time is
  whatever the test says, so runs are deterministic), or
* in real time by :meth:`ControllerEmulator.run` (or :meth:`start` in a thread), where
  model time is the monotonic clock since start.

What the firmware does (see the package README for the frame table):

* ``ValveCommand``: checked (checksum, counter, ranges); a valid one sets duty and PWM
  frequency (``Enable=0`` means duty 0). ``ClearFaults=1`` clears the latched faults whose
  condition is gone (overcurrent: the coil current is below the limit and no injected
  overcurrent with a duration is still running) and the held command flags; a latched
  fault whose condition persists stays set. A command with a bad checksum or a frozen
  counter is ignored and raises a fault flag for 1 s. The ``HostId`` of every valid
  command is remembered (``host_ids``); a second id within 1 s is logged.
* Command watchdog: while enabled, no valid command for ``command_timeout_s`` closes the
  valve (duty 0) and sets ``CommandTimeout`` until the next valid command. In real time a
  command counts from the time it was in the bus, so a stall of the emulator's own loop
  (counted as overruns) is not taken for silence of the host.
* Drive mode (``ValveCommand.DriveMode``): ``normal`` runs the stepper's own electronics
  (the emulated hardware's), ``bench`` bypasses boost, chopper and capacitor
  (:func:`~valve_driver_pkg.emulator.config.bench_electronics`): the coil sees the supply
  for as long as duty = 1. A change takes effect at the next main PWM period start, or at
  once while duty 0 is in force (duty 0 commanded, disabled, watchdog, overcurrent); it
  never energises the coil by itself (the model's ``set_electronics``). Duty 0 acts at
  once in either mode.
* ``ValveDrive`` every ``1/status_rate_hz`` and just before the telemetry frame of the
  instant the mode in force changed: mode in force, capacitor voltage and holding-current
  set points in force (0 = bypassed), supply voltage.
* ``ValvePressure``: port pressures for the model.
* ``ValveTelemetry`` every ``1/telemetry_rate_hz`` of model time: the sampled coil current,
  coil voltage and spool position (the controller's estimate; here the model's position).
* ``ValveTelemetryMean`` just before each ``ValveTelemetry``: the coil current and voltage
  averaged over the telemetry period that ends at that instant, as firmware averaging its
  ADC samples over the period would report them; here the model's exact integrals
  (``ValveStepper.interval_means``), so the mean has no aliasing of the 20 kHz chopper.
* Close semantics (docs/safety.md): a command with duty 0 or ``Enable=0``, the command
  watchdog and an overcurrent switch the coil off at once (the model's duty-0 rule); any
  other duty or frequency takes effect at the next main PWM period start.
* ``ValvePeriod`` just before the telemetry frame of an instant at which the position
  averaged over the last complete PWM period, or the duty/frequency in force, changed
  (i.e. once per PWM period), and at least every 0.1 s: what a firmware computes at its
  internal rate, here the model's own period average.
* ``ValveStatus`` every ``1/status_rate_hz``: command in force, supply voltage, fault flags.
* ``EmulatorControl``: fault injection (see :class:`~valve_driver_pkg.emulator.faults`),
  obeyed only with ``EmulatorConfig.fault_injection``; otherwise counted and ignored.
"""
from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass

import can
import numpy as np

from valve_driver_pkg.emulator.config import (FLAG_HOLD_S, MIN_PRESSURE_PA, PERIOD_REFRESH_S,
                                              UNKNOWN_INJECTED_ID, ControllerState,
                                              EmulatorConfig, StepperLike,
                                              bench_electronics, clamp)
from valve_driver_pkg.emulator.fault_handling import FaultHandling
from valve_driver_pkg.emulator.faults import FaultInjector
from valve_driver_pkg.errors import FrameRejected, ProtocolEncodeError
from valve_driver_pkg.protocol.codec import (COMMAND, CONTROL, DRIVE, PERIOD, PRESSURE,
                                             STATUS, TELEMETRY, TELEMETRY_MEAN, CounterCheck,
                                             CounterTracker, DriveMode, EmulatorFault,
                                             ValveCodec)

__all__ = ['StepperLike', 'EmulatorConfig', 'ControllerEmulator', 'ControllerState',
           'UNKNOWN_INJECTED_ID', 'CommandInForce']

logger = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class CommandInForce:
    """The last valid ``ValveCommand`` the firmware took: enable, duty [1], PWM frequency
    [Hz]. What the valve is driven at follows from it and the faults (``output_duty``)."""

    enabled: bool
    duty: float
    pwm_frequency_hz: float


def _wall_minus_monotonic() -> float:
    """``time.time() - time.monotonic()`` [s], read as the tightest of three pairs: a
    preemption between the two reads would shift every frame's stamp by its length."""
    best_gap, best = math.inf, 0.0
    for _ in range(3):
        m0 = time.monotonic()
        wall = time.time()
        m1 = time.monotonic()
        if m1 - m0 < best_gap:
            best_gap, best = m1 - m0, wall - 0.5 * (m0 + m1)
    return best


class ControllerEmulator(FaultHandling):
    """Controller firmware on the other end of the bus, running a valve model.

    Parameters
    ----------
    bus : can.BusABC
        The bus to answer on (any python-can bus; not closed by the emulator).
    stepper : StepperLike
        The valve model (``ValveStepper`` or a test double); reset on construction.
    config : EmulatorConfig
    codec : ValveCodec | None
        Codec for ``config.node_id`` (default: the shipped DBCs, ``valve.dbc`` and the
        test-only ``valve_test.dbc`` with ``EmulatorControl``).
    fault_seed : int | None
        Seed of the probabilistic fault draws.
    """

    def __init__(self, bus: can.BusABC, stepper: StepperLike,
                 config: EmulatorConfig | None = None, codec: ValveCodec | None = None,
                 fault_seed: int | None = None, supply_pressure_pa: float = 400_000.0,
                 output_pressure_pa: float = 0.0) -> None:
        self.config = config or EmulatorConfig()
        self.codec = codec or ValveCodec(self.config.node_id, include_test_messages=True)
        self.bus = bus
        self.stepper = stepper
        self.faults = FaultInjector(fault_seed)
        self._adc_rng = np.random.default_rng(self.config.noise_seed)
        self._lock = threading.RLock()
        self._telemetry_period_s = 1.0 / self.config.telemetry_rate_hz
        self._status_period_s = 1.0 / self.config.status_rate_hz
        self._i_lo, self._i_hi = self.codec.signal_range(TELEMETRY, 'CoilCurrent')
        self._v_lo, self._v_hi = self.codec.signal_range(TELEMETRY, 'CoilVoltage')
        self._x_lo, self._x_hi = self.codec.signal_range(TELEMETRY, 'SpoolPosition')
        self._f_lo, self._f_hi = self.codec.signal_range(COMMAND, 'PwmFrequency')
        self._w_lo, self._w_hi = self.codec.signal_range(TELEMETRY_MEAN, 'MeanInterval')
        self._model_t = 0.0
        # wall clock [s since the epoch] minus model time while run() keeps them together
        self._wall_minus_model: float | None = None
        #: Stamp frames with the model time itself [s] (the simulation clock's: the
        #: emulator on the simulation clock, whose model time is that clock).
        self.model_time_stamps = False
        self._next_telemetry_k = 0
        self._next_status_t = 0.0
        self._telemetry_counter = 0
        self._mean_counter = 0
        self._mean_t = 0.0          # model time the running averaging interval started
        self._status_counter = 0
        self._period_counter = 0
        self._period_sent: tuple[int, int, int] | None = None
        self._period_sent_t = -1.0
        self._command_counter = CounterTracker()
        self._control_counter = CounterTracker()
        self._duty = 0.0
        self._pwm_hz = 50.0
        self._enabled = False
        self._seen_command = False
        self._last_command_t: float | None = None
        self._timed_out = False
        self._overcurrent = False
        self._flag_until = {'checksum': -1.0, 'counter': -1.0, 'range': -1.0}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.stats = {'commands': 0, 'commands_rejected': 0, 'telemetry_sent': 0,
                      'telemetry_suppressed': 0, 'status_sent': 0, 'overruns': 0,
                      'send_errors': 0, 'control_frames': 0, 'control_frames_ignored': 0,
                      'fault_clears': 0, 'drive_sent': 0}
        self.host_ids: dict[int, float] = {}   # HostId -> model time of its last command
        self._last_current_a = 0.0
        # Drive modes: the stepper's electronics are the hardware's normal mode.
        self._normal_electronics = getattr(stepper, 'electronics', None)
        self._modes_supported = (self._normal_electronics is not None
                                 and hasattr(stepper, 'set_electronics')
                                 and hasattr(stepper, 'next_period_start_s'))
        self.mode_requested = DriveMode.NORMAL
        self.mode_active = DriveMode.NORMAL
        self._applied_duty = 0.0
        self._drive_counter = 0
        self._drive_due = False      # the mode in force changed: ValveDrive before telemetry
        self._drive_ranges = {name: self.codec.signal_range(DRIVE, name)
                              for name in ('CapacitorVoltage', 'HoldingCurrent',
                                           'SupplyVoltageMeasured')}
        stepper.reset()
        stepper.set_pressures(supply_pressure_pa, output_pressure_pa)
        stepper.set_command(0.0, self._pwm_hz)

    # --- read-only views ----------------------------------------------------------------------
    @property
    def command(self) -> CommandInForce:
        """The command in force (the last valid ``ValveCommand``)."""
        with self._lock:
            return CommandInForce(self._enabled, self._duty, self._pwm_hz)

    @property
    def output_duty(self) -> float:
        """The duty the valve is driven at now: the command's, 0 while disabled, timed out
        or switched off by an overcurrent."""
        with self._lock:
            return self._applied_duty

    # --- inputs ------------------------------------------------------------------------------
    @property
    def model_time_s(self) -> float:
        """Model time the emulator has reached [s]."""
        return self._model_t

    def poll(self, timeout: float = 0.0) -> int:
        """Handle every frame waiting on the bus (the first wait up to ``timeout``)."""
        handled = 0
        msg = self.bus.recv(timeout)
        while msg is not None:
            self.handle(msg)
            handled += 1
            msg = self.bus.recv(0.0)
        return handled

    def handle(self, msg: can.Message) -> None:
        """Process one received frame at the current model time."""
        if msg.is_error_frame:
            return
        found = self.codec.classify(msg.arbitration_id)
        if found is None or found[1] != self.config.node_id:
            return
        name = found[0]
        with self._lock:
            if (self.faults.is_active(EmulatorFault.BUS_OFF) and name != CONTROL):
                return   # a bus-off controller takes no part in the bus
            try:
                frame = self.codec.decode(msg)
            except FrameRejected as err:
                if name == COMMAND:
                    self.stats['commands_rejected'] += 1
                    key = 'checksum' if err.reason == 'checksum' else 'range'
                    self._flag_until[key] = self._model_t + FLAG_HOLD_S
                logger.debug('emulator ignored a frame: %s', err)
                return
            if name == COMMAND:
                self._on_command(frame.signals, frame.counter)
            elif name == PRESSURE:
                supply = max(float(frame.signals['SupplyPressure']), MIN_PRESSURE_PA)
                output = max(float(frame.signals['OutputPressure']), MIN_PRESSURE_PA)
                try:
                    self.stepper.set_pressures(supply, output)
                except ValueError as err:   # the model refused: keep the last pressures
                    logger.warning('emulator: pressures not applied: %s', err)
            elif name == CONTROL and not self.config.fault_injection:
                self.stats['control_frames_ignored'] += 1
                if self.stats['control_frames_ignored'] == 1:
                    logger.warning('emulator: EmulatorControl frame ignored (fault injection '
                                   'is off; start with --fault-injection)')
            elif name == CONTROL:
                if self._control_counter.check(frame.counter) is CounterCheck.FROZEN:
                    return
                self.stats['control_frames'] += 1
                self.inject(EmulatorFault(int(frame.signals['Fault'])),
                            bool(frame.signals['Active']),
                            float(frame.signals['Probability']),
                            float(frame.signals['Duration']))

    def _on_command(self, signals: dict, counter: int) -> None:
        if self._command_counter.check(counter) is CounterCheck.FROZEN:
            self.stats['commands_rejected'] += 1
            self._flag_until['counter'] = self._model_t + FLAG_HOLD_S
            return
        self.stats['commands'] += 1
        self._seen_command = True
        self._last_command_t = self._model_t
        self._timed_out = False
        self._note_host(int(signals.get('HostId', 0)))
        if signals['ClearFaults']:
            self._clear_faults()
        self._enabled = bool(signals['Enable'])
        self._duty = float(signals['Duty'])
        self._pwm_hz = float(signals['PwmFrequency'])
        # The output first: a stop acts at once, and the mode then follows at once too.
        self._apply_output()
        self._request_mode(DriveMode(int(signals.get('DriveMode', DriveMode.NORMAL))))

    def _apply_output(self) -> None:
        drive = self._enabled and not self._timed_out and not self._overcurrent
        duty = self._duty if drive else 0.0
        try:
            self.stepper.set_command(duty, self._pwm_hz)
        except ValueError as err:   # the model refused the command: close the valve
            self._flag_until['range'] = self._model_t + FLAG_HOLD_S
            logger.warning('emulator: command not applied (%s); valve closed', err)
            duty = 0.0
            self.stepper.set_command(0.0, self._pwm_hz if self._pwm_hz > 0 else 50.0)
        self._applied_duty = duty
        if duty == 0.0:   # duty 0 is in force at once: a requested mode may switch now
            self._switch_mode()

    # --- drive mode --------------------------------------------------------------------------
    def _request_mode(self, mode: DriveMode) -> None:
        """A command asked for ``mode``: now if duty 0 is in force, else at a period start."""
        if mode != self.mode_requested:
            self.mode_requested = mode
            if not self._modes_supported and mode != DriveMode.NORMAL:
                logger.warning('emulator: drive mode %s requested, but the model cannot '
                               'switch its electronics; staying normal', mode.name.lower())
            else:
                logger.info('emulator: drive mode %s requested', mode.name.lower())
        if self._applied_duty == 0.0:
            self._switch_mode()

    def _switch_mode(self) -> None:
        """Put the requested drive mode in force now (if it differs and can)."""
        mode = self.mode_requested
        if mode == self.mode_active or not self._modes_supported:
            return
        normal = self._normal_electronics
        self.stepper.set_electronics(normal if mode == DriveMode.NORMAL
                                     else bench_electronics(normal))
        self.mode_active = mode
        self._drive_due = True
        logger.info('emulator: drive mode %s in force at t = %.4f s', mode.name.lower(),
                    self._model_t)

    def _switch_mode_at_period_start(self, t_s: float) -> None:
        """A requested mode change waits for the first main PWM period start up to ``t_s``."""
        if self.mode_requested == self.mode_active or not self._modes_supported:
            return
        start = float(self.stepper.next_period_start_s)
        if start > t_s:
            return
        if start > self._model_t:
            self.stepper.advance_to(start)
            self._model_t = start
        self._switch_mode()

    # --- model time --------------------------------------------------------------------------
    def step(self, t_s: float, max_burst: int = 0) -> int:
        """Advance the model to ``t_s`` and send every frame due up to then.

        Parameters
        ----------
        t_s : float
            Model time to reach [s].
        max_burst : int
            If more telemetry instants than this are due (a stall in real time), only the
            last ``max_burst`` are sent; the skipped ones still advance the counter. 0 = send
            all (deterministic stepping).

        Returns
        -------
        int
            Number of telemetry instants passed (sent, dropped or skipped).
        """
        with self._lock:
            instants = 0
            period = self._telemetry_period_s
            due = int((t_s + 1e-12) / period) + 1 - self._next_telemetry_k
            if due > max_burst > 0:
                # Stalled: skip to the latest instants; the counter shows the loss.
                skip = due - max_burst
                self._next_telemetry_k += skip
                self._telemetry_counter = (self._telemetry_counter + skip) & 0xF
                self._mean_counter = (self._mean_counter + skip) & 0xF
                self.stats['overruns'] += skip
                instants += skip
                # the next mean covers one telemetry period, like the firmware's average
                self._advance((self._next_telemetry_k - 1) * period)
                self._close_mean_interval()
            while self._next_telemetry_k * period <= t_s + 1e-12:
                t_k = self._next_telemetry_k * period
                self._advance(t_k)
                self._send_telemetry()
                self._next_telemetry_k += 1
                instants += 1
                while self._next_status_t <= t_k + 1e-12:
                    self._send_status()
                    self._send_drive()
                    self._next_status_t += self._status_period_s
            self._advance(t_s)
            return instants

    def _advance(self, t_s: float) -> None:
        if t_s > self._model_t:
            self._check_watchdog(t_s)
            self._switch_mode_at_period_start(t_s)
            self.stepper.advance_to(t_s)
            self._model_t = t_s
        for fault in self.faults.expire(self._model_t):
            self._on_fault_end(fault)

    def _check_watchdog(self, t_s: float) -> None:
        timeout = self.config.command_timeout_s
        if (timeout > 0.0 and self._enabled and not self._timed_out
                and self._last_command_t is not None
                and t_s - self._last_command_t > timeout):
            # Close at the instant the timeout elapsed, not at the next frame.
            t_trip = max(self._model_t, self._last_command_t + timeout)
            self.stepper.advance_to(t_trip)
            self._model_t = t_trip
            self._timed_out = True
            self._apply_output()
            logger.warning('emulator: no command for %.3f s; valve closed', timeout)

    # --- outputs -----------------------------------------------------------------------------
    def _send(self, msg: can.Message) -> bool:
        try:
            self.bus.send(msg)
            return True
        except can.CanError as err:
            self.stats['send_errors'] += 1
            logger.debug('emulator send failed: %s', err)
            return False

    def _stamp(self) -> float:
        """The timestamp of a frame sent now: the wall time of the model instant its values
        belong to while running in real time (as a controller's clock would stamp it; the
        emulator's own stalls must not bunch them), the model instant itself with
        :attr:`model_time_stamps` (on the simulation clock), else the wall clock."""
        if self.model_time_stamps:
            return self._model_t
        if self._wall_minus_model is None:
            return time.time()
        return self._model_t + self._wall_minus_model

    def _silent(self) -> bool:
        return (self.faults.is_active(EmulatorFault.SILENT)
                or self.faults.is_active(EmulatorFault.BUS_OFF))

    def _fault_active(self) -> bool:
        return self._overcurrent or self._timed_out or any(
            until > self._model_t for until in self._flag_until.values())

    def _close_mean_interval(self) -> tuple[float, float, float]:
        """End the averaging interval now: (mean current A, mean voltage V, length s)."""
        interval_means = getattr(self.stepper, 'interval_means', None)
        if interval_means is None:   # a test double without means: the sampled values
            s = self.stepper.sample()
            current, voltage = float(s.coil_current_a), float(s.coil_voltage_v)
        else:
            current, voltage = interval_means()
        width = self._model_t - self._mean_t
        self._mean_t = self._model_t
        return current, voltage, width

    def _send_mean(self, current: float, voltage: float, width: float) -> None:
        counter = self._mean_counter
        if not self.faults.is_active(EmulatorFault.FREEZE_COUNTER):
            self._mean_counter = (counter + 1) & 0xF
        if self.config.current_noise_a > 0.0:
            current += float(self._adc_rng.normal(0.0, self.config.current_noise_a))
        signals = {'CoilCurrentMean': clamp(current, self._i_lo, self._i_hi),
                   'CoilVoltageMean': clamp(voltage, self._v_lo, self._v_hi),
                   'MeanInterval': clamp(width, self._w_lo, self._w_hi)}
        self._send(self.codec.encode(TELEMETRY_MEAN, signals, counter, timestamp=self._stamp()))

    def _send_telemetry(self) -> None:
        faults = self.faults
        counter = self._telemetry_counter
        mean = self._close_mean_interval()   # every period, sent or not: one period each
        if not faults.is_active(EmulatorFault.FREEZE_COUNTER):
            self._telemetry_counter = (counter + 1) & 0xF
        if self._silent() or faults.hits(EmulatorFault.DROP_TELEMETRY):
            self.stats['telemetry_suppressed'] += 1
            if not faults.is_active(EmulatorFault.FREEZE_COUNTER):
                self._mean_counter = (self._mean_counter + 1) & 0xF
            return
        s = self.stepper.sample()
        current = float(s.coil_current_a)
        self._last_current_a = current
        if current > self.config.overcurrent_a and not self._overcurrent:
            self._overcurrent = True
            self._apply_output()
            logger.warning('emulator: overcurrent %.3f A; output off until ClearFaults', current)
        position = float(s.spool_position_m) if self.config.position_estimate else 0.0
        if self._drive_due:
            self._send_drive()
        self._send_period(s)
        self._send_mean(*mean)
        if self.config.current_noise_a > 0.0:   # the ADC's noise, not the coil's current
            current += float(self._adc_rng.normal(0.0, self.config.current_noise_a))
        signals = {
            'CoilCurrent': clamp(current, self._i_lo, self._i_hi),
            'CoilVoltage': clamp(float(s.coil_voltage_v), self._v_lo, self._v_hi),
            'SpoolPosition': clamp(position, self._x_lo, self._x_hi),
            'Enabled': int(self._enabled and not self._timed_out and not self._overcurrent),
            'PositionValid': int(self.config.position_estimate),
            'FaultActive': int(self._fault_active()),
            'CommandTimeout': int(self._timed_out),
        }
        msg = self.codec.encode(TELEMETRY, signals, counter, timestamp=self._stamp())
        if faults.hits(EmulatorFault.CORRUPT_CHECKSUM):
            msg.data[7] ^= 0x5A
        if faults.hits(EmulatorFault.WRONG_LENGTH):
            msg = can.Message(arbitration_id=msg.arbitration_id, data=msg.data[:6],
                              is_extended_id=False, timestamp=msg.timestamp)
        if self._send(msg):
            self.stats['telemetry_sent'] += 1
        if faults.hits(EmulatorFault.UNKNOWN_ID):
            self._send(can.Message(arbitration_id=UNKNOWN_INJECTED_ID, data=bytes(8),
                                   is_extended_id=False, timestamp=self._stamp()))

    def _send_period(self, s) -> None:
        average = clamp(float(s.position_avg_m), self._x_lo, self._x_hi)
        duty = clamp(float(s.duty), 0.0, 1.0)
        freq = clamp(float(s.pwm_frequency_hz), 0.0, self._f_hi)
        key = (round(average / 1e-8), round(duty / 1e-4), round(freq / 0.1))
        if key == self._period_sent and self._model_t - self._period_sent_t < PERIOD_REFRESH_S:
            return
        msg = self.codec.encode(PERIOD, {'PositionAverage': average, 'DutyActive': duty,
                                         'PwmFrequencyActive': freq},
                                self._period_counter, timestamp=self._stamp())
        self._period_counter = (self._period_counter + 1) & 0xF
        if self._send(msg):
            self._period_sent, self._period_sent_t = key, self._model_t

    def _send_drive(self) -> None:
        """``ValveDrive``: the drive electronics in force and the supply voltage."""
        if self._silent():
            return
        electronics = getattr(self.stepper, 'electronics', None)
        ranges = self._drive_ranges
        capacitor = (electronics.capacitor_voltage_v
                     if electronics is not None and electronics.negative_voltage else 0.0)
        holding = (electronics.holding_current_a
                   if electronics is not None and electronics.current_control else 0.0)
        signals = {'DriveModeActive': int(self.mode_active),
                   'CapacitorVoltage': clamp(capacitor, *ranges['CapacitorVoltage']),
                   'HoldingCurrent': clamp(holding, *ranges['HoldingCurrent']),
                   'SupplyVoltageMeasured': clamp(self.config.supply_voltage_v,
                                                  *ranges['SupplyVoltageMeasured'])}
        msg = self.codec.encode(DRIVE, signals, self._drive_counter, timestamp=self._stamp())
        self._drive_counter = (self._drive_counter + 1) & 0xF
        if self._send(msg):
            self._drive_due = False
            self.stats['drive_sent'] += 1

    def _send_status(self) -> None:
        if self._silent():
            return
        s = self.stepper.sample()
        t = self._model_t
        state = (ControllerState.FAULT if self._overcurrent
                 else ControllerState.INIT if not self._seen_command
                 else ControllerState.RUNNING if self._enabled and not self._timed_out
                 else ControllerState.STANDBY)
        signals = {
            'DutyActive': clamp(float(s.duty), 0.0, 1.0),
            'PwmFrequencyActive': clamp(float(s.pwm_frequency_hz), 0.0, self._f_hi),
            'SupplyVoltage': clamp(self.config.supply_voltage_v, 0.0, 63.75),
            'FaultOvercurrent': int(self._overcurrent),
            'FaultUndervoltage': int(self.config.supply_voltage_v < 18.0),
            'FaultCommandTimeout': int(self._timed_out),
            'FaultCommandChecksum': int(self._flag_until['checksum'] > t),
            'FaultCommandCounter': int(self._flag_until['counter'] > t),
            'FaultCommandRange': int(self._flag_until['range'] > t),
            'FaultOvertemperature': 0,
            'FaultInternal': 0,
            'ControllerState': state,
        }
        try:
            msg = self.codec.encode(STATUS, signals, self._status_counter, timestamp=self._stamp())
        except ProtocolEncodeError as err:   # a bug here must not stop the telemetry
            logger.error('emulator: %s', err)
            return
        self._status_counter = (self._status_counter + 1) & 0xF
        if self._send(msg):
            self.stats['status_sent'] += 1

    # --- real time ---------------------------------------------------------------------------
    def run(self, stop: threading.Event | None = None, duration_s: float = 0.0,
            clock=time.monotonic) -> None:
        """Run in real time until ``stop`` is set (or for ``duration_s`` > 0)."""
        stop = stop or self._stop
        t0 = clock() - self._model_t
        if clock is time.monotonic:   # another clock (a test's) has no wall time to anchor
            self._wall_minus_model = t0 + _wall_minus_monotonic()
        period = self._telemetry_period_s
        while not stop.is_set():
            now = clock() - t0
            if duration_s > 0.0 and now >= duration_s:
                break
            commands_before = self.stats['commands']
            try:
                self.poll(0.0)
            except can.CanError as err:
                logger.error('emulator: bus receive failed (%s); stopping', err)
                raise
            if self.stats['commands'] > commands_before:
                self._commands_received_by(now)
            self.step(now, self.config.max_burst)
            # Wait for the next telemetry instant, handling commands as they come.
            next_t = self._next_telemetry_k * period
            remaining = next_t - (clock() - t0)
            if remaining > 0.0:
                msg = self.bus.recv(remaining)
                if msg is not None:
                    self.handle(msg)

    def _commands_received_by(self, t_s: float) -> None:
        """The commands just handled were in the bus by model time ``t_s``: the watchdog
        counts from there. A loop that fell behind real time (a stall: the overruns count
        it) handles frames that waited in the bus meanwhile at the model time it had
        reached; its own lateness must not read as silence of the host. A host that stopped
        sending leaves nothing in the bus, and the watchdog trips as before."""
        with self._lock:
            if self._last_command_t is not None and t_s > self._last_command_t:
                self._last_command_t = t_s

    def start(self) -> ControllerEmulator:
        """Run :meth:`run` in a daemon thread (in-process use); returns self."""
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self.run, name='valve_emulator',
                                            daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread started by :meth:`start`; safe to call more than once."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def __enter__(self) -> ControllerEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
