"""Bags into numpy arrays: one :class:`~.arrays.TopicData` per topic, one array per field.

For analysis, reports and identification: :func:`load_bag` reads a rosbag2 bag as
``valve_recorder`` or ``ros2 bag record`` writes it (MCAP or sqlite3 storage, split into
several files, zstd file, message or MCAP chunk compression, ``metadata.yaml`` up to
version 9, ROS 2 Jazzy's) and returns, per topic, the bag timestamps and every field of
the messages as numpy arrays, nested fields flattened to dotted names
(``header.stamp.sec``). Messages are decoded with the definitions the bag embeds, else
with the installed ones (:func:`~.typestore.typestore_for_bag`). A bag without
``metadata.yaml`` is indexed in memory as ``ros2 bag reindex`` would
(:mod:`.reindex`); one whose recorder was killed (MCAP cut off) is read up to its last
complete chunk, with a warning.
"""
from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from rosbags.rosbag2 import Reader, ReaderError
from rosbags.typesys.store import Typestore

from ..errors import BagFormatError
from .arrays import TopicAccumulator, TopicData, sequence_gaps
from .qos import qos_summary
from .reindex import decompress_message, reindex_bag, storage_messages
from .typestore import TypeDefinition, typestore_for_bag

__all__ = ['BagContents', 'TopicData', 'bag_info', 'is_complete_bag', 'load_bag',
           'load_bag_contents', 'sequence_gaps']

_LOG = logging.getLogger(__name__)

_STORAGE_FILE = ('.mcap', '.db3', '.zstd')


@dataclass
class BagContents:
    """What :func:`load_bag_contents` read.

    Attributes
    ----------
    path : pathlib.Path
        The bag directory (or the storage file given).
    topics : dict of str to TopicData
        Keyed by topic name with leading slash; the topics asked for that the bag has.
    available : dict of str to str
        Every topic of the bag and its message type, loaded or not.
    notes : list of str
        What the reader noticed and a user should be told: a missing ``metadata.yaml``
        (reindexed in memory), a file cut off by a killed recorder, damaged parts skipped.
    """

    path: Path
    topics: dict[str, TopicData] = field(default_factory=dict)
    available: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def is_complete_bag(path: str | Path) -> bool:
    """True for a bag directory with ``metadata.yaml`` (closed properly, or recovered)."""
    return (Path(path) / 'metadata.yaml').is_file()


def _one_line(err: BaseException) -> str:
    return ' '.join(str(err).split()) or type(err).__name__


class _Topics:
    """Accumulators per topic, each with a typestore that knows its type."""

    def __init__(self, path: Path, wanted: set[str] | None) -> None:
        self.path, self.wanted = path, wanted
        self.definitions: dict[str, TypeDefinition] = {}
        self.store: Typestore | None = None
        self.accs: dict[str, TopicAccumulator] = {}

    def know(self, definitions: Iterable[TypeDefinition]) -> None:
        """Decode with these definitions (the typestore is rebuilt when one is new)."""
        for d in definitions:
            if d.msgtype not in self.definitions:
                self.definitions[d.msgtype] = d
                self.store = None

    def accumulator(self, topic: str, definition: TypeDefinition) -> TopicAccumulator | None:
        acc = self.accs.get(topic)
        if acc is not None or (self.wanted is not None and topic not in self.wanted):
            return acc
        self.know([definition])
        if self.store is None:
            self.store = typestore_for_bag(self.definitions.values(), str(self.path))
        acc = self.accs[topic] = TopicAccumulator(topic, definition.msgtype, self.store)
        return acc

    def result(self) -> dict[str, TopicData]:
        return {t: a.result() for t, a in self.accs.items()}


def _read_messages(path: Path, topics: _Topics,
                   messages: Iterator[tuple[str, TypeDefinition, int, bytes | memoryview]]
                   ) -> None:
    """Feed ``messages`` to the accumulators; a damaged one ends in one line."""
    index = 0
    try:
        for topic, definition, log_ns, raw in messages:
            acc = topics.accumulator(topic, definition)
            if acc is not None:
                acc.add(log_ns, decompress_message(raw))
            index += 1
    except (BagFormatError, MemoryError):
        raise
    except Exception as err:  # a damaged chunk or message: the libraries raise many
        # types (OverflowError, struct.error, zstd errors, ...); one line for the user
        raise BagFormatError(
            f'{path} is damaged after {index} messages ({type(err).__name__}: '
            f'{_one_line(err)}); `valve_recorder --recover {path}` keeps the intact chunks'
        ) from err


