"""CANopen (CiA 301 + CiA 401) for valve_can_driver: set-up by SDO, RPDO commands, TPDO in.

The host is a CANopen node (``host_node_id``, default 127) on the driver's bus, which is
handed to ``canopen.Network``; the driver's one receive thread feeds the network
(``Network.notify``), so the ``canopen`` package's SDO client works on any bus of the
suite's factory, ``tcp_loopback`` included.

**Set-up** (configure, and again whenever the device sends a boot-up frame), never
trusting what the device stored:

1. NMT *enter pre-operational*, then the device type (0x1000) read by SDO until it answers
   (bounded by the set-up timeout, the SDO retried every ``sdo_timeout_s``);
2. RPDO1 and TPDO1 re-mapped by CiA 301's procedure: the PDO disabled (COB-ID bit 31 set),
   the mapping count set to 0, the entries written, the count written, the PDO enabled
   again (COB-ID 0x200/0x180 + node id); RPDO1 transmission type 255 (acted on at once),
   TPDO1 transmission type 255 with its event timer at the command period;
3. the device's heartbeat consumer 0x1016 sub 1 = host node id and 3 host heartbeat
   periods, its own heartbeat producer 0x1017 = ``heartbeat_ms``;
4. the output error mode and value (0x6443 = 1 / 0x6444 = 0, INTEGER32, for an analog
   output; 0x6206 = 0xFF / 0x6207 = 0 for a digital one; or the mapping's ``fail_safe``),
   so the device switches the output off itself when the host falls silent.

An SDO abort fails the set-up naming the object and the abort code (CiA 301).

**Activate**: NMT *start*; the host's heartbeat (0x700 + host id, state operational)
every ``heartbeat_ms`` from then on; RPDO1 with the duty (and the enable) every command
period and at once on a change.

**Receive**: TPDO1 -> coil current (and position); EMCY (0x080 + id) -> faults by name
until the device sends the EMCY "error reset" (0x0000); heartbeat (0x700 + id) -> the
device's NMT state and liveness; a boot-up frame -> set up again (without a restart of the
node) and, if active, NMT start.
"""
from __future__ import annotations

import logging
import math
import queue
import struct
import threading
import time

import can
import canopen
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from valve_driver_pkg.devices.base import DeviceFault, DeviceProtocol, DeviceReading, FrameOutcome
from valve_driver_pkg.devices.canopen_mapping import (CanopenMapping, ObjectRef,
                                                      fail_safe_writes, pdo_entry)
from valve_driver_pkg.driver.core_base import ClearResult
from valve_driver_pkg.errors import DeviceSetupError, MappingError, SdoAbortError

__all__ = ['CanopenProtocol', 'EMCY_NAMES', 'NMT_STATES', 'ERROR_REGISTER_BITS', 'emcy_name',
           'sdo_abort_text']

logger = logging.getLogger(__name__)

#: NMT states in heartbeat frames (CiA 301).
NMT_STATES = {0x00: 'boot-up', 0x04: 'stopped', 0x05: 'operational', 0x7F: 'pre-operational'}
#: NMT command specifiers (CiA 301).
_NMT_START, _NMT_PRE_OPERATIONAL, _NMT_RESET_COMMUNICATION = 0x01, 0x80, 0x82
#: CiA 301 error register (0x1001) bits.
ERROR_REGISTER_BITS = ('generic', 'current', 'voltage', 'temperature', 'communication',
                       'device profile', 'reserved', 'manufacturer')
#: EMCY error codes (CiA 301 table 21; CiA 401's output codes). Others by their class.
EMCY_NAMES = {
    0x0000: 'error reset or no error', 0x1000: 'generic error', 0x2000: 'current',
    0x2100: 'current, device input side', 0x2200: 'current inside the device',
    0x2300: 'current, device output side', 0x2310: 'output current too high (overload)',
    0x2320: 'short circuit at the output', 0x2330: 'load dump at the output',
    0x3000: 'voltage', 0x3100: 'mains voltage', 0x3110: 'mains overvoltage',
    0x3120: 'mains undervoltage', 0x3200: 'voltage inside the device', 0x3300: 'output voltage',
    0x4000: 'temperature', 0x4100: 'ambient temperature', 0x4200: 'device temperature',
    0x5000: 'device hardware', 0x6000: 'device software', 0x7000: 'additional modules',
    0x8000: 'monitoring', 0x8100: 'communication', 0x8110: 'CAN overrun (objects lost)',
    0x8120: 'CAN in error passive mode', 0x8130: 'life guard or heartbeat error',
    0x8140: 'recovered from bus off', 0x8150: 'CAN-ID collision',
    0x8200: 'protocol error', 0x8210: 'PDO not processed due to length error',
    0x8220: 'PDO length exceeded', 0x8250: 'RPDO timeout',
    0x9000: 'external error', 0xF000: 'additional functions', 0xFF00: 'device specific',
}
_HOST_HEARTBEAT_CONSUMER_PERIODS = 3


