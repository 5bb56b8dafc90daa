"""Writing rosbag2 bags in MCAP storage from serialized (CDR) messages, with rosbags.

The bag is what ``ros2 bag record -s mcap`` writes, readable by ``ros2 bag info/play``,
Foxglove, PlotJuggler and rosbags:

* a directory with ``metadata.yaml`` (rosbag2 version 9 and ``ros_distro: jazzy``, as ROS 2
  Jazzy writes it) and ``<name>.mcap`` (profile ``ros2``);
* every topic's message definition embedded as an MCAP schema, encoding ``ros2msg``, with
  its dependencies appended (the form rosbag2 uses), and its RIHS01 type hash in
  ``metadata.yaml``;
* every topic's offered QoS profiles in ``metadata.yaml`` and in the MCAP channel
  metadata, so ``ros2 bag play`` offers the same reliability and durability again;
* each MCAP channel's metadata holds ``offered_qos_profiles`` and ``topic_type_hash`` (the
  RIHS01 hash), the two keys rosbag2's MCAP storage plugin writes and reads back as the
  topic's ``type_description_hash``.

Messages are written as the CDR bytes they arrived in: no deserialisation, nothing lost.

Flush policy (what survives a killed writer)
--------------------------------------------
MCAP keeps its index and summary at the end of the file, and rosbag2 writes
``metadata.yaml`` on close, so a writer killed with SIGKILL leaves neither. What it does
leave is every *chunk* that reached the operating system. :class:`BagWriter` closes the
pending chunk and flushes it to the OS every ``flush_period_s`` (and rosbags closes a
chunk when it exceeds 1 MiB), optionally followed by ``fsync`` so the chunk also survives a
power cut. A killed writer therefore loses at most the messages of the last
``flush_period_s`` (plus what was still queued in memory); everything before is recovered
by :func:`valve_model_pkg.recording.recovery.recover_bag`.
"""
from __future__ import annotations

import logging
import os
import queue
import re
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from types import TracebackType
from typing import Literal, cast

from rosbags.interfaces import Connection, ConnectionExtRosbag2, Qos
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.rosbag2.storage_mcap import Channel, McapWriter, write_channel, write_string
from rosbags.typesys.store import Typestore

from ..errors import BagWriteError, RecordingError
from .typestore import build_typestore, ensure_type, msgdef_and_hash

__all__ = ['BAG_VERSION', 'ROS_DISTRO', 'BagWriter', 'QueuedBagWriter', 'WriterStats',
           'absolute_topic']

_LOG = logging.getLogger(__name__)

#: rosbag2 metadata version ROS 2 Jazzy writes (QoS profiles as a YAML list of names).
BAG_VERSION: Literal[9] = 9

#: The ROS distribution the bags are written for (``ros_distro`` of the bag metadata, as
#: rosbag2 writes it; rosbags would write its own name there).
ROS_DISTRO = 'jazzy'

# rosbags writes ``ros_distro: rosbags`` into metadata.yaml and into the MCAP file's
# ``rosbag2`` metadata record; both are rewritten to :data:`ROS_DISTRO`.
_ROS_DISTRO_LINE = re.compile(r'^(\s*ros_distro:[ \t]*)\S.*$', re.MULTILINE)


def _with_ros_distro(text: str, where: str) -> str:
    """``text`` (rosbag2 metadata YAML) with ``ros_distro`` set to :data:`ROS_DISTRO`."""
    new, n = _ROS_DISTRO_LINE.subn(lambda m: m.group(1) + ROS_DISTRO, text)
    if n != 1:
        # rosbags is pinned; an upgrade that changes its metadata must fail loudly here
        raise BagWriteError(f'{where}: expected one ros_distro line in the bag metadata, '
                            f'found {n}')
    return new


def absolute_topic(topic: str) -> str:
    """``topic`` with a leading slash, as rosbag2 stores names (root namespace assumed)."""
    return topic if topic.startswith('/') else '/' + topic


