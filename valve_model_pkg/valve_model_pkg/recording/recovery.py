"""Reading MCAP files up to their last complete record, and recovering killed bags.

A recorder killed with SIGKILL (or a power cut) leaves a bag directory with an MCAP file
that has chunks but no summary, no footer and no ``metadata.yaml``; the last chunk may be
cut in the middle. rosbags' reader (and ``ros2 bag info``) refuse such a file.
:class:`McapScanner` reads the file front to back, record by record, and stops cleanly at
the first record that is incomplete or damaged; everything before it is intact (MCAP
records carry their length, chunks are decompressed and size/CRC-checked).
:func:`recover_bag` writes what the scanner finds into a new, complete bag.

Only the ``ros2`` profile with ``cdr`` messages is recovered (what rosbag2 and
:class:`~valve_model_pkg.recording.writer.BagWriter` write). Plain-stdlib parsing, no
dependency beyond rosbags.
"""
from __future__ import annotations

import logging
import mmap
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from rosbags.rosbag2 import ReaderError
from rosbags.rosbag2.metadata import parse_qos
from rosbags.rosbag2.storage_mcap import decompress
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from ..errors import BagFormatError
from .typestore import TypeDefinition, typestore_for_bag
from .writer import BagWriter

__all__ = ['MAGIC', 'McapSchema', 'McapChannel', 'McapMessage', 'ScanReport', 'McapScanner',
           'RecoveryReport', 'find_mcap', 'typestore_from_schemas', 'recover_bag']

_LOG = logging.getLogger(__name__)

#: MCAP magic, at the start and at the end of a complete file.
MAGIC = b'\x89MCAP0\r\n'

_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 1, 2, 3, 4, 5, 6
_OP_DATA_END = 0x0F
_KNOWN_OPS = frozenset(range(0x01, 0x10))
_REC_HEAD = struct.Struct('<BQ')
_U16 = struct.Struct('<H')
_U32 = struct.Struct('<I')
_U64 = struct.Struct('<Q')
_MSG_HEAD = struct.Struct('<HIQQ')
_CHUNK_HEAD = struct.Struct('<QQQI')
#: A record longer than this is taken for garbage (rosbags' chunks are ~1 MiB).
_MAX_RECORD = 1 << 32


@dataclass(frozen=True)
class McapSchema:
    """An MCAP schema record: a message type and its definition."""

    id: int
    name: str       #: ``pkg/msg/Name``
    encoding: str   #: ``ros2msg`` or ``ros2idl``
    data: str       #: the definition text


@dataclass(frozen=True)
class McapChannel:
    """An MCAP channel record: a topic, its schema and its metadata."""

    id: int
    schema_id: int
    topic: str
    message_encoding: str
    metadata: dict[str, str]


@dataclass(frozen=True)
class McapMessage:
    """One message record."""

    channel_id: int
    log_time_ns: int
    publish_time_ns: int
    data: bytes


@dataclass
class ScanReport:
    """What :class:`McapScanner` found; filled in while scanning."""

    path: Path
    size_bytes: int = 0
    valid_bytes: int = 0        #: end offset of the last complete record
    complete: bool = False      #: the footer (or data-end record) was reached
    stop_reason: str = ''       #: why the scan stopped ('' when complete)
    chunks: int = 0             #: complete chunks read
    messages: int = 0           #: messages yielded
    profile: str = ''
    library: str = ''
    #: Damaged parts passed over (a chunk failing its CRC or decompression, or garbage up
    #: to the next intact chunk), one description each with offset and reason.
    skipped: list[str] = field(default_factory=list)
    skipped_bytes: int = 0      #: bytes of the damaged parts passed over

    @property
    def discarded_bytes(self) -> int:
        """Bytes after the last complete record (the cut-off tail of a killed writer)."""
        return self.size_bytes - self.valid_bytes


