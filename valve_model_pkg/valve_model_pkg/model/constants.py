"""Physical constants of the suite: the one home for each (SI units).

Everything that needs one of these imports it from here (or from
:mod:`valve_model_pkg.interface`, which re-exports them for the ROS side).
"""
from __future__ import annotations

__all__ = ['ATMOSPHERIC_PRESSURE_PA', 'gauge_from_absolute', 'absolute_from_gauge']

#: Standard atmosphere [Pa]. sensor_msgs/FluidPressure carries ABSOLUTE pressure; the
#: suite's own messages, the model's interface and the measured-data files carry gauge
#: pressure. Eq. (12) needs absolute pressures, so this is added there.
ATMOSPHERIC_PRESSURE_PA = 101_325.0


def gauge_from_absolute(absolute_pa: float) -> float:
    """Gauge pressure [Pa] from an absolute reading [Pa] (sensor_msgs/FluidPressure)."""
    return float(absolute_pa) - ATMOSPHERIC_PRESSURE_PA


def absolute_from_gauge(gauge_pa: float) -> float:
    """Absolute pressure [Pa] (for sensor_msgs/FluidPressure) from gauge [Pa]."""
    return float(gauge_pa) + ATMOSPHERIC_PRESSURE_PA
