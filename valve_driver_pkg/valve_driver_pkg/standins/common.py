"""What the stand-in devices share: their command line, their life as a process, the
output log line the tests and the fail-safe table read."""
from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from collections.abc import Callable
from typing import Protocol

import can

from valve_driver_pkg.canbus.cli import add_bus_arguments, open_device_bus
from valve_driver_pkg.errors import BusOpenError

__all__ = ['device_parser', 'OutputLog', 'serve', 'StandIn', 'DeviceLoop']


class StandIn(Protocol):
    """A stand-in device on a bus: it runs between :meth:`start` and :meth:`stop`."""

    def start(self) -> None: ...

    def stop(self) -> None: ...


def device_parser(prog: str, doc: str) -> argparse.ArgumentParser:
    """A stand-in's parser: its docstring as help, the bus, the valve, ``--duration-s``."""
    parser = argparse.ArgumentParser(prog=prog, description=doc.split('\n')[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog=doc.split('\n', 2)[2])
    add_bus_arguments(parser)
    parser.add_argument('--params-file', default='',
                        help='valve parameter YAML of the valve behind the output (default: '
                             'the model\'s config/valve.yaml)')
    parser.add_argument('--duration-s', type=float, default=0.0,
                        help='stop after this long (default: until SIGINT/SIGTERM)')
    return parser


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


class DeviceLoop:
    """A stand-in's two threads: the receive thread (a ``can.Notifier`` calling
    ``listeners``) and the firmware's cyclic task, ``tick(now)`` every ``tick_s`` with the
    monotonic time."""

    def __init__(self, bus: can.BusABC, listeners: list, tick: Callable[[float], None],
                 tick_s: float, name: str) -> None:
        self._bus = bus
        self._listeners = listeners
        self._tick = tick
        self._tick_s = tick_s
        self._stop = threading.Event()
        self._notifier: can.Notifier | None = None
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def start(self) -> None:
        self._notifier = can.Notifier(self._bus, self._listeners, timeout=0.1)
        self._thread.start()

    def stop(self) -> None:
        """End both threads (safe before start and twice)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        if self._notifier is not None:
            self._notifier.stop()
            self._notifier = None

    def _run(self) -> None:
        while not self._stop.wait(self._tick_s):
            self._tick(time.monotonic())


def serve(prog: str, args: argparse.Namespace, make: Callable[[can.BusABC], StandIn],
          where: str) -> None:
    """Open the bus, build the device with ``make(bus)``, print ``PROG ready: ...`` and
    run it until SIGINT/SIGTERM or ``--duration-s``; exit 2 with one line if the bus
    cannot be opened. ``where`` names the device in the ready line (after the channel)."""
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    try:
        bus = open_device_bus(args)
    except (BusOpenError, OSError, ValueError) as err:
        print(f'{prog}: error: {err}', file=sys.stderr)
        sys.exit(2)
    try:
        device = make(bus.bus)
        device.start()
        print(f'{prog} ready: {args.interface} {bus.channel} {where}', flush=True)
        try:
            done.wait(args.duration_s if args.duration_s > 0 else None)
        finally:
            device.stop()
    finally:
        bus.close()
