"""J1939 / ISO 11783-7 auxiliary valve for valve_can_driver, on the ``can-j1939`` stack.

The host is a controller application of ``can-j1939`` (address claim after J1939-81 with
``j1939.name`` for ``j1939.source_address``; transport protocol, so a DM1 of several DTCs
arrives whole). The stack sends through the driver's bus and is fed by the driver's one
receive thread (``ElectronicControlUnit.notify``), so it runs on any bus of the suite's
factory.

* **Configure**: the address is claimed; configure fails if it cannot be.
* **Commands**: Auxiliary Valve Command (PGN 65072 + ``valve_index``) every
  ``command_period_ms`` and at once on a change: duty 0..1 -> port flow 0..100 % in both
  resolutions, state extend (1), or block (0) at duty 0; fail-safe mode block.
* **Receive**: Auxiliary Valve Estimated Flow (PGN 65040 + n) is the device's liveness
  (100 ms) and the state: ``duty`` = extend port flow / 100, the opening in force as the
  device reports it; coil current and voltage NaN. DM1 (PGN 65226) of the valve's source
  address -> faults by SPN and FMI. An Address Claimed of another NAME for our address:
  if its NAME wins (lower), the claim is lost and reported (CAN bus ERROR).
* **Clear faults**: a Request for DM11 (clear active DTCs) to the valve's address; the
  valve's Acknowledgment and its next DM1 say what is left.
"""
from __future__ import annotations

import logging
import threading
import time

import can
import j1939

from valve_driver_pkg.devices.base import DeviceFault, DeviceProtocol, DeviceReading, FrameOutcome
from valve_driver_pkg.devices.j1939_codec import (PGN_ACKNOWLEDGMENT, PGN_ADDRESS_CLAIMED,
                                                  PGN_DM1, PGN_DM11, PGN_ESTIMATED_FLOW,
                                                  PGN_VALVE_COMMAND, STATE_EXTEND,
                                                  DiagnosticMessage, decode_dm1,
                                                  decode_estimated_flow, encode_valve_command,
                                                  request_frame, split_id)
from valve_driver_pkg.driver.core_base import ClearResult
from valve_driver_pkg.errors import DeviceSetupError, MappingError

__all__ = ['J1939Protocol', 'ESTIMATED_FLOW_PERIOD_S']

logger = logging.getLogger(__name__)

#: Estimated Flow repetition (ISO 11783-7: 100 ms): the device's liveness period [s].
ESTIMATED_FLOW_PERIOD_S = 0.1
#: DM1 repetition (J1939-73: once a second): a clear is judged on the DM1 after it [s].
DM1_PERIOD_S = 1.0
_ACK_NAMES = {0: 'ACK', 1: 'NACK', 2: 'access denied', 3: 'cannot respond'}


