"""The one sample type of the suite: the state of one valve at one instant.

The model (:class:`~valve_model_pkg.model.stepper.ValveStepper`) and the CAN driver (one
telemetry frame set) both produce it; :func:`valve_model_pkg.interface.ros.state_message`
turns it into ``valve_msgs/ValveState``. SI units, gauge pressures.
"""
from __future__ import annotations

import dataclasses
import math

__all__ = ['ValveSample']


@dataclasses.dataclass(frozen=True)
class ValveSample:
    """State of the valve at one instant (SI units, gauge pressures).

    Attributes
    ----------
    t_s : float
        Time the state refers to, s: model time from the model, the wall-clock receive
        time (s since the epoch) from the CAN driver.
    coil_voltage_v : float
        Voltage the driver applies to the coil, V.
    coil_current_a : float
        Coil terminal current, A.
    spool_position_m : float
        Spool position, m (0 closed).
    spool_velocity_m_s : float
        Spool velocity, m/s.
    position_avg_m : float
        Average position over the last complete main PWM period, m (0 before the first).
    mass_flow_kg_s : float
        Orifice mass flow from ``position_avg_m``, eq. (12), kg/s.
    duty : float
        Duty cycle in effect (the commanded one from the next period start on).
    pwm_frequency_hz : float
        PWM frequency in effect, Hz.
    supply_pressure_pa, output_pressure_pa : float
        Gauge pressures in effect, Pa.
    coil_temperature_rise_k : float
        Coil temperature above the reference (coil_heating), K.
    position_measured : bool
        True when the spool position is measured or estimated by hardware (CAN
        telemetry with a position sensor), False when it is modelled.
    coil_current_mean_a : float
        Mean coil terminal current over the interval since the previous sample, A: the
        model's exact integral, or the controller's ADC average over the telemetry period
        (CAN). NaN when the source does not provide it.
    coil_voltage_mean_v : float
        Mean coil terminal voltage over the same interval, V (NaN when not provided).
    samples_lost_before : int
        Samples the source took but did not deliver just before this one (a controller's
        telemetry counter that jumped): the interval of the means is then one sample
        period, not the time since the previous delivered sample, and a publisher
        advances its message counter by this many so that a reader can tell.
    """

    t_s: float
    coil_voltage_v: float
    coil_current_a: float
    spool_position_m: float
    spool_velocity_m_s: float
    position_avg_m: float
    mass_flow_kg_s: float
    duty: float
    pwm_frequency_hz: float
    supply_pressure_pa: float
    output_pressure_pa: float
    coil_temperature_rise_k: float = 0.0
    position_measured: bool = False
    coil_current_mean_a: float = math.nan
    coil_voltage_mean_v: float = math.nan
    samples_lost_before: int = 0
