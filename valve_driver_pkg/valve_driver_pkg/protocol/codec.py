"""cantools codec of the valve protocol: node ids, CRC-8, rolling counters, strict encoding.

The DBC (``valve.dbc`` beside this module) lists the frames of node 0; node ``n`` uses
``frame id + n`` for every message (``n`` in ``0..MAX_NODE_ID``). The default ids,
0x680-0x6CF, are the block CANopen's predefined connection set leaves free, so the valve
can share a bus with CANopen devices (see the package README). The test-only
``EmulatorControl`` message is in ``valve_test.dbc``, loaded only by the emulator and test
tools (``include_test_messages=True``). Every frame is 8 bytes with the same trailer:

* bits 48..51: ``Counter``, a 4-bit rolling counter, +1 (mod 16) per frame of that message;
* byte 7: ``Checksum``, CRC-8/SAE-J1850 (polynomial 0x1D, init 0xFF, final xor 0xFF;
  computed by crccheck's ``Crc8SaeJ1850``) over the two bytes of the 11-bit frame id (low
  byte first; the four bytes of a 29-bit id) followed by data bytes 0..6. The id is part
  of the checksum so a frame of another node or message can never pass for ours.

Every message has an 11-bit id except ``ValveTelemetryMean`` (the interval means, 1 kHz)
and ``ValveDrive`` (the drive electronics in force, 10 Hz): the 11-bit block beside CANopen
is full (6 messages x 16 nodes), so they use the 29-bit ids 0x16900 + node and 0x16910 +
node, which no CANopen device uses (:data:`EXTENDED_MESSAGE_NAMES`).

The drive mode (``ValveCommand.DriveMode``, :class:`DriveMode`) came with protocol 2.1; a
caller that leaves it out encodes 0 = ``Normal``, what a 2.0 controller does
(:data:`SIGNAL_DEFAULTS`). Every other signal must be given.

Encoding is strict: a signal outside its DBC range raises :class:`ProtocolEncodeError`
naming the signal, the limit and the value (callers clamp first; see the driver core).
Decoding checks, in this order, and raises :class:`FrameRejected` with a
:class:`RejectReason`: frame kind (error/remote/extended/FD), known id, length, checksum,
signal ranges. Rolling counters are stateful and checked by :class:`CounterTracker`.
"""
from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import can
import cantools
from cantools.database.errors import EncodeError
from crccheck.crc import Crc8SaeJ1850

from valve_driver_pkg.errors import DbcError, FrameRejected, ProtocolEncodeError

__all__ = [
    'COMMAND', 'TELEMETRY', 'TELEMETRY_MEAN', 'PERIOD', 'PRESSURE', 'STATUS', 'CONTROL',
    'DRIVE', 'DriveMode', 'SIGNAL_DEFAULTS', 'MESSAGE_NAMES', 'TEST_MESSAGE_NAMES',
    'EXTENDED_MESSAGE_NAMES', 'MAX_NODE_ID',
    'FRAME_LENGTH', 'RejectReason', 'EmulatorFault',
    'DecodedFrame', 'ValveCodec', 'CounterCheck', 'CounterTracker', 'crc8', 'frame_checksum',
    'default_dbc_path', 'fault_injection_dbc_path',
]