class J1939Protocol(DeviceProtocol):
    """An auxiliary valve over J1939 (see the module docstring).

    Parameters
    ----------
    source_address : int
        The address the host claims, 0..253.
    name : int
        The host's 64-bit NAME.
    valve_index : int
        Auxiliary valve n, 0..15.
    command_period_s : float
        Command period [s].
    """

    name = 'j1939'
    clear_timeout_s = 2.5 * DM1_PERIOD_S

    def __init__(self, source_address: int, name: int, valve_index: int,
                 command_period_s: float) -> None:
        if not 0 <= valve_index <= 15 or not 0 <= source_address <= 253:
            raise MappingError(f'j1939: valve_index {valve_index} (0..15), source_address '
                               f'{source_address} (0..253)')
        super().__init__(f'j1939 valve {valve_index}', command_period_s,
                         ESTIMATED_FLOW_PERIOD_S)
        self.source_address = source_address
        self.name_value = name
        self.valve_index = valve_index
        self._lock = threading.Lock()
        self._dm1_arrived = threading.Condition(self._lock)
        self.dm1_count = 0
        self.last_ack: tuple[int, int] | None = None   # (control byte, PGN) of the last one
        self._ecu: j1939.ElectronicControlUnit | None = None
        self._ca: j1939.ControllerApplication | None = None
        self.device_address: int | None = None
        self.claim_lost = ''
        self.dm1: DiagnosticMessage | None = None
        self.last_flow = None

    # --- DeviceProtocol ----------------------------------------------------------------------
    def attach(self, send, bus: can.BusABC | None) -> None:
        super().attach(send, bus)
        if self._ecu is None:
            self._ecu = j1939.ElectronicControlUnit(send_message=self._ecu_send)
            self._ca = j1939.ControllerApplication(j1939.Name(value=self.name_value),
                                                   self.source_address)
            self._ecu.add_ca(controller_application=self._ca)
            self._ecu.subscribe(self._on_pgn)

    def _ecu_send(self, can_id: int, extended_id: bool, data, fd_format: bool = False) -> None:
        self._send(can.Message(arbitration_id=can_id, is_extended_id=extended_id,
                               data=bytes(data)))

    def setup(self, timeout_s: float) -> None:
        ca = self._ca
        with self._lock:
            self.claim_lost = ''
        ca.start()
        deadline = time.monotonic() + timeout_s
        while ca.state != j1939.ControllerApplication.State.NORMAL:
            if ca.state == j1939.ControllerApplication.State.CANNOT_CLAIM or \
                    time.monotonic() >= deadline:
                raise DeviceSetupError(f'j1939: cannot claim address {self.source_address} '
                                       f'with NAME 0x{self.name_value:016X}')
            time.sleep(0.01)
        logger.info('j1939: address %d claimed (NAME 0x%016X)', ca.device_address,
                    self.name_value)

    def command_frames(self, duty: float, enable: bool) -> list[can.Message]:
        ca = self._ca
        if ca is None or ca.state != j1939.ControllerApplication.State.NORMAL or self.claim_lost:
            return []
        can_id, data = encode_valve_command(self.valve_index, ca.device_address,
                                            duty if enable else 0.0)
        return [can.Message(arbitration_id=can_id, is_extended_id=True, data=data)]

    def decode_command(self, msg: can.Message) -> float | None:
        if not msg.is_extended_id:
            return None
        _, pgn, _, _ = split_id(msg.arbitration_id)
        data = bytes(msg.data)
        if pgn != PGN_VALVE_COMMAND + self.valve_index or len(data) < 5:
            return None
        if data[2] & 0x0F != STATE_EXTEND:
            return 0.0
        if data[1] & 3 == 1 and data[3:5] != b'\xff\xff':
            return int.from_bytes(data[3:5], 'little') * 0.0015625 / 100.0
        return data[0] * 0.4 / 100.0 if data[0] <= 250 else None

    def on_frame(self, msg: can.Message) -> FrameOutcome:
        if msg.is_error_frame or msg.is_remote_frame or not msg.is_extended_id:
            return FrameOutcome()
        data = bytes(msg.data)
        if self._ecu is not None:
            self._ecu.notify(msg.arbitration_id, data, msg.timestamp)
        _, pgn, source, _ = split_id(msg.arbitration_id)
        if pgn == PGN_ADDRESS_CLAIMED:
            self._on_claim(source, data)
            return FrameOutcome()
        if pgn == PGN_ACKNOWLEDGMENT and source == self.device_address and len(data) >= 8:
            with self._lock:
                self.last_ack = (data[0], int.from_bytes(data[5:8], 'little'))
                self._dm1_arrived.notify_all()
        if pgn != PGN_ESTIMATED_FLOW + self.valve_index:
            return FrameOutcome(from_device=source == self.device_address)
        flow = decode_estimated_flow(data)
        if flow is None:
            return FrameOutcome()
        with self._lock:
            self.device_address = source
            self.last_flow = flow
        return FrameOutcome(from_device=True,
                            reading=DeviceReading(duty=flow.extend_pct / 100.0))

    def _on_claim(self, source: int, data: bytes) -> None:
        ca = self._ca
        if ca is None or len(data) < 8 or source != self.source_address:
            return
        theirs = int.from_bytes(data[:8], 'little')
        if theirs < self.name_value:
            text = (f'address claim lost: address {source} claimed by NAME 0x{theirs:016X} '
                    f'(ours 0x{self.name_value:016X} loses); not commanding')
            with self._lock:
                first = not self.claim_lost
                self.claim_lost = text
            if first:
                logger.error('j1939: %s', text)

    def _on_pgn(self, priority: int, pgn: int, sa: int, timestamp: float, data) -> None:
        """Reassembled messages from the stack (DM1 of one or several DTCs)."""
        if pgn != PGN_DM1:
            return
        with self._lock:
            if self.device_address is not None and sa != self.device_address:
                return
            self.dm1 = decode_dm1(bytes(data))
            self.dm1_count += 1
            self._dm1_arrived.notify_all()

    def faults(self) -> list[DeviceFault]:
        with self._lock:
            dm1 = self.dm1
        if dm1 is None or not dm1.dtcs:
            return []
        severe = dm1.red_stop == 1 or dm1.mil == 1
        named = (('red stop', dm1.red_stop), ('amber warning', dm1.amber), ('MIL', dm1.mil),
                 ('protect', dm1.protect))
        lamps = ', '.join(n for n, v in named if v == 1)
        return [DeviceFault(f'DM1 {dtc.text}' + (f'; lamps: {lamps}' if lamps else ''),
                            error=severe, values={'dm1_dtcs': ','.join(
                                f'{d.spn}:{d.fmi}' for d in dm1.dtcs)})
                for dtc in dm1.dtcs]

    def clear_faults(self, timeout_s: float) -> ClearResult:
        """DM11 (clear active DTCs) asked of the valve by a Request; the valve's
        Acknowledgment and its next DM1 say what was cleared and what is left."""
        ca = self._ca
        with self._lock:
            address = self.device_address
            count, self.last_ack = self.dm1_count, None
        before = tuple(f.text for f in self.faults())
        if address is None or ca is None or ca.state != j1939.ControllerApplication.State.NORMAL:
            return ClearResult(False, (), before, 'not cleared: no claimed address of ours or '
                               'no valve heard yet')
        can_id, data = request_frame(PGN_DM11, ca.device_address, address)
        if not self._send(can.Message(arbitration_id=can_id, is_extended_id=True, data=data)):
            return ClearResult(False, (), before, 'not cleared: the DM11 request could not be '
                               'sent (bus down?)')
        with self._lock:
            answered = self._dm1_arrived.wait_for(
                lambda: self.dm1_count > count or (self.last_ack is not None
                                                   and self.last_ack[0] != 0), timeout_s)
            ack = self.last_ack
        if ack is not None and ack[0] != 0:
            return ClearResult(False, (), before, f'j1939 valve at address {address} refused '
                               f'DM11: {_ACK_NAMES.get(ack[0], f"control byte {ack[0]}")}')
        if not answered:
            return ClearResult(False, (), before, f'DM11 sent, but no DM1 from the valve '
                               f'within {timeout_s:g} s')
        result = ClearResult.judged(f'DM11 to address {address}', before,
                                    tuple(f.text for f in self.faults()))
        logger.info('clear faults: %s', result.message)
        return result

    def bus_problem(self) -> str:
        with self._lock:
            if self.claim_lost:
                return self.claim_lost
        ca = self._ca
        if ca is not None and ca.state == j1939.ControllerApplication.State.CANNOT_CLAIM:
            return f'cannot claim address {self.source_address}'
        return ''

    def describe(self) -> dict:
        with self._lock:
            flow = self.last_flow
            return {'source_address': self.source_address,
                    'name': f'0x{self.name_value:016X}', 'valve_index': self.valve_index,
                    'device_address': '' if self.device_address is None
                    else self.device_address,
                    'valve_state': '' if flow is None else flow.state,
                    'exit_code': '' if flow is None else flow.exit_code}

    def close(self) -> None:
        ecu, self._ecu = self._ecu, None
        if ecu is not None:
            ecu.stop()
        self._ca = None
