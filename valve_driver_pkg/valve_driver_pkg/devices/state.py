"""A device's reading -> the suite's valve sample: what is measured, what is derived.

One home for the rule the driver's README table states per protocol, used by the driver
core on every reading it publishes and by ``valve_can_replay`` on every reading in a bus
log, so a replayed log gives the states the driver published:

* a reported spool position is measured (``position_measured``); its velocity is the
  difference of two readings, its period mean the suite's
  :class:`~valve_model_pkg.model.averaging.PeriodAverager` over the readings;
* without one, the period-mean position at the duty in force comes from the duty map
  (:class:`~valve_driver_pkg.devices.derived.DerivedOpening`) and stands for both the
  position and its mean (``position_measured`` false, velocity absent);
* the mass flow is eq. (12) from the period mean;
* the duty is the device's own report if it gives one (J1939 Estimated Flow), else the duty
  of the last command sent.

Not thread-safe: the caller serialises (the core under its lock).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from valve_driver_pkg.devices.base import DeviceReading
from valve_driver_pkg.devices.derived import DerivedOpening
from valve_driver_pkg.driver.receive import MassFlowFunction
from valve_model_pkg.model.averaging import PeriodAverager
from valve_model_pkg.model.sample import ValveSample

__all__ = ['StateBuilder', 'CommandContext']


@dataclass(frozen=True, slots=True)
class CommandContext:
    """What the host had sent when a reading came: the duty of the last command frame [1],
    the PWM frequency in force [Hz] (``frequency_sent``: the device got it), the gauge port
    pressures [Pa]."""

    duty_sent: float
    pwm_frequency_hz: float
    frequency_sent: bool
    supply_pressure_pa: float
    output_pressure_pa: float


class StateBuilder:
    """Readings -> :class:`~valve_model_pkg.model.sample.ValveSample` (module docstring).

    Parameters
    ----------
    mass_flow : MassFlowFunction | None
        eq. (12); NaN flow without it.
    derived : DerivedOpening | None
        The duty map for a device that reports no position; NaN position without it.
    """

    def __init__(self, mass_flow: MassFlowFunction | None = None,
                 derived: DerivedOpening | None = None) -> None:
        self._mass_flow = mass_flow
        self._derived = derived
        self._averager: PeriodAverager | None = None
        self._last_position: tuple[float, float] | None = None

    def reset(self) -> None:
        """Forget the position history (the device was lost: no mean across the gap)."""
        self._averager = None
        self._last_position = None

    def sample(self, reading: DeviceReading, command: CommandContext, mono_s: float,
               wall_s: float) -> ValveSample:
        """The sample of ``reading``, received at ``mono_s`` (monotonic [s], for velocity
        and the period mean) and stamped ``wall_s`` [s since the epoch]."""
        duty = reading.duty if math.isfinite(reading.duty) else command.duty_sent
        freq = command.pwm_frequency_hz
        position, velocity, avg = self._measured(reading.spool_position_m, mono_s, freq)
        measured = math.isfinite(position)
        if not measured and self._derived is not None:
            position = avg = self._derived.position_avg_m(duty, freq,
                                                          command.supply_pressure_pa)
        supply, output = command.supply_pressure_pa, command.output_pressure_pa
        flow = (self._mass_flow(avg, supply, output)
                if self._mass_flow is not None and math.isfinite(avg) else math.nan)
        return ValveSample(
            t_s=wall_s, coil_voltage_v=reading.coil_voltage_v,
            coil_current_a=reading.coil_current_a, spool_position_m=position,
            spool_velocity_m_s=velocity, position_avg_m=avg, mass_flow_kg_s=flow, duty=duty,
            pwm_frequency_hz=freq if command.frequency_sent else math.nan,
            supply_pressure_pa=supply, output_pressure_pa=output, position_measured=measured)

    def _measured(self, position: float, now: float,
                  pwm_hz: float) -> tuple[float, float, float]:
        """``(position, velocity, period mean)`` of a reported position; NaN if none."""
        if not math.isfinite(position):
            return math.nan, math.nan, math.nan
        last = self._last_position
        velocity = ((position - last[1]) / (now - last[0])
                    if last is not None and now > last[0] else 0.0)
        self._last_position = (now, position)
        if self._averager is None:
            self._averager = PeriodAverager(1.0 / pwm_hz, t0_s=now)
        else:
            self._averager.set_period(1.0 / pwm_hz)
        return position, velocity, self._averager.update(now, position)
