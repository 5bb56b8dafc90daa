"""ROS-free logic of the CAN driver: bus and threads, watchdog, fault detection, diagnostics."""
from valve_driver_pkg.driver.averaging import PeriodAverager
from valve_driver_pkg.driver.core import (CanDriverCore, CommandResult, DriverConfig, Level,
                                          StateSample, StatusReport)

__all__ = ['CanDriverCore', 'DriverConfig', 'StateSample', 'CommandResult', 'Level',
           'StatusReport', 'PeriodAverager']
