"""valve_j1939_device: an ISO 11783-7 auxiliary valve (the valve model behind it).

Written from ISO 11783-7 / SAE J1939-71 (auxiliary valve messages), J1939-81 (address
claim) and J1939-73 (DM1), with python-can frames of its own (not the driver's stack):

* **Address claim**: at start an Address Claimed (PGN 60928, global) with its NAME from
  ``--source-address``; it answers a Request for Address Claimed; if another NAME claims
  its address, the lower NAME wins: it repeats its claim when it wins, else sends Cannot
  Claim (source 254) and stays silent.
* **Auxiliary Valve Command** PGN 65072 + n (from any source): port flow from bytes 4-5
  (0.0015625 %/bit) when byte 2 bits 1-2 say extended resolution is valid, else from byte 1
  (0.4 %/bit); state (byte 3 bits 1-4): extend drives the valve at flow / 100 as duty,
  block and float switch it off; fail-safe mode (bits 7-8) is kept.
* **Command timeout**: no valid command for ``--command-timeout-ms`` (300 ms, three
  command periods) -> the fail-safe mode (block: valve off), exit/reason code 5 "remote
  command timeout", until the next command.
* **Auxiliary Valve Estimated Flow** PGN 65040 + n every 100 ms: extend port flow = the
  duty in force x 100 % (1 %/bit, offset -125), retract port 0 %, state, fail-safe mode,
  exit/reason code.
* **DM1** (PGN 65226) every second: lamps and the DTCs given with ``--dtc SPN:FMI``
  (amber lamp on while any), else "no DTC".
* **DM11** (a Request for PGN 65235 to its address): the DTCs are cleared, an
  Acknowledgment (ACK) and a DM1 answer at once.

Every change of the output prints ``valve_j1939_device: output duty D at monotonic T:
REASON``.
"""
from __future__ import annotations

import argparse
import threading
import time

import can

from valve_driver_pkg.standins.common import DeviceLoop, OutputLog, device_parser, serve
from valve_driver_pkg.standins.plant import ValvePlant

__all__ = ['J1939Device', 'main', 'build_parser']

PROG = 'valve_j1939_device'
#: A NAME for the stand-in (J1939-81): industry group 2 (agricultural), function 130,
#: identity number 0x1939; arbitrary address capable 0.
DEFAULT_NAME = (2 << 60) | (130 << 40) | 0x1939
_PRIORITY_CONTROL, _PRIORITY_INFO = 3, 6
_NULL_ADDRESS, _GLOBAL = 254, 255
_DM11 = (65235).to_bytes(3, 'little')     # PGN of DM11, as a Request carries it
_TICK_S = 0.002


def _frame_id(priority: int, pf: int, ps: int, source: int) -> int:
    return (priority << 26) | (pf << 16) | (ps << 8) | source