def _load_complete(path: Path, wanted: set[str] | None) -> BagContents:
    try:
        reader = Reader(path)
        reader.open()
    except (ReaderError, OSError, KeyError, ValueError, TypeError) as err:
        raise BagFormatError(f'{path} cannot be read as a rosbag2 bag: {_one_line(err)}'
                             ) from err
    except Exception as err:  # decompressing a damaged .zstd file, a damaged database
        raise BagFormatError(f'{path} cannot be read as a rosbag2 bag ({type(err).__name__}: '
                             f'{_one_line(err)})') from err
    try:
        available = {c.topic: c.msgtype for c in reader.connections}
        conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
        types: dict[str, str] = {}
        for c in conns:
            if types.setdefault(c.topic, c.msgtype) != c.msgtype:
                raise BagFormatError(f'{path}: topic {c.topic} carries two types, '
                                     f'{types[c.topic]} and {c.msgtype}')
        defs = {c.id: TypeDefinition.of_connection(c) for c in conns}
        topics = _Topics(path, wanted)
        topics.know(defs.values())
        for c in conns:
            topics.accumulator(c.topic, defs[c.id])
        if conns:
            _read_messages(path, topics, ((c.topic, defs[c.id], t, raw)
                                          for c, t, raw in reader.messages(connections=conns)))
    finally:
        with contextlib.suppress(Exception):  # closing a damaged bag may fail as well
            reader.close()
    return BagContents(path, topics.result(), available)


def _load_reindexed(path: Path, wanted: set[str] | None) -> BagContents:
    topics = _Topics(path, wanted)
    with contextlib.ExitStack() as stack:
        index, messages = storage_messages(path, stack)
        _read_messages(path, topics, ((m.topic, m.definition, m.log_time_ns, m.data)
                                      for m in messages))
    notes = index.notes()
    if index.complete:
        _LOG.warning('%s: %s', path, '; '.join(notes))
    else:
        _LOG.warning('%s is incomplete (no metadata.yaml: recorder killed?); %s', path,
                     '; '.join(notes))
    return BagContents(path, topics.result(),
                       {t: i.msgtype for t, i in index.topics.items()}, notes)


def load_bag_contents(path: str | Path, topics: Iterable[str] | None = None, *,
                      allow_incomplete: bool = True) -> BagContents:
    """Load a bag into numpy arrays, with what the reader noticed.

    Same as :func:`load_bag` (see there for the parameters), but returns a
    :class:`BagContents`, whose ``notes`` say whether the bag was reindexed, cut off or
    damaged.
    """
    p = Path(path)
    wanted = None if topics is None else {t if t.startswith('/') else '/' + t for t in topics}
    if p.is_dir() and is_complete_bag(p):
        return _load_complete(p, wanted)
    if p.is_file() and p.name.endswith(_STORAGE_FILE) and is_complete_bag(p.parent):
        return _load_complete(p.parent, wanted)
    if not p.exists():
        raise BagFormatError(f'{p} does not exist')
    if not allow_incomplete:
        raise BagFormatError(f'{p} has no metadata.yaml (recorder killed?); recover it with '
                             f'`valve_recorder --recover {p}` or pass allow_incomplete=True')
    return _load_reindexed(p, wanted)


def load_bag(path: str | Path, topics: Iterable[str] | None = None, *,
             allow_incomplete: bool = True) -> dict[str, TopicData]:
    """Load a bag into numpy arrays, per topic and field.

    Parameters
    ----------
    path : str or pathlib.Path
        Bag directory (``metadata.yaml`` and its ``.mcap`` or ``.db3`` files, possibly
        split and zstd-compressed), one storage file of it, or a bag directory or ``.mcap``
        file without ``metadata.yaml`` (reindexed in memory; a killed recorder's file is
        read up to its last complete chunk).
    topics : iterable of str, optional
        Topics to load (with or without leading slash); default all.
    allow_incomplete : bool
        Read a bag without ``metadata.yaml`` (logs a warning). When False such a bag raises
        :class:`BagFormatError`.

    Returns
    -------
    dict of str to TopicData
        Keyed by topic name with leading slash, e.g. ``data['/valve/state']``. Message
        types are taken from the definitions embedded in the bag (else from the installed
        ``.msg`` files), so no ROS install is needed.

    Raises
    ------
    BagFormatError
        The path is not a readable bag.
    UnknownMessageTypeError
        A type the bag neither embeds nor finds installed.

    Examples
    --------
    >>> data = load_bag('valve_bag')                                     # doctest: +SKIP
    >>> state = data['/valve/state']                                     # doctest: +SKIP
    >>> t = state.t_s                      # s since the first stamp     # doctest: +SKIP
    >>> plt.plot(t, state['coil_current'])                               # doctest: +SKIP
    >>> sequence_gaps(state['sequence'])                                 # doctest: +SKIP
    (0, 0)
    """
    return load_bag_contents(path, topics, allow_incomplete=allow_incomplete).topics


