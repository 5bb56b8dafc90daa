"""CAN error frames in the SocketCAN encoding (``linux/can/error.h``), read and made.

The Linux kernel reports controller state changes as error frames: the error class is in
the id (python-can keeps it in ``arbitration_id`` with ``is_error_frame=True``), details in
the data bytes. The driver reads them to report error-passive and bus-off; the emulator
makes them to inject those conditions on buses that have no controller (virtual,
tcp_loopback). On real hardware the kernel produces them itself (python-can's socketcan
interface receives error frames unless ``ignore_rx_error_frames=True``).
"""
from __future__ import annotations

import enum
from dataclasses import dataclass

import can

__all__ = ['BusCondition', 'ErrorFrameInfo', 'parse_error_frame', 'make_error_frame',
           'CAN_ERR_CRTL', 'CAN_ERR_BUSOFF', 'CAN_ERR_RESTARTED']

# Error classes (id bits).
CAN_ERR_TX_TIMEOUT = 0x001
CAN_ERR_LOSTARB = 0x002
CAN_ERR_CRTL = 0x004
CAN_ERR_PROT = 0x008
CAN_ERR_TRX = 0x010
CAN_ERR_ACK = 0x020
CAN_ERR_BUSOFF = 0x040
CAN_ERR_BUSERROR = 0x080
CAN_ERR_RESTARTED = 0x100
CAN_ERR_CNT = 0x200
# Controller status (data[1]) when CAN_ERR_CRTL is set.
CAN_ERR_CRTL_RX_OVERFLOW = 0x01
CAN_ERR_CRTL_TX_OVERFLOW = 0x02
CAN_ERR_CRTL_RX_WARNING = 0x04
CAN_ERR_CRTL_TX_WARNING = 0x08
CAN_ERR_CRTL_RX_PASSIVE = 0x10
CAN_ERR_CRTL_TX_PASSIVE = 0x20
CAN_ERR_CRTL_ACTIVE = 0x40
_PASSIVE = CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE
_WARNING = CAN_ERR_CRTL_RX_WARNING | CAN_ERR_CRTL_TX_WARNING


class BusCondition(enum.Enum):
    """Controller condition an error frame reports (most severe first wins)."""

    BUS_OFF = 'bus_off'
    ERROR_PASSIVE = 'error_passive'
    WARNING = 'warning'
    ERROR_ACTIVE = 'error_active'     # back to normal after passive/warning
    RESTARTED = 'restarted'           # controller restarted after bus-off
    OTHER = 'other'                   # protocol/ack/arbitration errors: counted only


@dataclass(frozen=True, slots=True)
class ErrorFrameInfo:
    """What an error frame says: condition, the raw class bits, and a readable text."""

    condition: BusCondition
    error_class: int
    text: str


def parse_error_frame(msg: can.Message) -> ErrorFrameInfo:
    """Interpret a python-can error frame (``msg.is_error_frame`` must be true)."""
    error_class = msg.arbitration_id & 0x1FFFFFFF
    data = bytes(msg.data) + bytes(8)
    ctrl = data[1]
    names = [name for bit, name in ((CAN_ERR_TX_TIMEOUT, 'tx-timeout'),
                                    (CAN_ERR_LOSTARB, 'lost-arbitration'),
                                    (CAN_ERR_CRTL, 'controller'),
                                    (CAN_ERR_PROT, 'protocol'),
                                    (CAN_ERR_TRX, 'transceiver'),
                                    (CAN_ERR_ACK, 'no-ack'),
                                    (CAN_ERR_BUSOFF, 'bus-off'),
                                    (CAN_ERR_BUSERROR, 'bus-error'),
                                    (CAN_ERR_RESTARTED, 'restarted')) if error_class & bit]
    if error_class & CAN_ERR_BUSOFF:
        condition = BusCondition.BUS_OFF
    elif error_class & CAN_ERR_CRTL and ctrl & _PASSIVE:
        condition = BusCondition.ERROR_PASSIVE
    elif error_class & CAN_ERR_RESTARTED:
        condition = BusCondition.RESTARTED
    elif error_class & CAN_ERR_CRTL and ctrl & _WARNING:
        condition = BusCondition.WARNING
    elif error_class & CAN_ERR_CRTL and ctrl & CAN_ERR_CRTL_ACTIVE:
        condition = BusCondition.ERROR_ACTIVE
    else:
        condition = BusCondition.OTHER
    text = f'error frame class 0x{error_class:03X} ({", ".join(names) or "unspecified"})'
    if error_class & CAN_ERR_CRTL:
        text += f', controller status 0x{ctrl:02X}'
    if error_class & CAN_ERR_CNT:
        text += f', tx errors {data[6]}, rx errors {data[7]}'
    return ErrorFrameInfo(condition, error_class, text)


def make_error_frame(condition: BusCondition, timestamp: float = 0.0) -> can.Message:
    """An error frame reporting ``condition`` as the Linux kernel would."""
    data = bytearray(8)
    if condition is BusCondition.BUS_OFF:
        error_class = CAN_ERR_BUSOFF
    elif condition is BusCondition.ERROR_PASSIVE:
        error_class = CAN_ERR_CRTL | CAN_ERR_CNT
        data[1] = CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE
        data[6], data[7] = 128, 128
    elif condition is BusCondition.WARNING:
        error_class = CAN_ERR_CRTL | CAN_ERR_CNT
        data[1] = CAN_ERR_CRTL_RX_WARNING | CAN_ERR_CRTL_TX_WARNING
        data[6], data[7] = 96, 96
    elif condition is BusCondition.ERROR_ACTIVE:
        error_class = CAN_ERR_CRTL
        data[1] = CAN_ERR_CRTL_ACTIVE
    elif condition is BusCondition.RESTARTED:
        error_class = CAN_ERR_RESTARTED
    else:
        error_class = CAN_ERR_PROT
    return can.Message(arbitration_id=error_class, data=data, is_error_frame=True,
                       is_extended_id=True, timestamp=timestamp)
