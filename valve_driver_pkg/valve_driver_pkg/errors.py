"""Exceptions of valve_driver_pkg: one small tree, leaves also inherit the matching built-in.

::

    ValveDriverError
    ├── ProtocolError
    │   ├── DbcError (ValueError)            the DBC breaks the protocol's layout rules
    │   ├── ProtocolEncodeError (ValueError) a signal value outside its DBC range (strict)
    │   ├── FrameRejected                    a received frame failed a check (has reason)
    │   └── MappingError (ValueError)        a device mapping names what is not there
    ├── DeviceError
    │   ├── DeviceSetupError (RuntimeError)  the device could not be set up (no answer, abort)
    │   └── SdoAbortError (RuntimeError)     a CANopen device refused an SDO access (has code)
    └── BusError
        ├── BusOpenError (OSError)           the bus could not be opened
        └── BusClosedError (ConnectionError) the bus went away while in use
"""
from __future__ import annotations

__all__ = [
    'ValveDriverError', 'ProtocolError', 'DbcError', 'ProtocolEncodeError', 'FrameRejected',
    'MappingError', 'DeviceError', 'DeviceSetupError', 'SdoAbortError',
    'BusError', 'BusOpenError', 'BusClosedError',
]


class ValveDriverError(Exception):
    """Base class of every error raised by valve_driver_pkg."""


class ProtocolError(ValveDriverError):
    """Something about the CAN protocol (DBC, encoding, decoding) is wrong."""


class DbcError(ProtocolError, ValueError):
    """The DBC file cannot be used: missing message, bad layout, overlapping ids."""


class ProtocolEncodeError(ProtocolError, ValueError):
    """A signal value is outside the range the DBC allows (cantools strict encoding)."""


class FrameRejected(ProtocolError):
    """A received frame failed a check; ``reason`` is a :class:`RejectReason` value.

    Parameters
    ----------
    reason : str
        Machine-readable reason (``RejectReason`` member value), used as a counter key.
    detail : str
        Human-readable description naming the frame, the check and the values.
    """

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(detail)
        self.reason = reason
        self.detail = detail


class MappingError(ProtocolError, ValueError):
    """A device mapping (CANopen objects, DBC messages and signals) cannot be used; the
    message names the file, the role and the missing object, message or signal."""


class DeviceError(ValveDriverError):
    """Base class of errors a device on the bus causes."""


class DeviceSetupError(DeviceError, RuntimeError):
    """The device did not answer its set-up in time, or refused it."""


class SdoAbortError(DeviceError, RuntimeError):
    """A CANopen device aborted an SDO transfer; ``code`` is the CiA 301 abort code.

    Parameters
    ----------
    code : int
        The 32-bit abort code.
    detail : str
        What was accessed and the code's name.
    """

    def __init__(self, code: int, detail: str) -> None:
        super().__init__(detail)
        self.code = code


class BusError(ValveDriverError):
    """Base class of CAN bus (transport) errors."""


class BusOpenError(BusError, OSError):
    """The bus could not be opened (no interface, no hub listening, bad channel)."""


class BusClosedError(BusError, ConnectionError):
    """The bus went away while it was in use (hub closed, interface down)."""
