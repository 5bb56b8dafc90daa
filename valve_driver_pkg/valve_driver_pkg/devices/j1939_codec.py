"""SAE J1939 / ISO 11783-7 auxiliary valve messages: ids, command, Estimated Flow, DM1.

Pure functions (no bus), shared by the driver's protocol and nothing else; the stand-in
device reads the same messages with code of its own.

* 29-bit id (J1939-21): priority (3 bits) | data page | PDU format | PDU specific | source.
* **Auxiliary Valve Command**, PGN 65072 + n (PF 254, PS 0x30 + n), priority 3, every
  100 ms when active (ISO 11783-7): byte 1 port flow 0.4 %/bit (0..250 = 0..100 %);
  byte 2 bits 1-2 resolution mode (01: extended and standard resolution valid); byte 3
  bits 1-4 state (0 block, 1 extend, 2 retract, 3 float), bits 7-8 fail-safe mode
  (00 block, 01 float); bytes 4-5 port flow, extended resolution, 0.0015625 %/bit
  (0..64000 = 0..100 %), little-endian. Unused bits are 1.
* **Auxiliary Valve Estimated Flow**, PGN 65040 + n: byte 1 extend port flow, byte 2
  retract port flow, 1 %/bit, offset -125 % (0xFB..0xFF: error / not available); byte 3
  bits 1-2 fail-safe mode, bits 5-8 valve state; byte 4 bits 1-6 exit/reason code.
* **DM1**, PGN 65226 (J1939-73): byte 1 lamps (protect 1-2, amber 3-4, red stop 5-6,
  MIL 7-8), byte 2 their flashing, then per active DTC 4 bytes: SPN (19 bits: byte 3,
  byte 4, byte 5 bits 6-8), FMI (byte 5 bits 1-5), occurrence count (byte 6 bits 1-7).
  SPN 0 / FMI 0 means no active DTC.
* **Address Claimed**, PGN 60928 (J1939-81): the 8-byte NAME, little-endian.
* **Request**, PGN 59904 (J1939-21, destination specific): the requested PGN in 3 bytes,
  little-endian; a Request for **DM11** (PGN 65235) asks the device to clear its active
  DTCs (J1939-73), which it answers with an **Acknowledgment** (PGN 59392: control byte
  0 ACK, 1 NACK, 2 access denied, 3 cannot respond; bytes 6-8 the PGN).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ['PGN_VALVE_COMMAND', 'PGN_ESTIMATED_FLOW', 'PGN_DM1', 'PGN_ADDRESS_CLAIMED',
           'PGN_REQUEST', 'PGN_DM11', 'PGN_ACKNOWLEDGMENT', 'request_frame', 'STATE_BLOCK',
           'STATE_EXTEND', 'FMI_NAMES', 'make_id', 'split_id',
           'encode_valve_command', 'decode_estimated_flow', 'EstimatedFlow', 'Dtc',
           'DiagnosticMessage', 'decode_dm1']

PGN_VALVE_COMMAND = 65072
PGN_ESTIMATED_FLOW = 65040
PGN_DM1 = 65226
PGN_ADDRESS_CLAIMED = 60928
PGN_REQUEST = 59904
#: DM11, diagnostic data clear/reset for active DTCs (J1939-73), asked for by a Request.
PGN_DM11 = 65235
#: Acknowledgment (J1939-21): control byte 0 ACK, 1 NACK, 2 access denied, 3 cannot respond.
PGN_ACKNOWLEDGMENT = 59392
_REQUEST_PRIORITY = 6
STATE_BLOCK, STATE_EXTEND = 0, 1
_FLOW_STEP_PCT = 0.4
_EXTENDED_STEP_PCT = 0.0015625
_COMMAND_PRIORITY = 3

#: J1939-73 failure mode identifiers.
FMI_NAMES = {
    0: 'data valid but above normal range (most severe)',
    1: 'data valid but below normal range (most severe)', 2: 'data erratic or incorrect',
    3: 'voltage above normal or shorted to high', 4: 'voltage below normal or shorted to low',
    5: 'current below normal or open circuit', 6: 'current above normal or grounded circuit',
    7: 'mechanical system not responding or out of adjustment', 8: 'abnormal frequency',
    9: 'abnormal update rate', 10: 'abnormal rate of change', 11: 'root cause not known',
    12: 'bad intelligent device or component', 13: 'out of calibration',
    14: 'special instructions', 15: 'above normal (least severe)',
    16: 'above normal (moderately severe)', 17: 'below normal (least severe)',
    18: 'below normal (moderately severe)', 19: 'received network data in error',
    20: 'data drifted high', 21: 'data drifted low', 31: 'condition exists',
}


def make_id(priority: int, pgn: int, source: int, destination: int = 0xFF) -> int:
    """The 29-bit id of a PGN; a PDU1 PGN (PF < 240) carries ``destination`` in PS."""
    pf = (pgn >> 8) & 0xFF
    ps = destination if pf < 240 else pgn & 0xFF
    return ((priority & 7) << 26) | ((pgn >> 16) & 3) << 24 | pf << 16 | ps << 8 | source & 0xFF


def split_id(can_id: int) -> tuple[int, int, int, int]:
    """``(priority, pgn, source, destination)`` of a 29-bit id (destination 0xFF: global)."""
    pf, ps = (can_id >> 16) & 0xFF, (can_id >> 8) & 0xFF
    pgn = (can_id >> 8) & 0x3FFFF
    destination = 0xFF
    if pf < 240:
        pgn &= 0x3FF00
        destination = ps
    return (can_id >> 26) & 7, pgn, can_id & 0xFF, destination


def request_frame(pgn: int, source: int, destination: int) -> tuple[int, bytes]:
    """``(can id, data)`` of a Request (PGN 59904, J1939-21) for ``pgn`` to ``destination``."""
    return (make_id(_REQUEST_PRIORITY, PGN_REQUEST, source, destination),
            pgn.to_bytes(3, 'little'))


def encode_valve_command(valve_index: int, source: int, duty: float) -> tuple[int, bytes]:
    """``(can id, data)`` of the Auxiliary Valve Command for ``duty`` in [0, 1].

    Duty 0 is state block (0), any other duty state extend (1) with port flow
    ``duty`` x 100 %; fail-safe mode block (00); both resolutions valid.
    """
    duty = min(max(float(duty), 0.0), 1.0)
    percent = duty * 100.0
    standard = round(percent / _FLOW_STEP_PCT)
    extended = round(percent / _EXTENDED_STEP_PCT)
    state = STATE_EXTEND if duty > 0.0 else STATE_BLOCK
    data = bytes([standard, 0xFC | 0b01, 0x30 | state, extended & 0xFF, extended >> 8,
                  0xFF, 0xFF, 0xFF])
    return make_id(_COMMAND_PRIORITY, PGN_VALVE_COMMAND + valve_index, source), data


@dataclass(frozen=True, slots=True)
class EstimatedFlow:
    """An Auxiliary Valve Estimated Flow: port flows [%] (NaN: not available), state."""

    extend_pct: float
    retract_pct: float
    state: int
    fail_safe: int
    exit_code: int


def _flow(raw: int) -> float:
    return math.nan if raw > 250 else float(raw) - 125.0


def decode_estimated_flow(data: bytes) -> EstimatedFlow | None:
    """The Estimated Flow in ``data`` (None if shorter than 4 bytes)."""
    if len(data) < 4:
        return None
    return EstimatedFlow(_flow(data[0]), _flow(data[1]), data[2] >> 4, data[2] & 3,
                         data[3] & 0x3F)


@dataclass(frozen=True, slots=True)
class Dtc:
    """One active diagnostic trouble code."""

    spn: int
    fmi: int
    occurrences: int

    @property
    def text(self) -> str:
        return (f'SPN {self.spn} FMI {self.fmi} ({FMI_NAMES.get(self.fmi, "reserved")}), '
                f'{self.occurrences} occurrence(s)')


@dataclass(frozen=True, slots=True)
class DiagnosticMessage:
    """A DM1: lamp states (0 off, 1 on) and the active DTCs."""

    protect: int
    amber: int
    red_stop: int
    mil: int
    dtcs: tuple[Dtc, ...]


def decode_dm1(data: bytes) -> DiagnosticMessage | None:
    """The DM1 in ``data`` (single frame or reassembled); None if shorter than 6 bytes."""
    if len(data) < 6:
        return None
    lamps = data[0]
    dtcs = []
    for offset in range(2, len(data) - 3, 4):
        b3, b4, b5, b6 = data[offset:offset + 4]
        spn = b3 | (b4 << 8) | ((b5 >> 5) << 16)
        fmi = b5 & 0x1F
        if spn == 0 and fmi == 0 or (b3, b4, b5, b6) == (0xFF, 0xFF, 0xFF, 0xFF):
            continue
        dtcs.append(Dtc(spn, fmi, b6 & 0x7F))
    return DiagnosticMessage(lamps & 3, (lamps >> 2) & 3, (lamps >> 4) & 3, (lamps >> 6) & 3,
                             tuple(dtcs))
