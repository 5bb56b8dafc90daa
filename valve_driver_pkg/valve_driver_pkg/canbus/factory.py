"""Open a python-can bus from the driver's parameters, including ``tcp_loopback``."""
from __future__ import annotations

import can

from valve_driver_pkg.canbus.tcp_loopback import TcpLoopbackBus
from valve_driver_pkg.errors import BusOpenError

__all__ = ['open_bus', 'LOCAL_INTERFACES']

#: Interfaces that have no bit timing of their own (the bitrate argument is not passed).
#: For socketcan the bitrate belongs to the kernel: ``ip link set can0 type can bitrate N``.
LOCAL_INTERFACES = ('virtual', 'tcp_loopback', 'socketcan')


def open_bus(interface: str, channel: str, bitrate: int = 500_000,
             connect_timeout: float = 5.0, **kwargs: object) -> can.BusABC:
    """Open a CAN bus.

    Parameters
    ----------
    interface : str
        A python-can interface name (``socketcan``, ``virtual``, ``pcan``, ...) or
        ``tcp_loopback`` (this package's loopback hub, resolved here, not by python-can).
    channel : str
        Interface channel (``can0``, a virtual channel name, ``127.0.0.1:29536``).
    bitrate : int
        Bit rate [bit/s] for interfaces that set it themselves.
    connect_timeout : float
        ``tcp_loopback`` only: how long to retry a hub that is not up yet [s].
    **kwargs
        Passed to the bus constructor.

    Raises
    ------
    BusOpenError
        The bus could not be opened; the message names interface, channel and cause.
    """
    try:
        if interface == 'tcp_loopback':
            return TcpLoopbackBus(channel=channel, connect_timeout=connect_timeout, **kwargs)
        if interface not in LOCAL_INTERFACES:
            kwargs['bitrate'] = int(bitrate)
        return can.Bus(interface=interface, channel=channel, **kwargs)
    except (can.CanError, OSError, ValueError, ImportError, NotImplementedError) as err:
        raise BusOpenError(f'cannot open CAN bus {interface}:{channel}: {err}') from err
