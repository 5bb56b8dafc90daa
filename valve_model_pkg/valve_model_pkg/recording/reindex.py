"""Bags without ``metadata.yaml``: their storage files read in memory, as ``ros2 bag reindex``
would index them.

``ros2 bag reindex`` rebuilds a lost ``metadata.yaml`` from the storage files of a bag
directory. Here the same is done in memory and nothing is written: the user's directory
is never modified. The storage files are the directory's ``.mcap`` and ``.db3`` files
(``<name>_<index>`` for a split bag, read in index order), also zstd-compressed as whole
files (``.mcap.zstd``, ``.db3.zstd``: rosbag2's file compression, decompressed one file
at a time into a temporary directory). Messages compressed one by one (rosbag2's message
compression) are recognised by the zstd frame magic, which no CDR payload starts with
(CDR starts with a zero byte), and decompressed.

MCAP files are read with :class:`~.recovery.McapScanner`, so a file whose recorder was
killed (no summary, last chunk cut off) is read up to its last complete chunk; sqlite3
files with rosbags' storage reader.
"""
from __future__ import annotations

import re
import tempfile
from collections.abc import Iterator
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path

from rosbags.rosbag2 import Reader
from rosbags.rosbag2.storage_mcap import DECOMPRESSORS

from ..errors import BagFormatError
from .recovery import McapChannel, McapMessage, McapScanner, McapSchema, ScanReport
from .typestore import TypeDefinition

__all__ = ['BagIndex', 'IndexedMessage', 'TopicIndex', 'ZSTD_MAGIC', 'decompress_message',
           'reindex_bag', 'storage_files', 'storage_messages']

#: First bytes of a zstd frame (RFC 8878); a CDR payload starts with a zero byte.
ZSTD_MAGIC = b'\x28\xb5\x2f\xfd'

_STORAGES = {'.mcap': 'mcap', '.db3': 'sqlite3'}


def _storage_suffix(path: Path) -> tuple[str, bool] | None:
    """(``.mcap``/``.db3``, file-compressed) of a storage file name, else ``None``."""
    name = path.name
    compressed = name.endswith('.zstd')
    base = Path(name[:-5]) if compressed else path
    return (base.suffix, compressed) if base.suffix in _STORAGES else None


def _split_index(path: Path) -> tuple[str, int, str]:
    """Sort key: the name with the split index ``_<n>`` before the suffix read as a number."""
    stem = path.name.split('.', 1)[0]
    m = re.fullmatch(r'(.*?)_(\d+)', stem)
    return (m.group(1), int(m.group(2)), path.name) if m else (stem, -1, path.name)


def storage_files(directory: Path) -> list[Path]:
    """The storage files of a bag directory, in split order.

    Raises
    ------
    BagFormatError
        No storage file, or files of both storages.
    """
    files = [p for p in directory.iterdir() if p.is_file() and _storage_suffix(p)]
    if not files:
        raise BagFormatError(f'{directory} holds no metadata.yaml and no bag file (.mcap, '
                             '.db3, .mcap.zstd or .db3.zstd)')
    kinds = {_storage_suffix(p)[0] for p in files}
    if len(kinds) > 1:
        raise BagFormatError(f'{directory} holds no metadata.yaml and files of two storages '
                             f'({sorted(p.name for p in files)}); expected one bag')
    return sorted(files, key=_split_index)


def decompress_message(data: bytes | memoryview) -> bytes | memoryview:
    """A message payload, decompressed when it is a zstd frame."""
    if bytes(data[:4]) == ZSTD_MAGIC:
        return DECOMPRESSORS['zstd'](bytes(data), 0)
    return data


@dataclass(frozen=True)
class IndexedMessage:
    """One message of a storage file: its topic, type and raw (possibly compressed) data."""

    topic: str
    definition: TypeDefinition
    log_time_ns: int
    data: bytes | memoryview


@dataclass
class TopicIndex:
    """What ``metadata.yaml`` says of one topic."""

    msgtype: str
    count: int = 0
    qos: str = ''