def _storage_id(files: list[str]) -> str:
    kinds = {'.mcap': 'mcap', '.db3': 'sqlite3'}
    return ', '.join(sorted({kinds[Path(f.removesuffix('.zstd')).suffix] for f in files})) \
        or 'unknown'


def bag_info(path: str | Path) -> str:
    """A summary like ``ros2 bag info``: files, duration, messages, topics with QoS.

    Works on complete bags (from ``metadata.yaml``), on bags without it (reindexed in
    memory) and on killed ones (read up to their last complete chunk).
    """
    p = Path(path)
    if p.is_dir() and is_complete_bag(p):
        try:
            with Reader(p) as reader:
                files = [f.name for f in p.iterdir()
                         if f.name.endswith(_STORAGE_FILE) and f.name != 'metadata.yaml']
                size = sum(f.stat().st_size for f in p.iterdir() if f.is_file())
                lines = [
                    f'Files:             {", ".join(sorted(files))}',
                    f'Bag size:          {size / 1e6:.2f} MB',
                    f'Storage id:        {_storage_id(files)}',
                    f'Compression:       {reader.compression_mode or "none"}',
                    f'Duration:          {reader.duration * 1e-9:.3f} s',
                    f'Start:             {reader.start_time * 1e-9:.6f} (epoch s)',
                    f'End:               {reader.end_time * 1e-9:.6f} (epoch s)',
                    f'Messages:          {reader.message_count}',
                    'Topic information:',
                ]
                for c in sorted(reader.connections, key=lambda c: c.topic):
                    lines.append(f'  Topic: {c.topic} | Type: {c.msgtype} | Count: '
                                 f'{c.msgcount} | Serialization Format: '
                                 f'{c.ext.serialization_format} | QoS: '
                                 f'{qos_summary(list(c.ext.offered_qos_profiles))}')
                return '\n'.join(lines)
        except ReaderError as err:
            raise BagFormatError(f'{p} cannot be read as a rosbag2 bag: {err}') from err
    return _reindexed_info(p)


def _reindexed_info(path: Path) -> str:
    """``bag_info`` of a bag without ``metadata.yaml``, from its in-memory index."""
    index = reindex_bag(path)
    if len(index.scans) == 1 and len(index.files) == 1:
        rep = index.scans[0]
        lines = [f'File:              {rep.path} (no metadata.yaml: '
                 f'{"complete MCAP" if rep.complete else "INCOMPLETE, recorder killed?"})',
                 f'Readable:          {rep.valid_bytes} of {rep.size_bytes} bytes, '
                 f'{rep.chunks} chunks' + ('' if rep.complete else f'; {rep.stop_reason}')]
    else:
        state = 'reindexed in memory' if index.complete else \
            'INCOMPLETE, recorder killed?; reindexed in memory'
        lines = [f'Files:             {", ".join(f.name for f in index.files)} '
                 f'(no metadata.yaml: {state})',
                 f'Storage id:        {index.storage_identifier}']
    total = index.message_count
    lines += [
        f'Duration:          {(index.end_ns - index.start_ns) * 1e-9 if total else 0.0:.3f} s',
        f'Messages:          {total}',
        'Topic information:',
    ]
    for topic, info in sorted(index.topics.items()):
        lines.append(f'  Topic: {topic} | Type: {info.msgtype} | Count: {info.count}')
    if not index.complete:
        lines.append(f'Recover with:      valve_recorder --recover {path}')
    return '\n'.join(lines)
