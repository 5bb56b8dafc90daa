"""ROS-free stand-in for the valve controller firmware (valve model + CAN protocol)."""
from valve_driver_pkg.emulator.config import ControllerState, EmulatorConfig, StepperLike
from valve_driver_pkg.emulator.controller import ControllerEmulator
from valve_driver_pkg.emulator.faults import (FAULT_NAMES, EmulatorRemote, FaultInjector,
                                              parse_fault_spec)
from valve_driver_pkg.protocol.codec import EmulatorFault

__all__ = ['ControllerEmulator', 'ControllerState', 'EmulatorConfig', 'StepperLike',
           'EmulatorRemote', 'FaultInjector', 'EmulatorFault', 'FAULT_NAMES', 'parse_fault_spec']