class _FlushableMcapWriter(McapWriter):
    """rosbags' MCAP storage writer that can push its pending chunk to disk on demand.

    rosbags keeps the pending chunk in memory until it exceeds 1 MiB; at 1 kHz of
    ValveState that is about 7 s of data. :meth:`flush` closes the pending chunk early
    (a complete chunk record plus its message index) and hands the bytes to the OS.
    Relies on ``McapWriter.chunk``, ``close_chunk`` and ``bio`` of rosbags 0.11 (pinned; a
    unit test fails if they change).
    """

    def add_connection(self, connection: Connection, offered_qos_profiles: str) -> None:
        """Add the channel with the metadata rosbag2's MCAP storage writes.

        rosbags writes ``offered_qos_profiles`` only; rosbag2 (``MCAPStorage::create_topic``)
        also writes ``topic_type_hash``, the RIHS01 type description hash, which it reads
        back as the topic's ``type_description_hash``. Otherwise as rosbags'
        ``McapWriter.add_connection``.
        """
        metadata = BytesIO()
        for key, value in (('offered_qos_profiles', offered_qos_profiles),
                           ('topic_type_hash', connection.digest)):
            write_string(metadata, key)
            write_string(metadata, value)
        self.channels.append(Channel(
            connection.id, connection.msgtype, connection.topic,
            cast(ConnectionExtRosbag2, connection.ext).serialization_format,
            metadata.getvalue()))
        self.channel_stats[connection.id] = 0
        write_channel(self.chunk.bio, self.channels[-1], self.schemas)

    def close(self, version: int, metadata: str) -> None:
        """Close with ``ros_distro`` in the MCAP ``rosbag2`` record set to :data:`ROS_DISTRO`.
        """
        super().close(version, _with_ros_distro(metadata, str(self.path)))

    def flush(self, fsync: bool) -> bool:
        """Close the pending chunk if it holds messages; flush (and fsync) the file.

        Returns
        -------
        bool
            True if a chunk was closed.
        """
        closed = False
        if self.chunk.msgs:
            self.close_chunk()
            closed = True
        self.bio.flush()
        if fsync:
            os.fsync(self.bio.fileno())
        return closed


class _Rosbag2Writer(Writer):
    """rosbags' rosbag2 writer using :class:`_FlushableMcapWriter` for MCAP storage, and
    ``ros_distro`` in ``metadata.yaml`` set to :data:`ROS_DISTRO`."""

    STORAGE_PLUGINS = {**Writer.STORAGE_PLUGINS, StoragePlugin.MCAP: _FlushableMcapWriter}

    def close(self) -> None:
        """Close as rosbags does, then set ``ros_distro`` in ``metadata.yaml``."""
        super().close()
        text = self.metapath.read_text(encoding='utf-8')
        tmp = self.metapath.with_suffix('.yaml.tmp')
        tmp.write_text(_with_ros_distro(text, str(self.metapath)), encoding='utf-8')
        tmp.replace(self.metapath)  # atomic: a reader sees the old or the new file