COMMAND = 'ValveCommand'          # host -> controller, 100 Hz + on change
TELEMETRY = 'ValveTelemetry'      # controller -> host, 1 kHz
TELEMETRY_MEAN = 'ValveTelemetryMean'  # controller -> host, 1 kHz interval means (29-bit id)
PERIOD = 'ValvePeriod'            # controller -> host, per PWM period / on change + 10 Hz
PRESSURE = 'ValvePressure'        # host -> controller, 10 Hz + on change
STATUS = 'ValveStatus'            # controller -> host, 10 Hz heartbeat
DRIVE = 'ValveDrive'              # controller -> host, 10 Hz + on change (29-bit id)
CONTROL = 'EmulatorControl'       # tester -> emulator, fault injection (valve_test.dbc)
#: The messages of the protocol (valve.dbc), the only ones the driver knows.
MESSAGE_NAMES = (COMMAND, TELEMETRY, PERIOD, PRESSURE, STATUS, TELEMETRY_MEAN, DRIVE)
#: Messages with a 29-bit id (all others: 11-bit).
EXTENDED_MESSAGE_NAMES = (TELEMETRY_MEAN, DRIVE)
#: Signals added after protocol 2.0 and their value when a caller leaves them out (what a
#: controller of the older protocol does): ``DriveMode`` 0 = Normal.
SIGNAL_DEFAULTS = {COMMAND: {'DriveMode': 0}}
#: Test-only messages (valve_test.dbc): the emulator and test tools add them.
TEST_MESSAGE_NAMES = (CONTROL,)

#: Highest node id: every message reserves 16 consecutive ids. 16 valves per bus is more
#: than a bus carries anyway: one valve's 1 kHz telemetry takes about 25 % of 500 kbit/s.
MAX_NODE_ID = 15
#: Every frame of the protocol is a classic CAN frame of 8 bytes.
FRAME_LENGTH = 8
_COUNTER_START_BIT = 48
_CHECKSUM_START_BIT = 56


class RejectReason(str, enum.Enum):
    """Why a received frame was rejected; the value is the diagnostics counter key."""

    UNKNOWN_ID = 'unknown_id'
    WRONG_LENGTH = 'wrong_length'
    CHECKSUM = 'checksum'
    COUNTER_FROZEN = 'counter_frozen'
    OUT_OF_RANGE = 'out_of_range'
    FRAME_TYPE = 'frame_type'          # remote, extended-id or CAN FD frame


class DriveMode(enum.IntEnum):
    """Values of ``ValveCommand.DriveMode`` and ``ValveDrive.DriveModeActive`` (VAL_ table).

    ``NORMAL``: the valve's drive electronics (boost, holding-current chopper, capacitor
    release pulse). ``BENCH``: boost, chopper and capacitor bypassed; the coil sees the
    supply voltage for the whole main PWM high phase (as long as duty = 1).
    """

    NORMAL = 0
    BENCH = 1

    @classmethod
    def parse(cls, text: str) -> DriveMode:
        """The mode named ``text`` (``'normal'`` or ``'bench'``, any case).

        Raises
        ------
        ValueError
            Any other name; the message lists the valid ones.
        """
        try:
            return cls[str(text).strip().upper()]
        except KeyError:
            names = ', '.join(repr(m.name.lower()) for m in cls)
            raise ValueError(f'drive mode {text!r} is not one of {names}') from None


class EmulatorFault(enum.IntEnum):
    """Values of ``EmulatorControl.Fault`` (the DBC's VAL_ table)."""

    CLEAR_ALL = 0
    DROP_TELEMETRY = 1
    CORRUPT_CHECKSUM = 2
    FREEZE_COUNTER = 3
    SILENT = 4
    BUS_OFF = 5
    ERROR_PASSIVE = 6
    WRONG_LENGTH = 7
    UNKNOWN_ID = 8
    OVERCURRENT = 9


def crc8(data: bytes | bytearray) -> int:
    """CRC-8/SAE-J1850 of ``data`` (poly 0x1D, init 0xFF, xorout 0xFF; check(b'123456789') = 0x4B).

    Computed by the maintained ``crccheck`` package (installed with cantools); a test checks
    it against the catalogue value and a table implementation on random frames.

    Parameters
    ----------
    data : bytes
        The bytes to protect.

    Returns
    -------
    int
        The checksum, 0..255.
    """
    return Crc8SaeJ1850.calc(data)


def frame_checksum(arbitration_id: int, data: bytes | bytearray, extended: bool = False) -> int:
    """Checksum byte of a protocol frame: CRC-8 over the id (LE: 2 bytes, 4 for a 29-bit
    id) and data[0:7]."""
    ident = (arbitration_id & 0x1FFFFFFF).to_bytes(4, 'little') if extended \
        else (arbitration_id & 0xFFFF).to_bytes(2, 'little')
    return crc8(ident + bytes(data[:7]))


