"""What the stand-in devices share: bus arguments, the bus (hosting a hub or not), the
output log line tests read, the signal-driven run loop."""
from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from collections.abc import Callable

import can

from valve_driver_pkg.canbus.factory import open_bus
from valve_driver_pkg.canbus.tcp_loopback import TcpLoopbackHub
from valve_driver_pkg.errors import BusOpenError

__all__ = ['add_bus_arguments', 'open_device_bus', 'OutputLog', 'run_device']


def add_bus_arguments(parser: argparse.ArgumentParser) -> None:
    """``--interface``, ``--channel``, ``--bitrate``, ``--no-hub``, ``--params-file``."""
    bus = parser.add_argument_group('bus')
    bus.add_argument('--interface', default='tcp_loopback',
                     help='python-can interface, or tcp_loopback (default)')
    bus.add_argument('--channel', default='127.0.0.1:29536',
                     help='channel (tcp_loopback: HOST:PORT, port 0 = any free port)')
    bus.add_argument('--bitrate', type=int, default=500_000, help='bit rate [bit/s]')
    bus.add_argument('--no-hub', action='store_true',
                     help='tcp_loopback: join an existing hub instead of hosting one')
    parser.add_argument('--params-file', default='',
                        help='valve parameter YAML of the valve behind the output (default: '
                             'the model\'s config/valve.yaml)')


def open_device_bus(args: argparse.Namespace) -> tuple[can.BusABC, TcpLoopbackHub | None,
                                                       str]:
    """The device's bus (and the hub it hosts); the channel it is reachable on."""
    hub = None
    channel = args.channel
    if args.interface == 'tcp_loopback' and not args.no_hub:
        hub = TcpLoopbackHub(channel).start()
        channel = hub.channel
    try:
        bus = open_bus(args.interface, channel, args.bitrate)
    except BusOpenError:
        if hub is not None:
            hub.close()
        raise
    return bus, hub, channel


class OutputLog:
    """One stdout line per change of the output (tests and the safety table read it)::

        output duty 0.6000 at monotonic 1234.567890: RPDO1

    The time is ``time.monotonic()`` (CLOCK_MONOTONIC, one clock for every process).
    """

    def __init__(self, prog: str) -> None:
        self._prog = prog
        self._duty: float | None = None
        self._lock = threading.Lock()

    def output(self, duty: float, reason: str) -> None:
        with self._lock:
            if self._duty is not None and abs(duty - self._duty) < 1e-9:
                return
            self._duty = duty
        print(f'{self._prog}: output duty {duty:.4f} at monotonic {time.monotonic():.6f}: '
              f'{reason}', flush=True)

    def note(self, text: str) -> None:
        print(f'{self._prog}: {text} at monotonic {time.monotonic():.6f}', flush=True)


def run_device(prog: str, start: Callable[[], str], stop: Callable[[], None],
               duration_s: float = 0.0) -> None:
    """Start the device, print ``PROG ready: ...``, run until SIGINT/SIGTERM or duration."""
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    try:
        where = start()
    except (BusOpenError, OSError, ValueError) as err:
        print(f'{prog}: error: {err}', file=sys.stderr)
        sys.exit(2)
    print(f'{prog} ready: {where}', flush=True)
    try:
        done.wait(duration_s if duration_s > 0 else None)
    finally:
        stop()
