"""The driver's receive tracker: frames in, valve samples out, counters and sequence checks.

:class:`ReceiveTracker` checks and decodes every received frame (on the receive thread),
follows the rolling counters of the three controller messages, turns each valid
``ValveTelemetry`` into a :class:`~valve_model_pkg.model.sample.ValveSample`, and
declares the telemetry lost when it stops (:meth:`check_loss`, on the I/O thread). Its
state changes only under the driver core's one lock; the sample callback runs outside it.

What is measured and what is derived (see the package README):

====================  ==================================================================
coil current/voltage  measured: ``ValveTelemetry``, quantised 0.2 mA / 10 mV
spool position        measured: the controller's estimate (``PositionValid``), 10 nm
spool velocity        derived: difference of consecutive positions / telemetry period
position average      measured: ``ValvePeriod`` (the controller's average over the last
                      complete PWM period); derived if the controller sends none: the
                      suite's :class:`~valve_model_pkg.model.averaging.PeriodAverager` on
                      the telemetry positions (periods counted from the first sample)
mass flow             derived: eq. (12) (``orifice_mass_flow``) from the average position
duty, PWM frequency   measured: in force at the controller (``ValvePeriod``); without it the
                      last command sent (duty 0 while the controller reports ``Enabled=0``)
pressures             the driver's inputs (parameters or pressure topics), also sent to
                      the controller in ``ValvePressure``
drive electronics     measured: ``ValveDrive`` (mode in force, capacitor and holding-
                      current set points, supply voltage), kept as ``last_drive`` for the
                      controller diagnostics
====================  ==================================================================
"""
from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable

import can

from valve_driver_pkg.canbus.frame_time import frame_time_s
from valve_driver_pkg.driver.bus_link import BusLink
from valve_driver_pkg.driver.config import DriverConfig
from valve_driver_pkg.driver.diagnostics import Tally
from valve_driver_pkg.driver.health import TelemetryHealth
from valve_driver_pkg.driver.transmit import TransmitScheduler
from valve_driver_pkg.errors import FrameRejected
from valve_driver_pkg.protocol.codec import (COMMAND, DRIVE, PERIOD, PRESSURE, STATUS,
                                             TELEMETRY, TELEMETRY_MEAN, CounterCheck,
                                             CounterTracker, DriveMode, RejectReason,
                                             ValveCodec)
from valve_model_pkg.model.averaging import PeriodAverager
from valve_model_pkg.model.orifice import orifice_mass_flow
from valve_model_pkg.model.parameters import ValveParameters
from valve_model_pkg.model.sample import ValveSample

__all__ = ['ReceiveTracker', 'MassFlowFunction', 'mass_flow_function']

logger = logging.getLogger(__name__)

#: ``f(position_avg_m, supply_pa, output_pa) -> kg/s`` (gauge pressures).
MassFlowFunction = Callable[[float, float, float], float]


#: Telemetry losses are logged at most this often (the diagnostics count every one) [s].
_LOG_INTERVAL_S = 5.0
#: A ValvePeriod older than this no longer counts; the driver's own average is used [s].
#: The age is counted in telemetry periods since that ValvePeriod (the controller's clock),
#: not on the host's, so a host that falls behind does not turn it stale.
_PERIOD_FRESH_S = 0.5
#: The telemetry rate is measured over windows of this length [s].
_RATE_WINDOW_S = 0.5


def mass_flow_function(params: ValveParameters) -> MassFlowFunction:
    """eq. (12) with the valve's parameter set, its compiled code loaded before traffic."""
    def mass_flow(position_avg_m: float, supply_pa: float, output_pa: float) -> float:
        return float(orifice_mass_flow(position_avg_m, supply_pa, output_pa, params))

    mass_flow(params.stroke_m * 0.5, 400_000.0, 0.0)   # the first call loads it (seconds)
    return mass_flow