@dataclass
class BagIndex:
    """The in-memory ``metadata.yaml`` of a bag directory without one.

    Attributes
    ----------
    path : pathlib.Path
        The bag directory (or the one storage file given).
    files : list of pathlib.Path
        Storage files in split order.
    storage_identifier : str
        ``mcap`` or ``sqlite3``.
    compression_mode : str
        ``''``, ``file`` (``.zstd`` files) or ``message`` (zstd-compressed messages).
    topics : dict of str to TopicIndex
        Per topic: type, message count, offered QoS (as the storage records it).
    start_ns, end_ns : int
        First and last message log time [ns] (0 when there is no message).
    scans : list of ScanReport
        One per MCAP file: how far it was intact.
    orphans : int
        Messages whose channel or schema record was lost (not readable).
    """

    path: Path
    files: list[Path]
    storage_identifier: str
    compression_mode: str = ''
    topics: dict[str, TopicIndex] = field(default_factory=dict)
    start_ns: int = 0
    end_ns: int = 0
    scans: list[ScanReport] = field(default_factory=list)
    orphans: int = 0

    @property
    def message_count(self) -> int:
        """Messages readable."""
        return sum(t.count for t in self.topics.values())

    @property
    def complete(self) -> bool:
        """Every MCAP file reached its end (no recorder killed while writing)."""
        return all(s.complete for s in self.scans)

    def notes(self) -> list[str]:
        """What a reader of this bag should be told, one sentence each."""
        names = ', '.join(p.name for p in self.files)
        out = [f'no metadata.yaml: reindexed in memory from {len(self.files)} '
               f'{self.storage_identifier} file(s) ({names}), as ros2 bag reindex would']
        if self.compression_mode:
            out.append(f'zstd {self.compression_mode} compression')
        for s in self.scans:
            if not s.complete:
                out.append(f'{s.path.name} is incomplete (recorder killed?): read '
                           f'{s.messages} messages up to offset {s.valid_bytes} of '
                           f'{s.size_bytes}: {s.stop_reason}')
            if s.skipped:
                out.append(f'{s.path.name}: skipped {len(s.skipped)} damaged parts '
                           f'({s.skipped_bytes} bytes)')
        if self.orphans:
            out.append(f'{self.orphans} messages of channels whose definition was lost '
                       'could not be read')
        return out