def _string(buf: bytes | memoryview, pos: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(buf, pos)
    end = pos + 4 + n
    if end > len(buf):
        raise ValueError('string runs past the end of its record')
    return bytes(buf[pos + 4:end]).decode('utf-8'), end


def _parse_schema(rec: memoryview) -> McapSchema:
    (sid,) = _U16.unpack_from(rec, 0)
    name, pos = _string(rec, 2)
    encoding, pos = _string(rec, pos)
    data, _ = _string(rec, pos)
    return McapSchema(sid, name, encoding, data)


def _parse_channel(rec: memoryview) -> McapChannel:
    cid, sid = struct.unpack_from('<HH', rec, 0)
    topic, pos = _string(rec, 4)
    encoding, pos = _string(rec, pos)
    (size,) = _U32.unpack_from(rec, pos)
    pos += 4
    end = pos + size
    meta: dict[str, str] = {}
    while pos < end:
        key, pos = _string(rec, pos)
        value, pos = _string(rec, pos)
        meta[key] = value
    return McapChannel(cid, sid, topic, encoding, meta)


def _parse_message(rec: memoryview) -> McapMessage:
    if len(rec) < _MSG_HEAD.size:
        raise ValueError(f'message record of {len(rec)} bytes is too short')
    cid, _, log_time, publish_time = _MSG_HEAD.unpack_from(rec, 0)
    return McapMessage(cid, log_time, publish_time, bytes(rec[_MSG_HEAD.size:]))


def find_mcap(path: str | Path) -> Path:
    """The MCAP file of a bag directory (or ``path`` itself if it is a file).

    Raises
    ------
    BagFormatError
        No ``.mcap`` file, or several (split bags are not recovered as one).
    """
    p = Path(path)
    if p.is_file():
        return p
    if not p.is_dir():
        raise BagFormatError(f'{p} does not exist')
    files = sorted(p.glob('*.mcap'))
    if not files:
        raise BagFormatError(f'{p} holds no .mcap file')
    if len(files) > 1:
        raise BagFormatError(f'{p} holds several .mcap files {[f.name for f in files]}; '
                             'give the file to read')
    return files[0]


class McapScanner:
    """Read an MCAP file front to back, stopping at the first incomplete record.

    Parameters
    ----------
    path : str or pathlib.Path
        An ``.mcap`` file, or a bag directory holding one.

    Notes
    -----
    Iterating yields :class:`McapSchema`, :class:`McapChannel` and :class:`McapMessage`
    objects in file order (a chunk's records are yielded only after the whole chunk was
    read and checked). :attr:`report` says how far the file was good and why the scan
    stopped. Summary-section records (indexes, statistics) are skipped: they are rebuilt
    by a writer.

    Examples
    --------
    >>> scanner = McapScanner('killed_bag')                         # doctest: +SKIP
    >>> n = sum(isinstance(r, McapMessage) for r in scanner)        # doctest: +SKIP
    >>> scanner.report.stop_reason                                  # doctest: +SKIP
    'record 0x06 at offset 3145833 is cut off: 1048611 bytes announced, 40960 present'
    """

    def __init__(self, path: str | Path) -> None:
        self.path = find_mcap(path)
        self.report = ScanReport(self.path)

    def __iter__(self) -> Iterator[McapSchema | McapChannel | McapMessage]:
        rep = self.report
        try:
            f = self.path.open('rb')
        except OSError as err:
            raise BagFormatError(f'cannot open {self.path}: {err.strerror}') from err
        with f:
            rep.size_bytes = f.seek(0, 2)
            f.seek(0)
            if f.read(len(MAGIC)) != MAGIC:
                raise BagFormatError(f'{self.path} is not an MCAP file (bad magic)')
            rep.valid_bytes = len(MAGIC)
            yield from self._records(f)
        if rep.stop_reason:
            _LOG.warning('%s: %s; %d messages in %d complete chunks read, %d bytes after '
                         'offset %d ignored', self.path, rep.stop_reason, rep.messages,
                         rep.chunks, rep.discarded_bytes, rep.valid_bytes)

    def _stop(self, reason: str) -> None:
        self.report.stop_reason = reason

    def _skip(self, offset: int, length: int, reason: str) -> None:
        rep = self.report
        rep.skipped.append(f'{length} bytes at offset {offset}: {reason}')
        rep.skipped_bytes += length
        _LOG.warning('%s: skipped %d damaged bytes at offset %d (%s)', self.path, length,
                     offset, reason)

    def _resync(self, f: BinaryIO, start: int) -> tuple[int, int, list] | None:
        """The next intact chunk after ``start``: (offset, record length, its records).

        A chunk is taken only when it decodes and its size (and CRC, when the writer set
        one) check out, so a chance 0x06 byte in damaged data is not mistaken for one.
        """
        size = self.report.size_bytes
        if size <= start + 1:
            return None
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            pos = start + 1
            while True:
                idx = mm.find(bytes([_OP_CHUNK]), pos)
                if idx < 0 or idx + _REC_HEAD.size > size:
                    return None
                pos = idx + 1
                _, length = _REC_HEAD.unpack_from(mm, idx)
                body_start = idx + _REC_HEAD.size
                if length < _CHUNK_HEAD.size + 12 or body_start + length > size:
                    continue
                try:
                    records = self._decode(_OP_CHUNK, memoryview(mm[body_start:
                                                                    body_start + length]))
                except (ValueError, struct.error, UnicodeDecodeError, ReaderError,
                        MemoryError, OverflowError):
                    continue
                return idx, length, records

    def _records(self, f: BinaryIO) -> Iterator[McapSchema | McapChannel | McapMessage]:
        rep = self.report
        while True:
            offset = f.tell()
            head = f.read(_REC_HEAD.size)
            if not head:
                self._stop(f'file ends at offset {offset} without footer')
                return
            if len(head) < _REC_HEAD.size:
                self._stop(f'record header at offset {offset} is cut off')
                return
            op, length = _REC_HEAD.unpack(head)
            left = rep.size_bytes - offset - _REC_HEAD.size
            problem = ''
            if op not in _KNOWN_OPS or length > _MAX_RECORD:
                problem = (f'no valid record at offset {offset} (opcode 0x{op:02x}, '
                           f'length {length}); garbage or zero-filled tail')
            elif length > left:
                problem = (f'record 0x{op:02x} at offset {offset} is cut off: {length} bytes '
                           f'announced, {left} present')
            if problem:
                # A cut-off tail, or damage in the middle: an intact chunk further on
                # tells the two apart; its records are kept and the damage skipped.
                found = self._resync(f, offset)
                if found is None:
                    self._stop(problem)
                    return
                idx, length, records = found
                self._skip(offset, idx - offset, problem)
                f.seek(idx + _REC_HEAD.size + length)
                rep.valid_bytes = f.tell()
                yield from self._count(records)
                continue
            if op == _OP_FOOTER:
                rep.valid_bytes = rep.size_bytes
                rep.complete = True
                return
            if op == _OP_DATA_END:  # the summary section follows: all data has been read
                rep.valid_bytes = offset + _REC_HEAD.size + length
                rep.complete = True
                return
            if op not in (_OP_HEADER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK):
                f.seek(length, 1)  # index, attachment, metadata: not needed to recover
                rep.valid_bytes = offset + _REC_HEAD.size + length
                continue
            rec = memoryview(f.read(length))
            try:
                records = self._decode(op, rec)
            except (ValueError, struct.error, UnicodeDecodeError, ReaderError,
                    OverflowError) as err:
                if op == _OP_HEADER:
                    self._stop(f'record 0x{op:02x} at offset {offset} is damaged: {err}')
                    return
                # the record's length is intact (the next record header is where it says):
                # skip this record and go on with the next
                self._skip(offset, _REC_HEAD.size + length,
                           f'record 0x{op:02x} is damaged: {err}')
                rep.valid_bytes = offset + _REC_HEAD.size + length
                continue
            rep.valid_bytes = offset + _REC_HEAD.size + length
            yield from self._count(records)

    def _count(self, records: list) -> Iterator[McapSchema | McapChannel | McapMessage]:
        for r in records:
            if isinstance(r, McapMessage):
                self.report.messages += 1
            yield r

    def _decode(self, op: int, rec: memoryview) -> list:
        if op == _OP_HEADER:
            rep = self.report
            rep.profile, pos = _string(rec, 0)
            rep.library, _ = _string(rec, pos)
            if rep.profile != 'ros2':
                raise ValueError(f'profile {rep.profile!r} is not ros2')
            return []
        if op == _OP_SCHEMA:
            return [_parse_schema(rec)]
        if op == _OP_CHANNEL:
            return [_parse_channel(rec)]
        if op == _OP_MESSAGE:
            return [_parse_message(rec)]
        # chunk: header, compressed records; checked as a whole before anything is used
        _, _, size, crc = _CHUNK_HEAD.unpack_from(rec, 0)
        compression, pos = _string(rec, _CHUNK_HEAD.size)
        (compressed_size,) = _U64.unpack_from(rec, pos)
        pos += 8
        if pos + compressed_size > len(rec):
            raise ValueError('chunk data runs past the end of the chunk record')
        raw = memoryview(decompress(bytes(rec[pos:pos + compressed_size]), compression, size,
                                    crc))
        out: list = []
        p = 0
        while p < len(raw):
            if p + _REC_HEAD.size > len(raw):
                raise ValueError('record header cut off inside the chunk')
            op_in, length = _REC_HEAD.unpack_from(raw, p)
            p += _REC_HEAD.size
            if p + length > len(raw):
                raise ValueError(f'record 0x{op_in:02x} runs past the end of its chunk')
            body = raw[p:p + length]
            p += length
            if op_in == _OP_SCHEMA:
                out.append(_parse_schema(body))
            elif op_in == _OP_CHANNEL:
                out.append(_parse_channel(body))
            elif op_in == _OP_MESSAGE:
                out.append(_parse_message(body))
        self.report.chunks += 1
        return out


def typestore_from_schemas(schemas: dict[int, McapSchema] | list[McapSchema]) -> Typestore:
    """A typestore with the types defined by embedded schemas.

    Raises
    ------
    BagFormatError
        A schema cannot be parsed.
    """
    items = schemas.values() if isinstance(schemas, dict) else schemas
    return typestore_for_bag([TypeDefinition(s.name, s.encoding, s.data) for s in items],
                             'MCAP schemas')


@dataclass(frozen=True)
class RecoveryReport:
    """Outcome of :func:`recover_bag`."""

    source: Path
    output: Path
    scan: ScanReport
    counts: dict[str, int] = field(default_factory=dict)  #: messages per topic
    first_ns: int = 0     #: first message log time [ns]
    last_ns: int = 0      #: last message log time [ns]
    orphans: int = 0      #: messages whose channel record was lost (not written)

    @property
    def messages(self) -> int:
        """Messages written to the recovered bag."""
        return sum(self.counts.values())

    def summary(self) -> str:
        """A few lines for a terminal."""
        s = self.scan
        state = 'complete file' if s.complete else f'stopped: {s.stop_reason}'
        lines = [f'recovered {self.messages} messages from {s.chunks} chunks of {self.source} '
                 f'({state})',
                 f'kept {s.valid_bytes} of {s.size_bytes} bytes; wrote {self.output}']
        if self.messages:
            lines.append(f'time span {(self.last_ns - self.first_ns) * 1e-9:.3f} s')
        lines += [f'  {t}: {n}' for t, n in sorted(self.counts.items())]
        if s.skipped:
            lines.append(f'skipped {len(s.skipped)} damaged parts ({s.skipped_bytes} bytes); '
                         'every intact chunk around them is kept:')
            lines += [f'  skipped {d}' for d in s.skipped]
        if self.orphans:
            lines.append(f'{self.orphans} messages of unknown channels dropped')
        return '\n'.join(lines)


def recover_bag(source: str | Path, output: str | Path | None = None, *,
                compression: str = 'none') -> RecoveryReport:
    """Write a complete bag from what is readable of a (possibly killed) bag's MCAP file.

    Parameters
    ----------
    source : str or pathlib.Path
        Bag directory (with or without ``metadata.yaml``) or its ``.mcap`` file. Not
        modified.
    output : str or pathlib.Path, optional
        New bag directory (must not exist); default ``<source dir>_recovered`` next to
        the source.
    compression : {'none', 'zstd'}
        Chunk compression of the new bag.

    Returns
    -------
    RecoveryReport
        Counts per topic, what was kept and why the scan stopped.

    Raises
    ------
    BagFormatError
        Not an MCAP file, or nothing at all recoverable (no channel).
    BagWriteError
        ``output`` exists or cannot be written.

    Notes
    -----
    Every message of every complete chunk is kept, with its log time; the message
    definitions and offered QoS profiles come from the file's own schema and channel
    records, so the recovered bag plays and opens like the original would have.
    """
    mcap = find_mcap(source)
    src_dir = mcap.parent
    dst = Path(output) if output is not None else src_dir.parent / f'{src_dir.name}_recovered'
    scanner = McapScanner(mcap)
    schemas: dict[int, McapSchema] = {}
    channels: dict[int, McapChannel] = {}
    store: Typestore | None = None
    conns: dict[int, object] = {}
    counts: dict[str, int] = {}
    first, last, orphans = 2**63 - 1, 0, 0
    writer: BagWriter | None = None
    try:
        for rec in scanner:
            if isinstance(rec, McapSchema):
                schemas[rec.id] = rec
                store = None  # rebuilt when a channel needs it
            elif isinstance(rec, McapChannel):
                channels[rec.id] = rec
            else:
                conn = conns.get(rec.channel_id)
                if conn is None:
                    ch = channels.get(rec.channel_id)
                    if ch is None or ch.schema_id not in schemas:
                        orphans += 1
                        continue
                    if writer is None:
                        writer = BagWriter(dst, get_typestore(Stores.EMPTY), flush_period_s=0.0,
                                           fsync=False, compression=compression,
                                           custom_data={'recovered_from': str(mcap)}).open()
                    if store is None:
                        store = typestore_from_schemas(schemas)
                    schema = schemas[ch.schema_id]
                    qos = parse_qos(ch.metadata.get('offered_qos_profiles', ''))
                    conn = writer.add_topic(ch.topic, schema.name, qos, msgdef=schema.data,
                                            type_hash=store.hash_rihs01(schema.name))
                    conns[rec.channel_id] = conn
                    counts.setdefault(conn.topic, 0)
                writer.write(conn, rec.log_time_ns, rec.data)
                counts[conn.topic] += 1
                first = min(first, rec.log_time_ns)
                last = max(last, rec.log_time_ns)
        if writer is None:
            if not channels:
                raise BagFormatError(f'{mcap}: nothing recoverable ({scanner.report.stop_reason}'
                                     f'{"" if scanner.report.stop_reason else "no channels"})')
            # channels but no message: an empty bag with the topics
            writer = BagWriter(dst, get_typestore(Stores.EMPTY), flush_period_s=0.0,
                               fsync=False, compression=compression,
                               custom_data={'recovered_from': str(mcap)}).open()
            store = typestore_from_schemas(schemas)
            for ch in channels.values():
                if ch.schema_id in schemas:
                    schema = schemas[ch.schema_id]
                    writer.add_topic(ch.topic, schema.name,
                                     parse_qos(ch.metadata.get('offered_qos_profiles', '')),
                                     msgdef=schema.data,
                                     type_hash=store.hash_rihs01(schema.name))
                    counts.setdefault(ch.topic, 0)
        writer.close()
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    report = RecoveryReport(source=Path(source), output=dst, scan=scanner.report,
                            counts=counts, first_ns=first if counts else 0,
                            last_ns=last, orphans=orphans)
    _LOG.info('%s', report.summary())
    return report