class J1939Device:
    """The auxiliary valve on a bus (see the module docstring)."""

    def __init__(self, bus: can.BusABC, plant: ValvePlant, source_address: int = 0xF0,
                 valve_index: int = 0, name: int = DEFAULT_NAME,
                 command_timeout_s: float = 0.3, dtcs: tuple[tuple[int, int], ...] = (),
                 log: OutputLog | None = None) -> None:
        self.bus = bus
        self.plant = plant
        self.address = source_address
        self.valve_index = valve_index
        self.name = name
        self.command_timeout_s = command_timeout_s
        self.dtcs = dtcs
        self.log = log or OutputLog(PROG)
        self._lock = threading.Lock()
        self._silent = False
        self._flow_pct = 0.0
        self._state = 0
        self._fail_safe = 0
        self._exit_code = 0
        self._last_command: float | None = None
        self._next_flow = self._next_dm1 = 0.0
        self._loop = DeviceLoop(bus, [self._on_frame], self._tick, _TICK_S, 'j1939_device')

    def start(self) -> None:
        self._claim(self.address)
        self._loop.start()

    def stop(self) -> None:
        self._loop.stop()

    def _send(self, can_id: int, data: bytes) -> None:
        try:
            self.bus.send(can.Message(arbitration_id=can_id, is_extended_id=True, data=data))
        except can.CanError:
            pass

    def _claim(self, address: int) -> None:
        self._send(_frame_id(_PRIORITY_INFO, 0xEE, _GLOBAL, address),
                   self.name.to_bytes(8, 'little'))

    # --- receive -----------------------------------------------------------------------------
    def _on_frame(self, msg: can.Message) -> None:
        if not msg.is_extended_id or msg.is_error_frame:
            return
        pf, ps, source = (msg.arbitration_id >> 16) & 0xFF, (msg.arbitration_id >> 8) & 0xFF, \
            msg.arbitration_id & 0xFF
        data = bytes(msg.data)
        if pf == 0xEE and source == self.address and len(data) >= 8:
            self._contend(int.from_bytes(data[:8], 'little'))
        elif pf == 0xEA and ps in (self.address, _GLOBAL) and data[:3] == b'\x00\xEE\x00':
            if not self._silent:
                self._claim(self.address)
        elif pf == 0xEA and ps == self.address and data[:3] == _DM11 and not self._silent:
            self._clear_dtcs(source)
        elif pf == 0xFE and ps == 0x30 + self.valve_index and not self._silent:
            self._on_command(data)

    def _clear_dtcs(self, requester: int) -> None:
        """DM11: the active DTCs are cleared (their simulated condition is gone); the
        Acknowledgment (PGN 59392, ACK) goes to global with the requester's address, and a
        DM1 follows at once."""
        with self._lock:
            cleared, self.dtcs = self.dtcs, ()
        self.log.note(f'DM11 from address {requester}: {len(cleared)} DTC(s) cleared')
        self._send(_frame_id(_PRIORITY_INFO, 0xE8, _GLOBAL, self.address),
                   bytes([0, 0xFF, 0xFF, 0xFF, requester]) + _DM11)
        self._send_dm1()

    def _contend(self, theirs: int) -> None:
        if theirs == self.name or self._silent:
            return
        if theirs < self.name:
            self._silent = True
            self._claim(_NULL_ADDRESS)       # cannot claim
            self.plant.set_output(0.0)
            self.log.output(0.0, f'address {self.address} lost to NAME 0x{theirs:016X}')
        else:
            self._claim(self.address)

    def _on_command(self, data: bytes) -> None:
        if len(data) < 5:
            return
        extended_valid = data[1] & 0x03 == 0x01 and data[3:5] != b'\xFF\xFF'
        if extended_valid:
            flow = int.from_bytes(data[3:5], 'little') * 0.0015625
        elif data[0] <= 250:
            flow = data[0] * 0.4
        else:
            return                            # not available: no valid command
        state, fail_safe = data[2] & 0x0F, data[2] >> 6
        with self._lock:
            self._last_command = time.monotonic()
            self._fail_safe = fail_safe if fail_safe in (0, 1) else 0
            self._state = state if state in (0, 1, 2, 3) else 0
            self._flow_pct = min(flow, 100.0) if self._state == 1 else 0.0
            self._exit_code = 0
            duty = self._flow_pct / 100.0
        self.plant.set_output(duty)
        self.log.output(duty, 'Auxiliary Valve Command')

    # --- cyclic ------------------------------------------------------------------------------
    def _tick(self, now: float) -> None:
        self._check_timeout(now)
        self.plant.read()
        if self._silent:
            return
        if now >= self._next_flow:
            self._next_flow = max(self._next_flow + 0.1, now - 0.1)
            self._send_estimated_flow()
        if now >= self._next_dm1:
            self._next_dm1 = max(self._next_dm1 + 1.0, now - 1.0)
            self._send_dm1()

    def _check_timeout(self, now: float) -> None:
        with self._lock:
            last = self._last_command
            if last is None or self._exit_code == 5 or now - last <= self.command_timeout_s:
                return
            self._exit_code = 5
            self._state = 0 if self._fail_safe == 0 else 3
            self._flow_pct = 0.0
        self.plant.set_output(0.0)
        self.log.output(0.0, f'command timeout ({(now - last) * 1e3:.0f} ms without '
                        'Auxiliary Valve Command): fail-safe mode')

    def _send_estimated_flow(self) -> None:
        with self._lock:
            extend = round(self._flow_pct) + 125
            data = bytes([extend, 125, 0x0C | self._fail_safe | (self._state << 4),
                          0xC0 | self._exit_code, 0x1F, 0xFF, 0xFF, 0xFF])
        self._send(_frame_id(_PRIORITY_CONTROL, 0xFE, 0x10 + self.valve_index, self.address),
                   data)

    def _send_dm1(self) -> None:
        if self.dtcs:
            lamps = 0b01 << 2          # amber warning on
            body = b''.join(bytes([spn & 0xFF, (spn >> 8) & 0xFF,
                                   ((spn >> 16) & 0x7) << 5 | fmi & 0x1F, 1])
                            for spn, fmi in self.dtcs)
        else:
            lamps, body = 0x00, b'\x00\x00\x00\x00'
        data = bytes([lamps, 0xFF]) + body
        if len(data) <= 8:
            self._send(_frame_id(_PRIORITY_INFO, 0xFE, 0xCA, self.address),
                       data.ljust(8, b'\xFF'))
            return
        self._send_bam(0xFECA, data)

    def _send_bam(self, pgn: int, data: bytes) -> None:
        """Transport protocol broadcast (J1939-21 TP.CM BAM + TP.DT), 50 ms apart."""
        packets = (len(data) + 6) // 7
        cm = bytes([32, len(data) & 0xFF, len(data) >> 8, packets, 0xFF, pgn & 0xFF,
                    (pgn >> 8) & 0xFF, pgn >> 16])
        self._send(_frame_id(7, 0xEC, _GLOBAL, self.address), cm)
        for i in range(packets):
            time.sleep(0.05)   # J1939-21: 50..200 ms between the packets of a BAM
            chunk = data[i * 7:(i + 1) * 7].ljust(7, b'\xFF')
            self._send(_frame_id(7, 0xEB, _GLOBAL, self.address), bytes([i + 1]) + chunk)


