"""valve_canopen_device: a CiA 401 I/O module with the valve model behind its PWM output.

Written from CiA 301 (communication) and CiA 401 (generic I/O modules), on ``canopen``'s
local node (object dictionary from the EDS, SDO server). What it does, as a module of this
class does:

* **Boot**: sends the boot-up frame (0x700 + id, data 0x00) and enters pre-operational;
  NMT *reset node* restores the object dictionary's defaults and boots again, *reset
  communication* boots again keeping the application objects.
* **NMT**: *start* -> operational (PDOs run); *stop* / *pre-operational* -> the outputs
  take their error behaviour (below); the heartbeat (0x1017, ms) carries the state.
* **PDO mapping** (CiA 301): a mapping entry (0x1600/0x1A00 sub 1..4) may be written only
  while the PDO is disabled (COB-ID bit 31 set) and its count (sub 0) is 0, else SDO abort
  0x08000022; an object that does not exist or cannot be mapped: 0x06020000 / 0x06040041;
  more than 64 bits: 0x06040042. Enabling the PDO (bit 31 clear) takes the mapping in.
* **RPDO1** (operational only): the mapped objects are written; analog output 1
  (0x6411 sub 1, per mille) is the PWM duty of the valve, digital output 1 bit 0
  (0x6200 sub 1) gates it when mapped.
* **TPDO1** (operational): every event-timer period (0x1800 sub 5, ms; 100 ms if 0) the
  mapped objects; analog input 1 (0x6401 sub 1) is the coil current in mA.
* **Heartbeat consumer** (0x1016 sub 1: node id << 16 | time ms): armed by the first
  heartbeat of that node; when it then misses the time, the module sends EMCY 0x8130
  (life guard / heartbeat error), enters pre-operational and sets every output to its
  error value where its error mode says so (0x6443 = 1 -> 0x6444, per mille; 0x6206 bit
  set -> 0x6207 bit). The next heartbeat ends the error (EMCY 0x0000). The error register
  (0x1001) carries the generic and communication bits while the error lasts.

Every change of the output prints ``valve_canopen_device: output duty D at monotonic T:
REASON`` (CLOCK_MONOTONIC), which the tests and the fail-safe table read.
"""
from __future__ import annotations

import argparse
import logging
import struct
import threading
import time

import can
import canopen
from canopen.sdo.exceptions import SdoAbortedError

from valve_driver_pkg.devices.canopen_mapping import default_eds_path
from valve_driver_pkg.standins.common import DeviceLoop, OutputLog, device_parser, serve
from valve_driver_pkg.standins.plant import ValvePlant

__all__ = ['CanopenDevice', 'main', 'build_parser']

logger = logging.getLogger(__name__)
PROG = 'valve_canopen_device'

_OPERATIONAL, _PRE_OPERATIONAL, _STOPPED = 'OPERATIONAL', 'PRE-OPERATIONAL', 'STOPPED'
_ABORT_STATE = 0x08000022      # data cannot be transferred: present device state
_ABORT_NOT_MAPPABLE = 0x06040041
_ABORT_NO_OBJECT = 0x06020000
_ABORT_PDO_LENGTH = 0x06040042
_TICK_S = 0.001


