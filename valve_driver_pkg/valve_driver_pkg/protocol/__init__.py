"""ROS-free CAN protocol of the valve controller: DBC file, cantools codec, checksums."""
from valve_driver_pkg.protocol.codec import (COMMAND, CONTROL, DRIVE, PERIOD, PRESSURE,
                                             STATUS, TELEMETRY, TELEMETRY_MEAN, CounterCheck,
                                             CounterTracker, DecodedFrame, DriveMode,
                                             EmulatorFault, RejectReason,
                                             ValveCodec, crc8, default_dbc_path,
                                             fault_injection_dbc_path)
from valve_driver_pkg.protocol.error_frames import (BusCondition, ErrorFrameInfo,
                                                    make_error_frame, parse_error_frame)

__all__ = [
    'COMMAND', 'TELEMETRY', 'TELEMETRY_MEAN', 'PERIOD', 'PRESSURE', 'STATUS', 'CONTROL',
    'DRIVE', 'DriveMode', 'ValveCodec',
    'DecodedFrame', 'RejectReason', 'CounterTracker', 'CounterCheck', 'EmulatorFault', 'crc8',
    'default_dbc_path', 'fault_injection_dbc_path', 'BusCondition', 'ErrorFrameInfo',
    'make_error_frame', 'parse_error_frame',
]
