"""valve_dbc_device: a user's own valve board (STM32 class) driven by its own DBC.

The firmware of the example board (``devices/data/examples/board.dbc``), as its author
would write it against that DBC (it knows its own message and signal names):

* ``BoardCommand`` (0x321, every 20 ms, Motorola): ``DutyPct`` 0.01 %, ``PwmFreq`` 0.1 Hz,
  ``Enable``, ``Alive`` (4-bit counter); no checksum. A frame whose ``Alive`` repeats the
  previous one is ignored. Enable 0 or duty 0 switches the output off at once.
* **Command timeout**: no accepted ``BoardCommand`` for ``--command-timeout-ms`` (200 ms,
  ten cycles) switches the output off until the next one.
* ``BoardStatus`` (29-bit 0x18FF2021, every 100 ms, multiplexed): page 0 the coil current
  [mA] and the duty in force [%], page 1 the spool position [um], the mean over the last
  complete PWM period as the board's position filter gives it, and the supply [V]; both
  pages every cycle.

Every change of the output prints ``valve_dbc_device: output duty D at monotonic T:
REASON``.
"""
from __future__ import annotations

import argparse
import threading
import time

import can
import cantools

from valve_driver_pkg.devices.dbc_protocol import example_dbc_path
from valve_driver_pkg.standins.common import DeviceLoop, OutputLog, device_parser, serve
from valve_driver_pkg.standins.plant import ValvePlant

__all__ = ['DbcDevice', 'main', 'build_parser']

PROG = 'valve_dbc_device'
_TICK_S = 0.002
_SUPPLY_V = 24.0


class DbcDevice:
    """The example board on a bus (see the module docstring)."""

    def __init__(self, bus: can.BusABC, plant: ValvePlant, dbc_file: str = '',
                 command_timeout_s: float = 0.2, log: OutputLog | None = None) -> None:
        self.bus = bus
        self.plant = plant
        self.db = cantools.database.load_file(str(dbc_file or example_dbc_path()))
        self.command = self.db.get_message_by_name('BoardCommand')
        self.status = self.db.get_message_by_name('BoardStatus')
        self.command_timeout_s = command_timeout_s
        self.log = log or OutputLog(PROG)
        self._lock = threading.Lock()
        self._alive: int | None = None
        self._last: float | None = None
        self._timed_out = False
        self._next_status = 0.0
        self._status_period_s = (self.status.cycle_time or 100) / 1000.0
        self._loop = DeviceLoop(bus, [self._on_frame], self._tick, _TICK_S, 'dbc_device')
        self.ignored = 0

    def start(self) -> None:
        self._loop.start()

    def stop(self) -> None:
        self._loop.stop()

    def _on_frame(self, msg: can.Message) -> None:
        if msg.arbitration_id != self.command.frame_id or msg.is_extended_id \
                or msg.is_error_frame:
            return
        try:
            sig = self.command.decode(bytes(msg.data))
        except Exception:   # noqa: BLE001 - a bad frame is ignored, as firmware does
            self.ignored += 1
            return
        with self._lock:
            if sig['Alive'] == self._alive:
                self.ignored += 1
                return
            self._alive = sig['Alive']
            self._last = time.monotonic()
            self._timed_out = False
        duty = float(sig['DutyPct']) / 100.0 if sig['Enable'] else 0.0
        self.plant.set_output(duty, float(sig['PwmFreq']))
        self.log.output(duty, 'BoardCommand')

    def _tick(self, now: float) -> None:
        with self._lock:
            last = self._last
            expired = (last is not None and not self._timed_out
                       and now - last > self.command_timeout_s)
            if expired:
                self._timed_out = True
        if expired:
            self.plant.set_output(0.0)
            self.log.output(0.0, f'command timeout ({(now - last) * 1e3:.0f} ms without '
                            'BoardCommand)')
        reading = self.plant.read()
        if now >= self._next_status:
            period = self._status_period_s
            self._next_status = max(self._next_status + period, now - period)
            self._send_status(reading)

    def _send_status(self, reading) -> None:
        current_ma = max(-32768, min(32767, round(reading.coil_current_a * 1000.0)))
        pages = ({'Page': 0, 'CoilCurrent': current_ma, 'DutyActual': reading.duty * 100.0},
                 {'Page': 1, 'SpoolPos': min(max(reading.position_avg_m * 1e6, 0.0), 655.35),
                  'SupplyVoltage': _SUPPLY_V})
        for page in pages:
            data = self.status.encode(page)
            try:
                self.bus.send(can.Message(arbitration_id=self.status.frame_id,
                                          is_extended_id=True, data=data))
            except can.CanError:
                pass


def build_parser() -> argparse.ArgumentParser:
    """The command-line interface."""
    p = device_parser(PROG, __doc__)
    p.add_argument('--dbc', default='', help='the board\'s DBC (default: the example)')
    p.add_argument('--command-timeout-ms', type=float, default=200.0,
                   help='no BoardCommand this long switches the output off (default 200)')
    return p


def main(args: list[str] | None = None) -> None:
    opts = build_parser().parse_args(args)
    serve(PROG, opts, lambda bus: DbcDevice(bus, ValvePlant(50.0, opts.params_file), opts.dbc,
                                            opts.command_timeout_ms / 1000.0),
          'board BoardCommand')


if __name__ == '__main__':
    main()