def default_dbc_path() -> Path:
    """Path of the protocol's DBC file shipped with the package."""
    return Path(__file__).resolve().with_name('valve.dbc')


def fault_injection_dbc_path() -> Path:
    """Path of the test-only DBC (fault injection); the driver never loads it."""
    return Path(__file__).resolve().with_name('valve_test.dbc')


@dataclass(frozen=True, slots=True)
class DecodedFrame:
    """A received frame that passed every stateless check.

    Attributes
    ----------
    name : str
        DBC message name (``TELEMETRY``, ``STATUS``, ...).
    node_id : int
        Node the frame belongs to (frame id minus the message's base id).
    signals : dict[str, float | int]
        Physical signal values (scaled), including ``Counter`` and ``Checksum``.
    counter : int
        The 4-bit rolling counter.
    timestamp : float
        python-can receive timestamp [s].
    """

    name: str
    node_id: int
    signals: dict
    counter: int
    timestamp: float


class ValveCodec:
    """Encodes and decodes the valve protocol for one node id.

    Parameters
    ----------
    node_id : int
        Node id of the controller, ``0..MAX_NODE_ID``; frame id = DBC id + node id.
    dbc_path : str | Path | None
        DBC file; ``None`` uses the shipped ``valve.dbc``. A custom DBC must keep the
        message names, the 8-byte length and the counter/checksum positions.
    include_test_messages : bool
        Also load ``valve_test.dbc`` (``EmulatorControl``, fault injection): for the
        emulator and test tools only; the driver never does.

    Raises
    ------
    DbcError
        The file cannot be loaded or breaks the layout rules above.
    ValueError
        ``node_id`` outside ``0..MAX_NODE_ID``.
    """

    def __init__(self, node_id: int, dbc_path: str | Path | None = None, *,
                 include_test_messages: bool = False) -> None:
        if not 0 <= int(node_id) <= MAX_NODE_ID:
            raise ValueError(f'node id {node_id!r} outside 0..{MAX_NODE_ID}')
        self.node_id = int(node_id)
        self.dbc_path = Path(dbc_path) if dbc_path else default_dbc_path()
        try:
            self._db = cantools.database.load_file(str(self.dbc_path), strict=True)
            if include_test_messages:
                self._db.add_dbc_file(str(fault_injection_dbc_path()))
        except (OSError, cantools.database.UnsupportedDatabaseFormatError,
                cantools.database.Error) as err:
            raise DbcError(f'cannot load DBC {self.dbc_path}: {err}') from err
        self._messages = {}
        self._base_ids = {}
        self._ranges = {}
        names = MESSAGE_NAMES + (TEST_MESSAGE_NAMES if include_test_messages else ())
        for name in names:
            try:
                message = self._db.get_message_by_name(name)
            except KeyError as err:
                raise DbcError(f'DBC {self.dbc_path} has no message {name!r}') from err
            self._check_layout(message)
            self._messages[name] = message
            self._base_ids[name] = message.frame_id
            self._ranges[name] = tuple(
                (s.name, s.minimum, s.maximum) for s in message.signals
                if s.name not in ('Counter', 'Checksum'))
        for extended in (False, True):
            spans = sorted((base, base + MAX_NODE_ID, name)
                           for name, base in self._base_ids.items()
                           if (name in EXTENDED_MESSAGE_NAMES) == extended)
            for (lo_a, hi_a, a), (lo_b, _, b) in zip(spans, spans[1:]):
                if lo_b <= hi_a:
                    raise DbcError(f'DBC {self.dbc_path}: id ranges of {a} and {b} overlap '
                                   f'(each message needs {MAX_NODE_ID + 1} ids)')
            if spans and spans[-1][1] > (0x1FFFFFFF if extended else 0x7FF):
                raise DbcError(f'DBC {self.dbc_path}: {spans[-1][2]} ids exceed '
                               f'{29 if extended else 11} bits')
        # id -> (message name, node id) for every id of the protocol, for O(1) lookups.
        # (29-bit ids are above 0x7FF, so one table holds both kinds.)
        self._by_id = {base + n: (name, n) for name, base in self._base_ids.items()
                       for n in range(MAX_NODE_ID + 1)}
        self._extended = {name for name in self._messages if name in EXTENDED_MESSAGE_NAMES}

    def _check_layout(self, message) -> None:
        if message.length != FRAME_LENGTH:
            raise DbcError(f'DBC {self.dbc_path}: {message.name} is {message.length} bytes, '
                           f'the protocol needs {FRAME_LENGTH}')
        if message.is_extended_frame != (message.name in EXTENDED_MESSAGE_NAMES):
            bits = 29 if message.name in EXTENDED_MESSAGE_NAMES else 11
            raise DbcError(f'DBC {self.dbc_path}: {message.name} must use a {bits}-bit id')
        for name, start, length in (('Counter', _COUNTER_START_BIT, 4),
                                    ('Checksum', _CHECKSUM_START_BIT, 8)):
            try:
                signal = message.get_signal_by_name(name)
            except KeyError as err:
                raise DbcError(f'DBC {self.dbc_path}: {message.name} has no {name}') from err
            layout = (signal.start, signal.length, signal.byte_order)
            if layout != (start, length, 'little_endian'):
                raise DbcError(f'DBC {self.dbc_path}: {message.name}.{name} must be '
                               f'{length} bits at bit {start}, little endian')

    # --- ids ---------------------------------------------------------------------------------
    def frame_id(self, name: str, node_id: int | None = None) -> int:
        """Arbitration id of message ``name`` for ``node_id`` (default: this codec's node)."""
        return self._base_ids[name] + (self.node_id if node_id is None else node_id)

    def classify(self, arbitration_id: int) -> tuple[str, int] | None:
        """``(message name, node id)`` of a protocol id, or ``None`` for a foreign id."""
        return self._by_id.get(arbitration_id)

    def signal_range(self, name: str, signal: str) -> tuple[float, float]:
        """``(minimum, maximum)`` of a signal as the DBC declares it."""
        sig = self._messages[name].get_signal_by_name(signal)
        return float(sig.minimum), float(sig.maximum)

    def signal_scale(self, name: str, signal: str) -> float:
        """Quantisation step (scale) of a signal."""
        return float(self._messages[name].get_signal_by_name(signal).scale)

    # --- encoding ----------------------------------------------------------------------------
    def encode(self, name: str, signals: Mapping[str, float], counter: int,
               node_id: int | None = None, timestamp: float = 0.0) -> can.Message:
        """Encode a frame with counter and checksum filled in (strict: no silent clipping).

        Parameters
        ----------
        name : str
            DBC message name.
        signals : Mapping[str, float]
            Physical values of every signal except ``Counter`` and ``Checksum`` (and the
            later signals of :data:`SIGNAL_DEFAULTS`, which default to their old meaning).
        counter : int
            Rolling counter value, taken modulo 16.
        node_id : int | None
            Node the frame is for; ``None`` = this codec's node.

        Returns
        -------
        can.Message
            An 8-byte standard-id data frame.

        Raises
        ------
        ProtocolEncodeError
            A signal is missing or outside its DBC range; the message names the signal,
            the limit and the value (cantools' strict check).
        """
        message = self._messages[name]
        values = {**SIGNAL_DEFAULTS.get(name, {}), **signals}
        values['Counter'] = counter & 0xF
        values['Checksum'] = 0
        try:
            data = bytearray(message.encode(values, strict=True))
        except (EncodeError, KeyError, ValueError, TypeError) as err:
            raise ProtocolEncodeError(f'cannot encode {name}: {err}') from err
        arbitration_id = self.frame_id(name, node_id)
        extended = name in self._extended
        data[7] = frame_checksum(arbitration_id, data, extended)
        return can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=extended,
                           timestamp=timestamp)

    # --- decoding ----------------------------------------------------------------------------
    def decode(self, msg: can.Message, expect_node: bool = True) -> DecodedFrame:
        """Check and decode a received frame.

        Parameters
        ----------
        msg : can.Message
            The frame as python-can delivers it (error frames are handled elsewhere).
        expect_node : bool
            If true, a protocol frame of another node id is rejected as ``UNKNOWN_ID``.

        Returns
        -------
        DecodedFrame

        Raises
        ------
        FrameRejected
            With ``reason`` a :class:`RejectReason` value and a message naming the check.
        """
        arbitration_id = msg.arbitration_id
        found = self._by_id.get(arbitration_id)
        extended = found is not None and found[0] in self._extended
        if (msg.is_remote_frame or msg.is_extended_id != extended or msg.is_fd
                or msg.is_error_frame):
            kind = ('remote' if msg.is_remote_frame else 'error' if msg.is_error_frame
                    else 'CAN FD' if msg.is_fd else 'extended-id')
            raise FrameRejected(RejectReason.FRAME_TYPE.value,
                                f'{kind} frame with id 0x{arbitration_id:X} is not part of '
                                'the protocol')
        if found is None or (expect_node and found[1] != self.node_id):
            raise FrameRejected(RejectReason.UNKNOWN_ID.value,
                                f'frame id 0x{arbitration_id:X} is not a protocol id of node '
                                f'{self.node_id}')
        name, node_id = found
        data = msg.data
        if len(data) != FRAME_LENGTH or msg.dlc != FRAME_LENGTH:
            raise FrameRejected(RejectReason.WRONG_LENGTH.value,
                                f'{name} (0x{arbitration_id:X}) has {len(data)} data bytes '
                                f'(dlc {msg.dlc}), expected {FRAME_LENGTH}')
        expected = frame_checksum(arbitration_id, data, extended)
        if data[7] != expected:
            raise FrameRejected(RejectReason.CHECKSUM.value,
                                f'{name} (0x{arbitration_id:X}) checksum 0x{data[7]:02X}, '
                                f'expected 0x{expected:02X}')
        signals = self._messages[name].decode(bytes(data), decode_choices=False, scaling=True)
        for signal, low, high in self._ranges[name]:
            value = signals[signal]
            if (low is not None and value < low) or (high is not None and value > high):
                raise FrameRejected(RejectReason.OUT_OF_RANGE.value,
                                    f'signal "{signal}" of {name} is {value!r}, outside '
                                    f'[{low}, {high}]')
        return DecodedFrame(name, node_id, signals, int(signals['Counter']), msg.timestamp)


class CounterCheck(enum.Enum):
    """Result of a rolling-counter check."""

    FIRST = 'first'      # first frame seen (or first after a reset)
    OK = 'ok'            # previous + 1
    JUMP = 'jump'        # frames lost (or reordered): accepted, counted
    FROZEN = 'frozen'    # same counter as the previous frame: stale data, rejected


@dataclass(slots=True)
class CounterTracker:
    """Checks the 4-bit rolling counter of one message stream.

    ``check`` returns the result and, for a jump, how many frames were skipped
    (``lost``, ``1..14``). A frozen counter repeats the previous value.
    """

    last: int | None = None
    lost: int = 0

    def check(self, counter: int) -> CounterCheck:
        """Compare ``counter`` with the previous one and remember it."""
        previous, self.last = self.last, counter
        self.lost = 0
        if previous is None:
            return CounterCheck.FIRST
        step = (counter - previous) & 0xF
        if step == 1:
            return CounterCheck.OK
        if step == 0:
            return CounterCheck.FROZEN
        self.lost = step - 1
        return CounterCheck.JUMP

    def reset(self) -> None:
        """Forget the previous counter (after a gap the next frame is FIRST)."""
        self.last = None
        self.lost = 0
