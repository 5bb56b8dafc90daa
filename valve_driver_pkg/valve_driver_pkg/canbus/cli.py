"""A bus from the command line of a bus device (the emulator, the stand-ins), and the
``tcp_loopback`` hub as a process of its own.

:func:`add_bus_arguments` adds ``--interface``, ``--channel``, ``--bitrate`` and
``--no-hub``; :func:`open_device_bus` opens that bus and, for ``tcp_loopback`` without
``--no-hub``, first hosts the loopback hub the other bus clients join.

``python -m valve_driver_pkg.canbus.cli [--channel 127.0.0.1:PORT]`` hosts a hub alone (port
0: a free one), prints ``tcp_loopback hub ready: HOST:PORT`` and forwards frames until
SIGINT/SIGTERM: a bus that outlives every device on it (a device may die and come back).
"""
from __future__ import annotations

import argparse
import signal
import sys
import threading
from dataclasses import dataclass

import can

from valve_driver_pkg.canbus.factory import open_bus
from valve_driver_pkg.canbus.tcp_loopback import TcpLoopbackHub
from valve_driver_pkg.errors import BusOpenError

__all__ = ['add_bus_arguments', 'open_device_bus', 'DeviceBus', 'hub_main']


def add_bus_arguments(parser: argparse.ArgumentParser) -> argparse._ArgumentGroup:
    """The ``bus`` argument group (returned, for a device's own bus options)."""
    bus = parser.add_argument_group('bus')
    bus.add_argument('--interface', default='tcp_loopback',
                     help='python-can interface, or tcp_loopback (default)')
    bus.add_argument('--channel', default='127.0.0.1:29536',
                     help='channel (tcp_loopback: HOST:PORT, port 0 = any free port)')
    bus.add_argument('--bitrate', type=int, default=500_000, help='bit rate [bit/s]')
    bus.add_argument('--no-hub', action='store_true',
                     help='tcp_loopback: join an existing hub instead of hosting one')
    return bus


@dataclass
class DeviceBus:
    """An open bus, the hub it hosts (or None) and the channel others reach it on."""

    bus: can.BusABC
    hub: TcpLoopbackHub | None
    channel: str

    def close(self) -> None:
        """Shut the bus down, then the hub."""
        self.bus.shutdown()
        if self.hub is not None:
            self.hub.close()


def open_device_bus(args: argparse.Namespace, connect_timeout: float = 5.0) -> DeviceBus:
    """The bus of :func:`add_bus_arguments`' arguments, hosting the hub if asked to.

    Raises
    ------
    BusOpenError, OSError
        No bus or no hub (nothing is left open); the message names the cause.
    """
    hub = None
    channel = args.channel
    try:
        if args.interface == 'tcp_loopback' and not args.no_hub:
            hub = TcpLoopbackHub(channel).start()
            channel = hub.channel
        return DeviceBus(open_bus(args.interface, channel, args.bitrate,
                                  connect_timeout=connect_timeout), hub, channel)
    except (BusOpenError, OSError, ValueError):
        if hub is not None:
            hub.close()
        raise


def hub_main(args: list[str] | None = None) -> None:
    """Host a tcp_loopback hub until SIGINT/SIGTERM (exit 2 if it cannot listen)."""
    parser = argparse.ArgumentParser(prog='python -m valve_driver_pkg.canbus.cli',
                                     description='host a tcp_loopback CAN hub (loopback only)')
    parser.add_argument('--channel', default='127.0.0.1:0',
                        help='HOST:PORT to listen on (port 0: a free port)')
    opts = parser.parse_args(args)
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    try:
        hub = TcpLoopbackHub(opts.channel).start()
    except (OSError, ValueError) as err:
        print(f'tcp_loopback hub: error: {err}', file=sys.stderr)
        sys.exit(2)
    print(f'tcp_loopback hub ready: {hub.channel}', flush=True)
    try:
        done.wait()
    finally:
        hub.close()


if __name__ == '__main__':
    hub_main()