class CanopenDevice:
    """The module on a bus (see the module docstring).

    Parameters
    ----------
    bus : can.BusABC
    node_id : int
    eds_file : str
        The object dictionary (default: the suite's generic CiA 401 EDS).
    plant : ValvePlant
        The valve behind analog output 1.
    """

    def __init__(self, bus: can.BusABC, node_id: int, plant: ValvePlant,
                 eds_file: str = '', log: OutputLog | None = None) -> None:
        self.node_id = node_id
        self.plant = plant
        self.log = log or OutputLog(PROG)
        self.network = canopen.Network(bus)
        self.node = canopen.LocalNode(node_id, str(eds_file or default_eds_path()))
        self.network.add_node(self.node)
        self.node.add_write_callback(self._on_sdo_write)
        self.network.subscribe(0x000, self._on_nmt)
        self._lock = threading.RLock()
        self._rpdo_id: int | None = None
        self._rpdo_map: list[tuple[int, int, int]] = []
        self._tpdo_id: int | None = None
        self._tpdo_map: list[tuple[int, int, int]] = []
        self._consumer: tuple[int, float] = (0, 0.0)    # host node id, timeout s
        self._host_seen: float | None = None
        self._comm_error = False
        self._next_tpdo = 0.0
        self._subscribed_host = 0
        self._loop = DeviceLoop(self.network.bus, self.network.listeners, self._tick, _TICK_S,
                                'canopen_device')
        self.rpdo_count = 0

    # --- life --------------------------------------------------------------------------------
    def start(self) -> None:
        self._loop.start()
        self._boot(reset_application=True)

    def stop(self) -> None:
        self._loop.stop()
        self.node.nmt.stop_heartbeat()

    def _boot(self, reset_application: bool) -> None:
        """Power-on / reset: defaults, boot-up frame, pre-operational."""
        with self._lock:
            if reset_application:
                self.node.data_store.clear()
            else:
                for index in [i for i in self.node.data_store if i < 0x2000]:
                    del self.node.data_store[index]
            self._comm_error = False
            self._host_seen = None
            self._read_consumer()
            self._rpdo_id, self._rpdo_map = self._pdo(0x1400, 0x1600)
            self._tpdo_id, self._tpdo_map = self._pdo(0x1800, 0x1A00)
            if self._rpdo_id is not None:
                self.network.subscribe(self._rpdo_id, self._on_rpdo)
        self.node.nmt.send_command(0x81)      # initialising: sends the boot-up frame
        self.node.nmt.send_command(0x80)      # pre-operational: heartbeat from 0x1017
        self.log.note('boot-up sent')
        self._update_output('boot')

    # --- object dictionary helpers -----------------------------------------------------------
    def _get(self, index: int, sub: int) -> int:
        obj = self.node.object_dictionary[index]
        var = obj if isinstance(obj, canopen.objectdictionary.ODVariable) else obj[sub]
        return var.decode_raw(self.node.get_data(index, sub))

    def _set(self, index: int, sub: int, value: int) -> None:
        obj = self.node.object_dictionary[index]
        var = obj if isinstance(obj, canopen.objectdictionary.ODVariable) else obj[sub]
        self.node.data_store.setdefault(index, {})[sub] = var.encode_raw(value)

    def _pdo(self, comm: int, mapping: int) -> tuple[int | None, list[tuple[int, int, int]]]:
        cob = self._get(comm, 1)
        if cob & 0x8000_0000:
            return None, []
        entries = []
        for sub in range(1, self._get(mapping, 0) + 1):
            entry = self._get(mapping, sub)
            entries.append((entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF))
        return cob & 0x7FF, entries

    def _read_consumer(self) -> None:
        value = self._get(0x1016, 1)
        self._consumer = ((value >> 16) & 0x7F, (value & 0xFFFF) / 1000.0)

    # --- SDO writes (CiA 301 rules) ----------------------------------------------------------
    def _on_sdo_write(self, index: int, subindex: int, od, data: bytes, **_) -> None:
        with self._lock:
            if index in (0x1600, 0x1A00):
                self._check_mapping_write(index, subindex, data)
            elif index in (0x1400, 0x1800) and subindex == 1:
                cob = struct.unpack('<I', data)[0]
                if not cob & 0x8000_0000:      # enable: take the mapping in
                    self._enable_pdo(index, cob)
                elif index == 0x1400:
                    self._rpdo_id, self._rpdo_map = None, []
                else:
                    self._tpdo_id, self._tpdo_map = None, []
            elif index == 0x1016:
                value = struct.unpack('<I', data)[0]
                self._consumer = ((value >> 16) & 0x7F, (value & 0xFFFF) / 1000.0)
                self._host_seen = None
        if index in (0x6411, 0x6200, 0x6443, 0x6444, 0x6206, 0x6207):
            threading.Timer(0.0, self._update_output, args=('SDO write',)).start()

    def _check_mapping_write(self, index: int, sub: int, data: bytes) -> None:
        comm = 0x1400 if index == 0x1600 else 0x1800
        if not self._get(comm, 1) & 0x8000_0000:
            raise SdoAbortedError(_ABORT_STATE)        # PDO valid: mapping is frozen
        if sub == 0:
            count = data[0]
            total = sum(self._get(index, s) & 0xFF for s in range(1, count + 1))
            if count > 4 or total > 64:
                raise SdoAbortedError(_ABORT_PDO_LENGTH)
            return
        if self._get(index, 0) != 0:
            raise SdoAbortedError(_ABORT_STATE)        # count must be 0 while entries change
        entry = struct.unpack('<I', data)[0]
        obj_index, obj_sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
        od = self.node.object_dictionary
        if obj_index not in od:
            raise SdoAbortedError(_ABORT_NO_OBJECT)
        obj = od[obj_index]
        var = obj if isinstance(obj, canopen.objectdictionary.ODVariable) else (
            obj[obj_sub] if obj_sub in obj else None)
        if var is None or not var.pdo_mappable or len(var) != bits:
            raise SdoAbortedError(_ABORT_NOT_MAPPABLE)

    def _enable_pdo(self, comm: int, cob: int) -> None:
        mapping = 0x1600 if comm == 0x1400 else 0x1A00
        entries = []
        for sub in range(1, self._get(mapping, 0) + 1):
            entry = self._get(mapping, sub)
            entries.append((entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF))
        if comm == 0x1400:
            self._rpdo_id, self._rpdo_map = cob & 0x7FF, entries
            self.network.subscribe(cob & 0x7FF, self._on_rpdo)
        else:
            self._tpdo_id, self._tpdo_map = cob & 0x7FF, entries

    # --- bus ---------------------------------------------------------------------------------
    def _on_nmt(self, can_id: int, data: bytes, timestamp: float) -> None:
        if len(data) < 2 or data[1] not in (0, self.node_id):
            return
        command = data[0]
        if command in (0x81, 0x82):
            self.log.note(f'NMT reset {"node" if command == 0x81 else "communication"}')
            threading.Timer(0.0, self._boot, args=(command == 0x81,)).start()
            return
        self._update_output(f'NMT 0x{command:02X}')

    def _on_rpdo(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self._lock:
            if can_id != self._rpdo_id or self.node.nmt.state != _OPERATIONAL:
                return
            offset = 0
            for index, sub, bits in self._rpdo_map:
                size = bits // 8
                if offset + size > len(data):
                    return            # PDO length error: not processed
                self.node.data_store.setdefault(index, {})[sub] = bytes(data[offset:offset + size])
                offset += size
            self.rpdo_count += 1
        self._update_output('RPDO1')

    def _on_heartbeat(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self._lock:
            self._host_seen = time.monotonic()
            recovered, self._comm_error = self._comm_error, False
        if recovered:
            self.node.emcy.send(0x0000, self._error_register())
            self.log.note('host heartbeat back')
            self._update_output('heartbeat back')

    def _error_register(self) -> int:
        """The error register (0x1001, CiA 301): generic and communication bits while the
        heartbeat consumer's error lasts; kept in the dictionary, readable by SDO."""
        register = 0x11 if self._comm_error else 0x00
        self._set(0x1001, 0, register)
        return register

    # --- the output --------------------------------------------------------------------------
    def _gate_mapped(self) -> bool:
        return any(index == 0x6200 for index, _, _ in self._rpdo_map)

    def _update_output(self, reason: str) -> None:
        """Analog output 1 -> the valve; the error behaviour when not operational."""
        with self._lock:
            operational = self.node.nmt.state == _OPERATIONAL and not self._comm_error
            analog = self._get(0x6411, 1)
            gate = bool(self._get(0x6200, 1) & 1) if self._gate_mapped() else True
            if not operational:
                if self._get(0x6443, 1) == 1:
                    analog = self._get(0x6444, 1)
                if self._get(0x6206, 1) & 1:
                    gate = bool(self._get(0x6207, 1) & 1)
                reason += ' (error behaviour: not operational)' if not self._comm_error \
                    else ' (error behaviour: heartbeat consumer timeout)'
            duty = min(max(analog / 1000.0, 0.0), 1.0) if gate else 0.0
        self.plant.set_output(duty)
        self.log.output(duty, reason)

    def _tick(self, now: float) -> None:
        host, timeout = self._consumer
        if host != self._subscribed_host:
            if self._subscribed_host:
                self.network.unsubscribe(0x700 + self._subscribed_host, self._on_heartbeat)
            if host:
                self.network.subscribe(0x700 + host, self._on_heartbeat)
            self._subscribed_host = host
        self._check_consumer(now, host, timeout)
        reading = self.plant.read()
        current_ma = max(-32768, min(32767, round(reading.coil_current_a * 1000.0)))
        self._set(0x6401, 1, current_ma)
        self._send_tpdo(now)

    def _check_consumer(self, now: float, host: int, timeout: float) -> None:
        with self._lock:
            seen = self._host_seen
            if not host or timeout <= 0.0 or seen is None or self._comm_error \
                    or now - seen <= timeout:
                return
            self._comm_error = True
        self.log.note(f'heartbeat consumer timeout: node {host} silent for '
                      f'{(now - seen) * 1e3:.0f} ms (limit {timeout * 1e3:.0f} ms)')
        self._update_output('heartbeat consumer timeout')
        self.node.emcy.send(0x8130, self._error_register())
        self.node.nmt.send_command(0x80)

    def _send_tpdo(self, now: float) -> None:
        with self._lock:
            if self._tpdo_id is None or self.node.nmt.state != _OPERATIONAL \
                    or now < self._next_tpdo:
                return
            period = (self._get(0x1800, 5) or 100) / 1000.0
            self._next_tpdo = max(self._next_tpdo + period, now - period)
            data = b''.join(self.node.get_data(index, sub) for index, sub, _ in self._tpdo_map)
            cob = self._tpdo_id
        try:
            self.network.send_message(cob, data)
        except can.CanError:
            pass


def build_parser() -> argparse.ArgumentParser:
    """The command-line interface."""
    p = device_parser(PROG, __doc__)
    p.add_argument('--node-id', type=int, default=5, help='CANopen node id 1..127 (default 5)')
    p.add_argument('--eds', default='', help='EDS file (default: the generic CiA 401 EDS)')
    p.add_argument('--pwm-frequency-hz', type=float, default=50.0,
                   help='PWM frequency of the output [Hz] (the module\'s own setting)')
    return p


def main(args: list[str] | None = None) -> None:
    opts = build_parser().parse_args(args)
    if not 1 <= opts.node_id <= 127:
        build_parser().error(f'--node-id {opts.node_id} outside 1..127')
    serve(PROG, opts, lambda bus: CanopenDevice(
        bus, opts.node_id, ValvePlant(opts.pwm_frequency_hz, opts.params_file), opts.eds),
        f'node {opts.node_id}')


if __name__ == '__main__':
    main()
