"""ROS-free logic of the CAN driver: bus link, transmit scheduler, receive tracker, diagnostics.

The samples are the suite's :class:`~valve_model_pkg.model.sample.ValveSample`; the
per-period average the driver derives when a controller sends no ``ValvePeriod`` is the
suite's :class:`~valve_model_pkg.model.averaging.PeriodAverager`.
"""
from valve_driver_pkg.driver.config import DriverConfig
from valve_driver_pkg.driver.core import CanDriverCore
from valve_driver_pkg.driver.diagnostics import (DriverSnapshot, Level, StatusReport,
                                                 diagnose, overall_level)
from valve_driver_pkg.driver.transmit import CommandResult

__all__ = ['CanDriverCore', 'DriverConfig', 'CommandResult', 'Level', 'StatusReport',
           'DriverSnapshot', 'diagnose', 'overall_level']