class ReceiveTracker:
    """Received frames -> counters, sequence checks, controller state and valve samples.

    Parameters
    ----------
    config : DriverConfig
    codec : ValveCodec
    lock : threading.Condition
        The driver core's lock.
    tally : Tally
        Counters: frames by kind, rejections by reason, counter jumps, lost frames,
        telemetry losses.
    link : BusLink
        Told when valid traffic ends a bus-off.
    scheduler : TransmitScheduler
        Read for what was sent (duty, frequency, pressures) and whether the driver is
        active.
    mass_flow : MassFlowFunction | None
        Orifice equation; ``None`` reports 0.
    on_sample : callable | None
        ``on_sample(ValveSample)`` on the receive thread for every valid telemetry frame
        while active.
    on_change : callable
        ``on_change()`` when a diagnostic level may have changed (outside the lock).
    """

    def __init__(self, config: DriverConfig, codec: ValveCodec, lock: threading.Condition,
                 tally: Tally, link: BusLink, scheduler: TransmitScheduler,
                 mass_flow: MassFlowFunction | None,
                 on_sample: Callable[[ValveSample], None] | None,
                 on_change: Callable[[], None]) -> None:
        self._config = config
        self._codec = codec
        self._lock = lock
        self._tally = tally
        self._link = link
        self._scheduler = scheduler
        self._mass_flow = mass_flow
        self._on_sample = on_sample
        self._on_change = on_change
        #: The clock a frame's timestamp is checked against and that stamps a frame
        #: without one [s]: the wall clock, or the node's (simulation) clock.
        self.frame_clock: Callable[[], float] = time.time
        self._telemetry_counter = CounterTracker()
        self._status_counter = CounterTracker()
        self._period_counter = CounterTracker()
        self._mean_counter = CounterTracker()
        self._drive_counter = CounterTracker()
        # (mean current A, mean voltage V, counter) of the last ValveTelemetryMean, paired
        # with the ValveTelemetry frame of the same instant (same counter) and then dropped
        self._mean: tuple[float, float, int] | None = None
        self.frozen_run = 0
        self.last_valid_mono: float | None = None
        self.opened_mono = 0.0
        self.health = TelemetryHealth(
            config.telemetry_period_s, config.telemetry_timeout_s, config.telemetry_window_s,
            config.telemetry_loss_fraction, config.telemetry_error_windows,
            config.telemetry_ok_windows)
        self.foreign_host_id: int | None = None   # HostId of the last foreign ValveCommand
        self.last_reject = ''
        self.last_status: dict | None = None
        self.last_status_mono: float | None = None
        self.last_drive: dict | None = None         # the last ValveDrive's signals
        self.last_drive_mono: float | None = None
        self.period: tuple[float, float, float] | None = None   # avg, duty, f
        self._periods_since_valve_period = 0     # telemetry periods since the last ValvePeriod
        self.rate_hz = 0.0
        self._rate_window = (time.monotonic(), 0)
        self._last_loss_log = -math.inf
        self._losses_logged = 0
        self._last_sample_t = 0.0
        self._last_position: float | None = None
        self._averager: PeriodAverager | None = None

    # --- bus events (lock held by the caller) ------------------------------------------------
    def on_open(self, now: float) -> None:
        """A bus was (re)opened: counters start afresh; the loss timer runs from ``now``."""
        self._telemetry_counter.reset()
        self._status_counter.reset()
        self._period_counter.reset()
        self._mean_counter.reset()
        self._drive_counter.reset()
        self._mean = None
        self.opened_mono = now
        self.health.reset(now)

    @property
    def lost(self) -> bool:
        """True while the telemetry is judged lost (see :mod:`.health`)."""
        return self.health.lost

    @property
    def lost_after_s(self) -> float:
        """How long the telemetry had been silent (or gappy) when it was declared lost [s]."""
        return self.health.lost_after_s

    @property
    def frozen_counter(self) -> int | None:
        """The repeated telemetry counter value (for the diagnostics)."""
        return self._telemetry_counter.last

    def average_source(self) -> str:
        """``'controller'`` while ValvePeriod frames are fresh (at most ``_PERIOD_FRESH_S``
        of telemetry periods old), else ``'driver'``."""
        fresh = (self._periods_since_valve_period * self._config.telemetry_period_s
                 <= _PERIOD_FRESH_S)
        return 'controller' if self.period is not None and fresh else 'driver'

    # --- receive thread ----------------------------------------------------------------------
    def on_frame(self, msg: can.Message) -> None:
        """Check, decode and account for one (non-error) frame."""
        found = self._codec.classify(msg.arbitration_id)
        with self._lock:
            if found is not None and found[1] != self._config.node_id:
                self._tally.count('other_node_frames')   # another valve on the same bus
                return
            if found is not None and found[0] in (COMMAND, PRESSURE):
                self._tally.count('host_frames')   # another host or a test tool: not for us
                if found[0] == PRESSURE:
                    return
        if found is not None and found[0] == COMMAND:
            self._on_host_command(msg)
            return
        try:
            frame = self._codec.decode(msg)
        except FrameRejected as err:
            with self._lock:
                self._reject(err.reason, err.detail)
            return
        if frame.name == TELEMETRY:
            self._on_telemetry(frame.signals, frame.counter, msg.timestamp)
        elif frame.name == PERIOD:
            with self._lock:
                self._on_period(frame.signals, frame.counter)
        elif frame.name == STATUS:
            with self._lock:
                self._on_status(frame.signals, frame.counter)
        elif frame.name == TELEMETRY_MEAN:
            with self._lock:
                self._on_mean(frame.signals, frame.counter)
        elif frame.name == DRIVE:
            with self._lock:
                changed = self._on_drive(frame.signals, frame.counter)
            if changed is not None:
                logger.info('controller reports drive mode %s in force (holding current '
                            '%.4g A, capacitor %.4g V, supply %.4g V)', changed,
                            frame.signals['HoldingCurrent'], frame.signals['CapacitorVoltage'],
                            frame.signals['SupplyVoltageMeasured'])

    def _on_host_command(self, msg: can.Message) -> None:
        """A ValveCommand for our node on the bus: ours echoed, or another host's.

        CAN is broadcast: a second host commanding this node shows its frames here. An
        echo of our own frame (an interface that loops sent frames back) is recognised by
        its bytes; a frame that fails the checksum is only counted as a host frame.
        """
        try:
            frame = self._codec.decode(msg)
        except FrameRejected:
            return
        with self._lock:
            if self._scheduler.sent_recently(bytes(msg.data)):
                return
            self._tally.count('foreign_command_frames')
            self._tally.mark('foreign_command', time.monotonic())
            first = self.foreign_host_id is None
            self.foreign_host_id = int(frame.signals.get('HostId', 0))
        if first:
            logger.error('another host (host id %d) sends ValveCommand to node %d: two '
                         'hosts command one valve', self.foreign_host_id, self._config.node_id)
            self._on_change()

    def _reject(self, reason: str, detail: str) -> None:
        self._tally.count('rejected_total')
        self._tally.count(f'rejected_{reason}')
        self._tally.mark('rejected_' + reason, time.monotonic())
        self.last_reject = detail
        logger.debug('frame rejected: %s', detail)

    def _on_period(self, signals: dict, counter: int) -> None:
        if self._period_counter.check(counter) is CounterCheck.FROZEN:
            self._reject(RejectReason.COUNTER_FROZEN.value,
                         f'ValvePeriod counter stuck at {counter}')
            return
        self._tally.count('period_frames')
        self.period = (float(signals['PositionAverage']), float(signals['DutyActive']),
                       float(signals['PwmFrequencyActive']))
        self._periods_since_valve_period = 0

    def _on_mean(self, signals: dict, counter: int) -> None:
        if self._mean_counter.check(counter) is CounterCheck.FROZEN:
            self._reject(RejectReason.COUNTER_FROZEN.value,
                         f'ValveTelemetryMean counter stuck at {counter}')
            return
        self._tally.count('mean_frames')
        self._mean = (float(signals['CoilCurrentMean']), float(signals['CoilVoltageMean']),
                      counter)

    def _take_mean(self, counter: int) -> tuple[float, float]:
        """The interval means sent with telemetry frame ``counter`` (NaN if none came)."""
        mean, self._mean = self._mean, None
        if mean is None or mean[2] != counter:
            return math.nan, math.nan
        return mean[0], mean[1]

    def _on_drive(self, signals: dict, counter: int) -> str | None:
        """Keep the ValveDrive; returns the mode's name if the mode in force changed."""
        if self._drive_counter.check(counter) is CounterCheck.FROZEN:
            self._reject(RejectReason.COUNTER_FROZEN.value,
                         f'ValveDrive counter stuck at {counter}')
            return None
        self._tally.count('drive_frames')
        previous, self.last_drive = self.last_drive, dict(signals)
        self.last_drive_mono = time.monotonic()
        mode = int(signals['DriveModeActive'])
        if previous is None or int(previous['DriveModeActive']) != mode:
            return DriveMode(mode).name.lower()
        return None

    def _on_status(self, signals: dict, counter: int) -> None:
        if self._status_counter.check(counter) is CounterCheck.FROZEN:
            self._reject(RejectReason.COUNTER_FROZEN.value,
                         f'ValveStatus counter stuck at {counter}')
            return
        self._tally.count('status_frames')
        self.last_status = dict(signals)
        self.last_status_mono = time.monotonic()

    def _on_telemetry(self, signals: dict, counter: int, timestamp_s: float) -> None:
        """One ValveTelemetry frame: accounted, and handed on as a sample stamped with the
        frame's time (:func:`~valve_driver_pkg.canbus.frame_time.frame_time_s`)."""
        wall = self.frame_clock()
        with self._lock:
            state, changed = self._track_telemetry(signals, counter)
            current_mean, voltage_mean = self._take_mean(counter)
        if changed:
            self._on_change()
        if state is None or self._on_sample is None:
            return
        # Outside the lock: the orifice equation and the callback (the node publishes).
        average, duty, pwm_hz, supply, output, velocity, lost = state
        flow = self._mass_flow(average, supply, output) if self._mass_flow else 0.0
        self._on_sample(ValveSample(
            t_s=frame_time_s(timestamp_s, wall), coil_voltage_v=float(signals['CoilVoltage']),
            coil_current_a=float(signals['CoilCurrent']),
            spool_position_m=float(signals['SpoolPosition']), spool_velocity_m_s=velocity,
            position_avg_m=average, mass_flow_kg_s=flow, duty=duty, pwm_frequency_hz=pwm_hz,
            supply_pressure_pa=supply, output_pressure_pa=output,
            position_measured=bool(signals['PositionValid']),
            coil_current_mean_a=current_mean, coil_voltage_mean_v=voltage_mean,
            samples_lost_before=lost))

    def _track_telemetry(self, signals: dict, counter: int) -> tuple[tuple | None, bool]:
        """Account for one telemetry frame (lock held).

        Returns the values of the sample to hand on (None while inactive or for a rejected
        frame) and whether a diagnostic level may have changed.
        """
        now = time.monotonic()
        cfg = self._config
        check = self._telemetry_counter.check(counter)
        if check is CounterCheck.FROZEN:
            self.frozen_run += 1
            self._reject(RejectReason.COUNTER_FROZEN.value,
                         f'ValveTelemetry counter stuck at {counter} ({self.frozen_run} '
                         'frames)')
            return None, self.frozen_run == cfg.frozen_counter_limit
        self.frozen_run = 0
        gap = self.last_valid_mono is None or now - self.last_valid_mono > cfg.telemetry_timeout_s
        if check is CounterCheck.JUMP:
            self._tally.count('counter_jumps')
            self._tally.count('frames_lost', self._telemetry_counter.lost)
            self._tally.mark('counter_jump', now)
        self.health.frame(now, self._telemetry_counter.lost)
        # the counter tells the controller's skipped instants even after a stall of this
        # process (frames queued, not lost), unless it wrapped (more than 14)
        lost = 0 if check is CounterCheck.FIRST else self._telemetry_counter.lost
        steps = 1 + self._telemetry_counter.lost
        if gap or check is CounterCheck.FIRST:
            self._averager = None
            self._last_position = None
            steps = 1
        self._tally.count('telemetry_frames')
        self._periods_since_valve_period += 1 + self._telemetry_counter.lost
        self.last_valid_mono = now
        self._link.note_valid_traffic()
        period_s = cfg.telemetry_period_s
        t = self._last_sample_t + steps * period_s
        self._last_sample_t = t
        position = float(signals['SpoolPosition'])
        previous = self._last_position
        velocity = 0.0 if previous is None else (position - previous) / (steps * period_s)
        self._last_position = position
        average = self._driver_average(t, position)
        scheduler = self._scheduler
        duty_sent, pwm_hz = scheduler.last_sent_duty, scheduler.pwm_hz
        supply, output = scheduler.supply_pa, scheduler.output_pa
        duty = duty_sent if signals['Enabled'] else 0.0
        if self.average_source() == 'controller':
            average, duty, pwm_hz = self.period[0], self.period[1], self.period[2] or pwm_hz
        if not scheduler.active:
            return None, False
        return (average, duty, pwm_hz, supply, output, velocity, lost), False

    def _driver_average(self, t: float, position: float) -> float:
        """The suite's period average on the telemetry positions (used without ValvePeriod).

        The driver does not know the phase of the controller's PWM, so its periods start
        at the first sample after a gap; over a full period of a periodic signal the mean
        does not depend on the phase.
        """
        period = 1.0 / self._scheduler.pwm_hz
        if self._averager is None:
            self._averager = PeriodAverager(period, t0_s=t)
        else:
            self._averager.set_period(period)
        return self._averager.update(t, position)

    # --- I/O thread --------------------------------------------------------------------------
    def loss_deadline(self) -> float:
        """The next instant :meth:`check_loss` may change the telemetry state."""
        return self.health.deadline()

    def check_loss(self, now: float) -> bool:
        """Judge the telemetry (I/O thread); True if it was declared lost or back now."""
        with self._lock:
            change = self.health.update(now)
            if change is None:
                return False
            timeout = self._config.telemetry_timeout_s
            log = True
            if change.lost:
                self._tally.count('telemetry_losses')
                losses = self._tally.counts['telemetry_losses']
                log = now - self._last_loss_log >= _LOG_INTERVAL_S
                if log:
                    suppressed = losses - self._losses_logged - 1
                    self._last_loss_log = now
                    self._losses_logged = losses
            else:
                log = self._losses_logged == self._tally.counts['telemetry_losses']
        if change.lost and log:
            logger.error('telemetry lost (%s): %s%s', change.reason,
                         f'no valid ValveTelemetry for {change.after_s * 1e3:.1f} ms (limit '
                         f'{timeout * 1e3:.1f} ms)' if change.reason == 'silence' else
                         f'frames missing in {change.after_s:.2f} s of consecutive windows',
                         f'; {suppressed} more losses since the last message'
                         if suppressed > 0 else '')
        elif not change.lost and log:
            logger.info('telemetry is back')   # only after a loss that was logged
        return True

    def update_rate(self, now: float) -> None:
        """Measure the telemetry rate over the last window (I/O thread)."""
        with self._lock:
            start, count = self._rate_window
            if now - start >= _RATE_WINDOW_S:
                frames = self._tally.counts['telemetry_frames']
                self.rate_hz = (frames - count) / (now - start)
                self._rate_window = (now, frames)