class BagWriter:
    """A rosbag2 bag (MCAP storage) written from serialized messages.

    Parameters
    ----------
    path : str or pathlib.Path
        Bag directory to create; it must not exist.
    typestore : rosbags Typestore, optional
        Where message definitions come from; default :func:`build_typestore` (ROS 2 Jazzy
        types plus ``valve_msgs``). Types missing from it are looked up in ``.msg`` files
        of the ament prefixes when a topic is added.
    flush_period_s : float
        Longest time a written message stays in memory before its chunk is closed and
        flushed to the OS [s]; bounds what a killed writer loses. ``0`` flushes only when
        rosbags closes a chunk (1 MiB) and on :meth:`close`.
    fsync : bool
        Also ``fsync`` after each flush (survives a power cut, not only a killed process).
    compression : {'none', 'zstd'}
        MCAP chunk compression (what ``ros2 bag record -s mcap --storage-preset-profile
        zstd_fast`` does); every MCAP reader decompresses it transparently.
    custom_data : mapping of str to str, optional
        Stored in ``metadata.yaml`` under ``custom_data``.
    clock : callable
        Monotonic clock [s] for the flush period (tests substitute it).

    Notes
    -----
    Use it as a context manager or call :meth:`open` and :meth:`close`. Not thread-safe:
    one thread writes (see :class:`QueuedBagWriter` for producers on other threads).
    """

    def __init__(self, path: str | Path, typestore: Typestore | None = None, *,
                 flush_period_s: float = 1.0, fsync: bool = True,
                 compression: str = 'none', custom_data: Mapping[str, str] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not flush_period_s >= 0.0:
            raise ValueError(f'flush_period_s must be >= 0, got {flush_period_s!r}')
        if compression not in ('none', 'zstd'):
            raise ValueError(f"compression must be 'none' or 'zstd', got {compression!r}")
        self.path = Path(path)
        self.typestore = typestore if typestore is not None else build_typestore()
        self.flush_period_s = float(flush_period_s)
        self.fsync = bool(fsync)
        self.compression = compression
        self._clock = clock
        try:
            self._writer = _Rosbag2Writer(self.path, version=BAG_VERSION,
                                          storage_plugin=StoragePlugin.MCAP)
        except WriterError as err:
            raise BagWriteError(f'cannot create bag {self.path}: {err}') from err
        if compression == 'zstd':
            self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        for key, value in (custom_data or {}).items():
            self._writer.set_custom_data(str(key), str(value))
        self._connections: dict[str, Connection] = {}
        self._opened = False
        self._closed = False
        self._next_flush = float('inf')
        self.message_count = 0
        """Messages written (handed to the storage), all topics."""
        self.flushed_count = 0
        """Messages known to be in the file on the OS side (as of the last flush)."""
        self.bytes_written = 0
        """Payload bytes written, all topics."""
        self.flush_count = 0
        """Flushes that closed a chunk."""
        self.counts: dict[str, int] = {}
        """Messages written per topic."""

    # --- life cycle ---------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        """True between :meth:`open` and :meth:`close` / :meth:`abort`."""
        return self._opened and not self._closed

    @property
    def mcap_path(self) -> Path:
        """The MCAP file inside the bag directory."""
        return self.path / f'{self.path.name}.mcap'

    def open(self) -> BagWriter:
        """Create the bag directory and the MCAP file.

        Raises
        ------
        BagWriteError
            The directory exists already or cannot be created.
        """
        if self._opened:
            raise BagWriteError(f'bag {self.path} is already open')
        try:
            self._writer.open()
        except WriterError as err:
            raise BagWriteError(f'cannot create bag {self.path}: {err}') from err
        except OSError as err:
            raise BagWriteError(f'cannot create bag {self.path}: {err.strerror}') from err
        self._opened = True
        self._next_flush = self._clock() + self.flush_period_s if self.flush_period_s else \
            float('inf')
        _LOG.info('recording to %s (flush every %g s, fsync %s, compression %s)',
                  self.path, self.flush_period_s, self.fsync, self.compression)
        return self

    def close(self) -> None:
        """Write the last chunk, the MCAP summary and ``metadata.yaml``. Idempotent.

        Raises
        ------
        BagWriteError
            Writing failed (the MCAP file stays recoverable up to its last flushed chunk).
        """
        if self._closed or not self._opened:
            self._closed = True
            return
        self._closed = True
        try:
            self._writer.close()
        except (WriterError, OSError) as err:
            raise BagWriteError(f'closing bag {self.path} failed: {err}') from err
        self.flushed_count = self.message_count
        _LOG.info('closed %s: %d messages on %d topics', self.path, self.message_count,
                  len(self._connections))

    def abort(self) -> None:
        """Close the file without summary or metadata (it stays recoverable)."""
        if self._opened and not self._closed:
            self._closed = True
            self._writer.abort()

    def __enter__(self) -> BagWriter:
        return self.open()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    # --- topics and messages ------------------------------------------------------------
    @property
    def topics(self) -> dict[str, str]:
        """Topic -> message type of the topics added so far."""
        return {t: c.msgtype for t, c in self._connections.items()}

    def add_topic(self, topic: str, msgtype: str, offered_qos: Iterable[Qos] = (), *,
                  msgdef: str | None = None, type_hash: str | None = None) -> Connection:
        """Add a topic; returns the handle to pass to :meth:`write`.

        Parameters
        ----------
        topic : str
            Topic name; stored with a leading slash.
        msgtype : str
            ``pkg/msg/Name``.
        offered_qos : iterable of rosbags Qos
            QoS profiles the topic's publishers offer (one per publisher), recorded for
            ``ros2 bag play``; see :func:`valve_model_pkg.recording.qos.make_qos`.
        msgdef, type_hash : str, optional
            Message definition (``ros2msg`` text, dependencies appended) and RIHS01 hash;
            by default generated from the typestore (the type is registered from its
            ``.msg`` file if the typestore lacks it).

        Raises
        ------
        UnknownMessageTypeError
            No definition of ``msgtype`` is known.
        BagWriteError
            The bag is not open, or the topic was added before with another type.
        """
        if not self._opened or self._closed:
            raise BagWriteError(f'bag {self.path} is not open')
        topic = absolute_topic(topic)
        if topic in self._connections:
            have = self._connections[topic]
            if have.msgtype != msgtype:
                raise BagWriteError(f'topic {topic} was added as {have.msgtype}, '
                                    f'not {msgtype}')
            return have
        if msgdef is None or type_hash is None:
            ensure_type(self.typestore, msgtype)
            msgdef, type_hash = msgdef_and_hash(self.typestore, msgtype)
        try:
            conn = self._writer.add_connection(topic, msgtype, msgdef=msgdef, rihs01=type_hash,
                                               offered_qos_profiles=list(offered_qos))
        except WriterError as err:
            raise BagWriteError(f'cannot add topic {topic} to {self.path}: {err}') from err
        self._connections[topic] = conn
        self.counts[topic] = 0
        _LOG.debug('topic %s (%s) added to %s', topic, msgtype, self.path)
        return conn

    def write(self, connection: Connection, timestamp_ns: int, data: bytes | memoryview) -> None:
        """Write one serialized (CDR) message, then flush if the flush period is over.

        Parameters
        ----------
        connection : Connection
            Handle from :meth:`add_topic`.
        timestamp_ns : int
            Bag timestamp (MCAP log time) [ns since the epoch].
        data : bytes
            The message as CDR, encapsulation header included (what a raw rclpy
            subscription delivers).
        """
        self._writer.write(connection, timestamp_ns, data)
        self.message_count += 1
        self.bytes_written += len(data)
        self.counts[connection.topic] += 1
        if self._clock() >= self._next_flush:
            self.flush()

    def flush(self) -> None:
        """Close the pending chunk (if it holds messages) and push the file to the OS."""
        if not self._opened or self._closed:
            return
        storage = self._writer.storage
        if storage is not None and self.flushed_count != self.message_count:
            if storage.flush(self.fsync):
                self.flush_count += 1
            self.flushed_count = self.message_count
        if self.flush_period_s:
            self._next_flush = self._clock() + self.flush_period_s

    def flush_if_due(self) -> bool:
        """Flush if the flush period is over; returns True if it flushed."""
        if self._opened and not self._closed and self._clock() >= self._next_flush:
            self.flush()
            return True
        return False

    def seconds_to_next_flush(self) -> float:
        """Time until the next periodic flush [s] (``inf`` without a period)."""
        return max(0.0, self._next_flush - self._clock())


@dataclass(frozen=True)
class WriterStats:
    """A snapshot of a :class:`QueuedBagWriter`'s counters."""

    received: int          #: messages handed to :meth:`QueuedBagWriter.put`
    written: int           #: messages written to the storage
    flushed: int           #: messages in the file on the OS side (last flush)
    queued: int            #: messages waiting in the queue now
    queue_high_water: int  #: most messages ever waiting
    bytes_written: int     #: payload bytes written
    chunks_flushed: int    #: flushes that closed a chunk
    error: str             #: why the writer thread stopped ('' while healthy)


_STOP = object()


class QueuedBagWriter:
    """A :class:`BagWriter` driven by a thread of its own; producers only enqueue bytes.

    A subscription callback must return quickly for the executor to keep up with 1 kHz;
    :meth:`put` only appends ``(key, timestamp, bytes)`` to an unbounded queue. The thread
    writes, flushes every ``flush_period_s`` even when no message comes, and on
    :meth:`close` drains the queue before closing the bag.

    Parameters
    ----------
    writer : BagWriter
        Opened by :meth:`start` if not open yet.
    batch : int
        Most messages written between two checks of the flush deadline.
    """

    def __init__(self, writer: BagWriter, *, batch: int = 512) -> None:
        self.writer = writer
        self._batch = int(batch)
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._keys: dict[int, Connection] = {}
        self._topics: dict[str, int] = {}
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._received = 0
        self._high_water = 0
        self._closed = False

    # --- producer side (any thread) -------------------------------------------------------
    def start(self) -> QueuedBagWriter:
        """Open the bag (if needed) and start the writer thread."""
        if self._thread is not None:
            raise RecordingError('writer thread already started')
        if not self.writer.is_open:
            self.writer.open()
        self._thread = threading.Thread(target=self._run, name='bag-writer', daemon=True)
        self._thread.start()
        return self

    def add_topic(self, topic: str, msgtype: str, offered_qos: Iterable[Qos] = ()) -> int:
        """Add a topic (definition looked up now, on the caller's thread); returns its key.

        Raises
        ------
        UnknownMessageTypeError
            No definition of ``msgtype`` is known.
        """
        topic = absolute_topic(topic)
        with self._lock:
            if topic in self._topics:
                return self._topics[topic]
            ensure_type(self.writer.typestore, msgtype)
            msgdef, type_hash = msgdef_and_hash(self.writer.typestore, msgtype)
            key = len(self._topics) + 1
            self._topics[topic] = key
        self._queue.put(('add', key, topic, msgtype, tuple(offered_qos), msgdef, type_hash))
        return key

    def put(self, key: int, timestamp_ns: int, data: bytes) -> None:
        """Queue one serialized message for writing.

        Raises
        ------
        BagWriteError
            The writer thread has stopped on an error (its message is the cause).
        """
        if self._error is not None:
            raise BagWriteError(f'bag writer stopped: {self._error}') from self._error
        self._received += 1
        self._queue.put((key, timestamp_ns, data))

    @property
    def error(self) -> BaseException | None:
        """The exception that stopped the writer thread, if any."""
        return self._error

    def stats(self) -> WriterStats:
        """Current counters (read without locking; each value is consistent on its own)."""
        w = self.writer
        return WriterStats(received=self._received, written=w.message_count,
                           flushed=w.flushed_count, queued=self._queue.qsize(),
                           queue_high_water=self._high_water, bytes_written=w.bytes_written,
                           chunks_flushed=w.flush_count,
                           error='' if self._error is None else str(self._error))

    def close(self, timeout_s: float | None = 60.0) -> WriterStats:
        """Write what is queued, close the bag, stop the thread. Idempotent.

        Raises
        ------
        BagWriteError
            The writer thread failed, or did not finish within ``timeout_s``.
        """
        if not self._closed:
            self._closed = True
            if self._thread is not None:
                self._queue.put(_STOP)
                self._thread.join(timeout_s)
                if self._thread.is_alive():
                    raise BagWriteError(f'bag writer did not finish within {timeout_s} s '
                                        f'({self._queue.qsize()} messages still queued)')
            else:
                self.writer.close()
        if self._error is not None:
            raise BagWriteError(f'bag writer failed: {self._error}') from self._error
        return self.stats()

    # --- writer thread ------------------------------------------------------------------
    def _handle(self, item: tuple) -> None:
        if item[0] == 'add':
            _, key, topic, msgtype, qos, msgdef, type_hash = item
            self._keys[key] = self.writer.add_topic(topic, msgtype, qos, msgdef=msgdef,
                                                    type_hash=type_hash)
        else:
            key, timestamp_ns, data = item
            self.writer.write(self._keys[key], timestamp_ns, data)

    def _run(self) -> None:
        w = self.writer
        q = self._queue
        try:
            while True:
                try:
                    item = q.get(timeout=min(w.seconds_to_next_flush(), 0.5))
                except queue.Empty:
                    w.flush_if_due()
                    continue
                depth = q.qsize() + 1
                if depth > self._high_water:
                    self._high_water = depth
                n = 0
                while True:
                    if item is _STOP:
                        w.close()
                        return
                    self._handle(item)
                    n += 1
                    if n >= self._batch:
                        break
                    try:
                        item = q.get_nowait()
                    except queue.Empty:
                        break
                w.flush_if_due()
        except BaseException as err:  # disk full, bad data: stop, keep what is on disk
            self._error = err
            _LOG.error('bag writer for %s stopped: %s', w.path, err)
            try:
                w.abort()
            except Exception:  # noqa: BLE001 - already failing; the first error is kept
                pass