class _MessageStream:
    """Iterates the messages of storage files; fills a :class:`BagIndex` as it goes."""

    def __init__(self, index: BagIndex, stack: ExitStack) -> None:
        self.index = index
        self.stack = stack
        self.tmp: Path | None = None

    def _plain(self, path: Path) -> Path:
        """``path``, or its decompressed copy in a temporary directory for ``.zstd``."""
        if not path.name.endswith('.zstd'):
            return path
        if self.tmp is None:
            self.tmp = Path(self.stack.enter_context(tempfile.TemporaryDirectory()))
        out = self.tmp / path.name[:-5]
        try:
            out.write_bytes(DECOMPRESSORS['zstd'](path.read_bytes(), 0))
        except Exception as err:  # zstd raises its own error types
            raise BagFormatError(f'{path} is not a zstd-compressed bag file: '
                                 f'{" ".join(str(err).split())}') from err
        self.index.compression_mode = 'file'
        return out

    def _count(self, msg: IndexedMessage) -> IndexedMessage:
        ix = self.index
        topic = ix.topics.get(msg.topic)
        if topic is None:
            topic = ix.topics[msg.topic] = TopicIndex(msg.definition.msgtype)
        elif topic.msgtype != msg.definition.msgtype:
            raise BagFormatError(f'{ix.path}: topic {msg.topic} carries two types, '
                                 f'{topic.msgtype} and {msg.definition.msgtype}')
        topic.count += 1
        if not ix.start_ns or msg.log_time_ns < ix.start_ns:
            ix.start_ns = msg.log_time_ns
        ix.end_ns = max(ix.end_ns, msg.log_time_ns)
        if not ix.compression_mode and bytes(msg.data[:4]) == ZSTD_MAGIC:
            ix.compression_mode = 'message'
        return msg

    def _mcap(self, path: Path) -> Iterator[IndexedMessage]:
        scanner = McapScanner(path)
        self.index.scans.append(scanner.report)
        schemas: dict[int, McapSchema] = {}
        channels: dict[int, tuple[str, TypeDefinition] | None] = {}
        raw_channels: dict[int, McapChannel] = {}
        for rec in scanner:
            if isinstance(rec, McapSchema):
                schemas[rec.id] = rec
                channels.clear()
            elif isinstance(rec, McapChannel):
                raw_channels[rec.id] = rec
                channels.pop(rec.id, None)
            elif isinstance(rec, McapMessage):
                if rec.channel_id not in channels:
                    ch = raw_channels.get(rec.channel_id)
                    schema = schemas.get(ch.schema_id) if ch is not None else None
                    channels[rec.channel_id] = None if schema is None else (
                        ch.topic, TypeDefinition(schema.name, schema.encoding, schema.data,
                                                 ch.metadata.get('topic_type_hash', '')))
                    if schema is not None and ch.topic not in self.index.topics:
                        self.index.topics[ch.topic] = TopicIndex(
                            schema.name, 0, ch.metadata.get('offered_qos_profiles', ''))
                known = channels[rec.channel_id]
                if known is None:
                    self.index.orphans += 1
                    continue
                yield self._count(IndexedMessage(known[0], known[1], rec.log_time_ns,
                                                 rec.data))

    def _sqlite(self, path: Path) -> Iterator[IndexedMessage]:
        try:
            reader = Reader(path)
            reader.open()
        except Exception as err:  # rosbags and sqlite raise several unrelated types
            raise BagFormatError(f'{path} cannot be read as a sqlite3 bag file: '
                                 f'{" ".join(str(err).split())}') from err
        try:
            defs = {c.id: TypeDefinition.of_connection(c) for c in reader.connections}
            for conn, log_ns, data in reader.messages():
                yield self._count(IndexedMessage(conn.topic, defs[conn.id], log_ns, data))
        finally:
            reader.close()

    def __iter__(self) -> Iterator[IndexedMessage]:
        for path in self.index.files:
            plain = self._plain(path)
            yield from (self._mcap(plain) if plain.suffix == '.mcap' else self._sqlite(plain))


def _index_of(path: Path) -> BagIndex:
    files = storage_files(path) if path.is_dir() else [path]
    kind = _storage_suffix(files[0])
    if kind is None:
        raise BagFormatError(f'{path} is not a bag file (expected .mcap, .db3, .mcap.zstd or '
                             '.db3.zstd, or a bag directory)')
    return BagIndex(path, files, _STORAGES[kind[0]])


def storage_messages(path: Path, stack: ExitStack) -> tuple[BagIndex, Iterator[IndexedMessage]]:
    """The messages of a bag without ``metadata.yaml``, in file order.

    Parameters
    ----------
    path : pathlib.Path
        A bag directory without ``metadata.yaml``, or one storage file.
    stack : contextlib.ExitStack
        Holds the temporary directory of decompressed ``.zstd`` files; close it after
        iterating.

    Returns
    -------
    BagIndex
        Filled in while the messages are iterated (complete once they are exhausted).
    iterator of IndexedMessage
        Payloads as stored: decompress them with :func:`decompress_message`.

    Raises
    ------
    BagFormatError
        No storage file, mixed storages, a file that is not a bag file.
    """
    index = _index_of(path)
    return index, iter(_MessageStream(index, stack))


def reindex_bag(path: str | Path) -> BagIndex:
    """Index a bag directory without ``metadata.yaml`` in memory (nothing is written).

    Parameters
    ----------
    path : str or pathlib.Path
        A bag directory without ``metadata.yaml``, or one storage file.

    Returns
    -------
    BagIndex
        Files, storage, compression, topics with types and counts, time span, and how far
        each MCAP file was intact: what ``ros2 bag reindex`` would write.

    Raises
    ------
    BagFormatError
        No storage file, mixed storages, a file that is not a bag file.
    """
    with ExitStack() as stack:
        index, messages = storage_messages(Path(path), stack)
        for _ in messages:
            pass
    return index