def emcy_name(code: int) -> str:
    """The CiA 301 name of an EMCY error code (exact, else its class)."""
    for key in (code, code & 0xFFF0, code & 0xFF00, code & 0xF000):
        if key in EMCY_NAMES:
            return EMCY_NAMES[key]
    return 'unknown'


def sdo_abort_text(code: int) -> str:
    """The CiA 301 name of an SDO abort code."""
    return SdoAbortedError.CODES.get(code, 'unknown abort code')


class _HostNetwork(canopen.Network):
    """``canopen.Network`` on the driver's bus; frames go out through the driver's send."""

    def __init__(self, bus: can.BusABC | None, send) -> None:
        super().__init__(bus)
        self._driver_send = send

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        msg = can.Message(arbitration_id=can_id, is_extended_id=can_id > 0x7FF,
                          data=bytes(data), is_remote_frame=remote)
        if not self._driver_send(msg):
            raise can.CanOperationError(f'frame 0x{can_id:03X} not sent (bus down)')


class CanopenProtocol(DeviceProtocol):
    """A CiA 401 output module driven over CANopen (see the module docstring).

    Parameters
    ----------
    node_id : int
        The device's node id, 1..127.
    host_node_id : int
        The host's node id (heartbeat producer), 1..127.
    eds_file : str
        The device's EDS (objects and types the mapping is checked against).
    mapping : CanopenMapping
    heartbeat_ms : int
        Host heartbeat period [ms]; the device's consumer gets 3 periods.
    sdo_timeout_s : float
        One SDO answer's timeout [s].
    command_period_s : float
        RPDO1 period; also TPDO1's event timer [s].

    Raises
    ------
    MappingError
        The EDS cannot be read, or a mapped object is not in it (named).
    """

    name = 'canopen'
    clear_timeout_s = 6.0      # one set-up of the device after its reset

    def __init__(self, node_id: int, host_node_id: int, eds_file: str,
                 mapping: CanopenMapping, heartbeat_ms: int, sdo_timeout_s: float,
                 command_period_s: float) -> None:
        if not 1 <= node_id <= 127 or not 1 <= host_node_id <= 127 or node_id == host_node_id:
            raise MappingError(f'canopen node ids: device {node_id}, host {host_node_id}: both '
                               'in 1..127 and different')
        super().__init__(f'canopen node {node_id}', command_period_s, heartbeat_ms / 1000.0)
        self.node_id = node_id
        self.host_node_id = host_node_id
        self.mapping = mapping
        self.measures_position = mapping.position is not None
        self.heartbeat_ms = int(heartbeat_ms)
        self.sdo_timeout_s = float(sdo_timeout_s)
        self.eds_file = eds_file
        try:
            self._od = canopen.import_od(eds_file, node_id)
        except Exception as err:   # noqa: BLE001 - canopen raises many kinds on a bad file
            raise MappingError(f'{eds_file}: cannot read the EDS: {err}') from err
        self._check_against_eds()
        self._fail_safe = fail_safe_writes(mapping)
        self._lock = threading.Lock()
        self._setup_done = threading.Condition(self._lock)
        self._network = _HostNetwork(None, self._send_frame)
        self._node = canopen.RemoteNode(node_id, self._od)
        self._network.add_node(self._node)
        self._node.sdo.RESPONSE_TIMEOUT = self.sdo_timeout_s
        self._heartbeat_next = 0.0
        self._setting_up = False
        self.device_state = 'unknown'
        self._emcy: dict[int, tuple[int, bytes]] = {}     # code -> (error register, data)
        self.last_abort = ''
        self.setups = 0

    def _send_frame(self, msg: can.Message) -> bool:
        return self._send(msg)

    def _check_against_eds(self) -> None:
        for ref in (self.mapping.duty, self.mapping.enable, self.mapping.current,
                    self.mapping.position):
            if ref is None:
                continue
            where = f'{self.mapping.path}: role {ref.role!r}: object {ref.name}'
            obj = self._od.get(ref.index)
            if isinstance(obj, canopen.objectdictionary.ODVariable):
                var = obj if ref.subindex == 0 else None
            else:
                var = None if obj is None else obj.subindices.get(ref.subindex)
            if var is None:
                raise MappingError(f'{where} is not in the EDS {self.eds_file}')
            if not getattr(var, 'pdo_mappable', True):
                raise MappingError(f'{where} cannot be mapped to a PDO (EDS {self.eds_file})')

    # --- DeviceProtocol ----------------------------------------------------------------------
    def attach(self, send, bus: can.BusABC | None) -> None:
        super().attach(send, bus)
        self._network.bus = bus

    def setup(self, timeout_s: float) -> None:
        with self._lock:
            self._setting_up = True
        try:
            self._setup(timeout_s)
        finally:
            with self._lock:
                self._setting_up = False

    def _setup(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        self._nmt(_NMT_PRE_OPERATIONAL)
        self._wait_for_device(deadline)
        rpdo = [(0x1400, 0x1600, 0x200, self.mapping.rpdo, {2: (255, 'UNSIGNED8')})]
        event_ms = max(1, round(self.command_period_s * 1000.0))
        tpdo = [(0x1800, 0x1A00, 0x180, self.mapping.tpdo,
                 {2: (255, 'UNSIGNED8'), 5: (event_ms, 'UNSIGNED16')})]
        for comm, map_index, base, refs, extra in rpdo + (tpdo if self.mapping.tpdo else []):
            self._remap(comm, map_index, base + self.node_id, refs, extra)
        consumer_ms = _HOST_HEARTBEAT_CONSUMER_PERIODS * self.heartbeat_ms
        self._write(0x1016, 1, struct.pack('<I', (self.host_node_id << 16) | consumer_ms),
                    'heartbeat consumer')
        self._write(0x1017, 0, struct.pack('<H', self.heartbeat_ms), 'heartbeat producer')
        for write in self._fail_safe:
            self._write(write.index, write.subindex, write.pack(), 'output error mode/value')
        with self._lock:
            self.setups += 1
            self._emcy.clear()
            self.last_abort = ''
            self._setup_done.notify_all()
        logger.info('canopen node %d set up: RPDO1 %s, TPDO1 %s, consumer %d ms, %d error '
                    'mode/value writes', self.node_id,
                    ', '.join(r.name for r in self.mapping.rpdo),
                    ', '.join(r.name for r in self.mapping.tpdo) or 'none', consumer_ms,
                    len(self._fail_safe))

    def start_frames(self) -> list[can.Message]:
        self._heartbeat_next = 0.0
        return [self._nmt_frame(_NMT_START)]

    def command_frames(self, duty: float, enable: bool) -> list[can.Message]:
        data = b''.join(self._raw(ref, duty, enable) for ref in self.mapping.rpdo)
        return [can.Message(arbitration_id=0x200 + self.node_id, is_extended_id=False,
                            data=data)]

    def decode_command(self, msg: can.Message) -> float | None:
        if msg.is_extended_id or msg.arbitration_id != 0x200 + self.node_id:
            return None
        ref = self.mapping.duty
        size = ref.bits // 8
        data = bytes(msg.data)
        return ref.unpack(data[:size]) * ref.scale if len(data) >= size else None

    def own_frames(self, now: float, active: bool) -> list[can.Message]:
        """The host's heartbeat; with it, NMT start again to a device that reports itself
        pre-operational or stopped while the driver is active and not setting it up (it
        left operational on its own, e.g. after its heartbeat consumer timed out)."""
        if not active or now < self._heartbeat_next:
            return []
        self._heartbeat_next = max(self._heartbeat_next + self.heartbeat_ms / 1000.0,
                                   now - self.heartbeat_ms / 1000.0)
        frames = [can.Message(arbitration_id=0x700 + self.host_node_id, is_extended_id=False,
                              data=bytes([0x05]))]
        with self._lock:
            restart = (self.device_state in ('pre-operational', 'stopped')
                       and not self._setting_up)
        if restart:
            logger.warning('canopen node %d reports %s while active: NMT start again',
                           self.node_id, self.device_state)
            frames.append(self._nmt_frame(_NMT_START))
        return frames

    def next_own_due(self) -> float:
        return self._heartbeat_next if self._heartbeat_next > 0.0 else math.inf

    def on_frame(self, msg: can.Message) -> FrameOutcome:
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            return FrameOutcome()
        self._network.notify(msg.arbitration_id, bytes(msg.data), msg.timestamp)
        can_id, data = msg.arbitration_id, bytes(msg.data)
        if can_id & 0x7F != self.node_id or can_id < 0x080:
            return FrameOutcome()
        function = can_id & 0x780
        if function == 0x700 and data:
            state = NMT_STATES.get(data[0] & 0x7F, f'state 0x{data[0]:02X}')
            with self._lock:
                self.device_state = state
            if data[0] == 0x00:
                logger.warning('canopen node %d booted (boot-up frame): setting it up again',
                               self.node_id)
                self.needs_setup = True
            return FrameOutcome(from_device=True)
        if function == 0x080:
            self._on_emcy(data)
            return FrameOutcome(from_device=True)
        if function == 0x180 and self.mapping.tpdo:
            return FrameOutcome(from_device=True, reading=self._decode_tpdo(data))
        return FrameOutcome(from_device=True)

    def faults(self) -> list[DeviceFault]:
        with self._lock:
            emcy = dict(self._emcy)
            abort = self.last_abort
        out = [DeviceFault(f'EMCY 0x{code:04X} {emcy_name(code)} (error register '
                           f'0x{reg:02X})', values={'emcy_codes': ','.join(
                               f'0x{c:04X}' for c in emcy)})
               for code, (reg, _) in emcy.items()]
        if abort:
            out.append(DeviceFault(abort))
        return out

    def clear_faults(self, timeout_s: float) -> ClearResult:
        """NMT reset communication: the device boots, the driver sets it up again and
        starts it; then its error register (0x1001) and the EMCYs since say what is left.

        CiA 301 offers no other host request that clears a fault; a reset of the
        communication ends the device's communication errors (its heartbeat consumer's
        among them) and keeps its application. Meanwhile the output takes its error value
        (CiA 401), which de-energises the valve for about one set-up.
        """
        before = tuple(f.text for f in self.faults())
        with self._lock:
            setups = self.setups
        self._nmt(_NMT_RESET_COMMUNICATION)
        with self._lock:
            if not self._setup_done.wait_for(lambda: self.setups > setups, timeout_s):
                return ClearResult(False, (), before,
                                   f'NMT reset communication sent, but canopen node '
                                   f'{self.node_id} was not set up again within '
                                   f'{timeout_s:g} s')
        try:
            self._drop_late_answers()
            register = self._node.sdo.upload(0x1001, 0)[0]
        except (SdoCommunicationError, SdoAbortedError, can.CanError) as err:
            return ClearResult(False, (), before, f'canopen node {self.node_id} set up '
                               f'again, but its error register (0x1001) did not answer: {err}')
        still = tuple(f.text for f in self.faults())
        if register:
            bits = [name for i, name in enumerate(ERROR_REGISTER_BITS) if register >> i & 1]
            still += (f'error register 0x{register:02X} ({", ".join(bits)})',)
        result = ClearResult.judged(f'NMT reset communication: canopen node {self.node_id} '
                                    'set up again', before, still)
        logger.info('clear faults: %s', result.message)
        return result

    def describe(self) -> dict:
        with self._lock:
            return {'node_id': self.node_id, 'host_node_id': self.host_node_id,
                    'nmt_state': self.device_state, 'eds': self.eds_file,
                    'mapping': self.mapping.path, 'heartbeat_ms': self.heartbeat_ms}

    def close(self) -> None:
        self._network.bus = None

    # --- helpers -----------------------------------------------------------------------------
    def _nmt_frame(self, command: int) -> can.Message:
        return can.Message(arbitration_id=0x000, is_extended_id=False,
                           data=bytes([command, self.node_id]))

    def _nmt(self, command: int) -> None:
        self._send(self._nmt_frame(command))

    def _drop_late_answers(self) -> None:
        """Forget SDO answers that came after their request timed out (a device that was
        still booting answers the reads it got then): one of them would be taken for the
        answer to the next request ("Unexpected response"). Requests go one at a time, so
        nothing waiting before a new request belongs to it."""
        while True:
            try:
                self._node.sdo.responses.get_nowait()
            except queue.Empty:
                return

    def _wait_for_device(self, deadline: float) -> None:
        """Read the device type until the device answers (bounded, retried)."""
        last = ''
        while True:
            try:
                self._drop_late_answers()
                raw = self._node.sdo.upload(0x1000, 0)
                device_type = struct.unpack_from('<I', raw.ljust(4, b'\0'))[0]
                if device_type & 0xFFFF != 401:
                    logger.warning('canopen node %d: device type 0x%08X is not CiA 401',
                                   self.node_id, device_type)
                return
            except SdoCommunicationError as err:
                last = str(err)
            except SdoAbortedError as err:
                raise self._abort(0x1000, 0, 'device type', err) from err
            except can.CanError as err:
                last = str(err)
            if time.monotonic() >= deadline:
                raise DeviceSetupError(f'canopen node {self.node_id} does not answer (SDO '
                                       f'0x1000 read, {last or "no answer"})')
            self._nmt(_NMT_PRE_OPERATIONAL)

    def _abort(self, index: int, sub: int, what: str, err: SdoAbortedError) -> SdoAbortError:
        code = int(err.code)
        text = (f'canopen node {self.node_id} refused {what} 0x{index:04X} sub {sub}: SDO '
                f'abort 0x{code:08X} ({sdo_abort_text(code)})')
        with self._lock:
            self.last_abort = text
        return SdoAbortError(code, text)

    def _write(self, index: int, sub: int, data: bytes, what: str) -> None:
        try:
            self._drop_late_answers()
            self._node.sdo.download(index, sub, data)
        except SdoAbortedError as err:
            raise self._abort(index, sub, what, err) from err
        except (SdoCommunicationError, can.CanError) as err:
            raise DeviceSetupError(f'canopen node {self.node_id}: no answer writing {what} '
                                   f'0x{index:04X} sub {sub}: {err}') from err

    def _remap(self, comm: int, map_index: int, cob_id: int, refs: tuple[ObjectRef, ...],
               extra: dict[int, tuple[int, str]]) -> None:
        """CiA 301's PDO re-mapping: disable, count 0, entries, count, parameters, enable."""
        what = f'PDO 0x{comm:04X}/0x{map_index:04X}'
        self._write(comm, 1, struct.pack('<I', cob_id | 0x8000_0000), f'{what} disable')
        self._write(map_index, 0, b'\x00', f'{what} mapping count 0')
        for i, ref in enumerate(refs, start=1):
            self._write(map_index, i, struct.pack('<I', pdo_entry(ref)),
                        f'{what} entry {i} ({ref.role} {ref.name})')
        self._write(map_index, 0, bytes([len(refs)]), f'{what} mapping count')
        for sub, (value, kind) in extra.items():
            fmt = '<B' if kind == 'UNSIGNED8' else '<H'
            self._write(comm, sub, struct.pack(fmt, value), f'{what} sub {sub}')
        self._write(comm, 1, struct.pack('<I', cob_id), f'{what} enable')

    @staticmethod
    def _raw(ref: ObjectRef, duty: float, enable: bool) -> bytes:
        lo, hi = ref.limits()
        if ref.role == 'enable':
            return ref.pack(ref.on_value if enable and duty > 0.0 else 0)
        value = round((duty if enable else 0.0) / ref.scale)
        return ref.pack(min(max(value, lo), hi))

    def _decode_tpdo(self, data: bytes) -> DeviceReading | None:
        values = {}
        offset = 0
        for ref in self.mapping.tpdo:
            size = ref.bits // 8
            if offset + size > len(data):
                return None
            values[ref.role] = ref.unpack(data[offset:offset + size]) * ref.scale
            offset += size
        return DeviceReading(coil_current_a=values.get('current', math.nan),
                             spool_position_m=values.get('position', math.nan))

    def _on_emcy(self, data: bytes) -> None:
        if len(data) < 3:
            return
        code = data[0] | (data[1] << 8)
        with self._lock:
            if code == 0x0000:
                self._emcy.clear()
            else:
                self._emcy[code] = (data[2], data[3:8])
        if code:
            logger.error('canopen node %d EMCY 0x%04X: %s', self.node_id, code, emcy_name(code))
        else:
            logger.info('canopen node %d EMCY error reset', self.node_id)