def _dtc(text: str) -> tuple[int, int]:
    spn, _, fmi = text.partition(':')
    try:
        return int(spn, 0), int(fmi or '31', 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f'--dtc {text!r}: SPN:FMI, e.g. 1907:5') from None


def build_parser() -> argparse.ArgumentParser:
    """The command-line interface."""
    p = device_parser(PROG, __doc__)
    p.add_argument('--source-address', type=int, default=0xF0,
                   help='address the valve claims (default 240)')
    p.add_argument('--name', type=lambda s: int(s, 0), default=DEFAULT_NAME,
                   help='64-bit NAME (default 0x%016X)' % DEFAULT_NAME)
    p.add_argument('--valve-index', type=int, default=0, help='auxiliary valve n, 0..15')
    p.add_argument('--command-timeout-ms', type=float, default=300.0,
                   help='no command this long: fail-safe mode (default 300 ms)')
    p.add_argument('--pwm-frequency-hz', type=float, default=50.0,
                   help='PWM frequency of the valve driver [Hz]')
    p.add_argument('--dtc', type=_dtc, action='append', default=[], metavar='SPN:FMI',
                   help='an active DTC reported in DM1 (repeatable)')
    return p


def main(args: list[str] | None = None) -> None:
    opts = build_parser().parse_args(args)
    if not 0 <= opts.valve_index <= 15:
        build_parser().error(f'--valve-index {opts.valve_index} outside 0..15')
    serve(PROG, opts, lambda bus: J1939Device(
        bus, ValvePlant(opts.pwm_frequency_hz, opts.params_file), opts.source_address,
        opts.valve_index, opts.name, opts.command_timeout_ms / 1000.0, tuple(opts.dtc)),
        f'address {opts.source_address} valve {opts.valve_index}')


if __name__ == '__main__':
    main()
