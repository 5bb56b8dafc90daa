"""Bags into numpy arrays: one :class:`TopicData` per topic, one array per field.

For analysis and reports: :func:`load_bag` reads a bag recorded by ``valve_recorder`` or
by ``ros2 bag record`` (MCAP or sqlite3) and returns, per topic, the bag timestamps and
every field of the messages as numpy arrays, nested fields flattened to dotted names
(``header.stamp.sec``). A bag whose recorder was killed (no ``metadata.yaml``, MCAP cut
off) is read up to its last complete chunk, with a warning.
"""
from __future__ import annotations

import contextlib
import logging
import operator
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import Nodetype
from rosbags.rosbag2 import Reader, ReaderError
from rosbags.typesys.store import Typestore

from ..errors import BagFormatError
from .qos import qos_summary
from .recovery import McapChannel, McapMessage, McapScanner, McapSchema, typestore_from_schemas

__all__ = ['TopicData', 'load_bag', 'bag_info', 'sequence_gaps', 'is_complete_bag']

_LOG = logging.getLogger(__name__)

_NUMPY_BASE = {
    'bool': np.bool_, 'byte': np.uint8, 'char': np.uint8, 'int8': np.int8, 'uint8': np.uint8,
    'int16': np.int16, 'uint16': np.uint16, 'int32': np.int32, 'uint32': np.uint32,
    'int64': np.int64, 'uint64': np.uint64, 'float32': np.float32, 'float64': np.float64,
    'string': np.str_, 'wstring': np.str_,
}


@dataclass
class TopicData:
    """The messages of one topic as arrays.

    Attributes
    ----------
    topic : str
        Topic name (with leading slash).
    msgtype : str
        ``pkg/msg/Name``.
    log_time_ns : numpy.ndarray of int64, shape (n,)
        Bag timestamps [ns since the epoch]: the receive time for ``valve_recorder`` and
        ``ros2 bag record``. Sorted (messages are returned in bag-time order).
    fields : dict of str to numpy.ndarray
        One array per field, first axis = message: numbers as their numpy type, strings as
        ``str`` arrays, fixed-length numeric sequences as 2-D arrays, ragged numeric
        sequences as object arrays of 1-D arrays, string sequences and sequences of
        messages as object arrays of lists. Nested messages are flattened with dots:
        ``header.stamp.sec``, ``header.frame_id``.
    """

    topic: str
    msgtype: str
    log_time_ns: np.ndarray
    fields: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.log_time_ns.size)

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.fields[name]
        except KeyError:
            raise KeyError(f'{self.topic} ({self.msgtype}) has no field {name!r}; it has '
                           f'{sorted(self.fields)}') from None

    @property
    def log_time_s(self) -> np.ndarray:
        """Bag timestamps [s since the epoch], float64 (0.24 us resolution; see
        :attr:`t_s`)."""
        return self.log_time_ns * 1e-9

    @property
    def t_s(self) -> np.ndarray:
        """Time since the first message [s], float64, from ``header.stamp`` when the type
        has a header, else from the bag timestamps. Formed from integer nanoseconds, so it
        keeps nanosecond resolution (epoch seconds in float64 have only 0.24 us)."""
        ns = self.stamp_ns
        if ns is None:
            ns = self.log_time_ns
        return (ns - ns[0]) * 1e-9 if ns.size else np.empty(0)

    @property
    def stamp_ns(self) -> np.ndarray | None:
        """``header.stamp`` [ns since the epoch], int64; ``None`` without a header."""
        if 'header.stamp.sec' not in self.fields:
            return None
        return (self.fields['header.stamp.sec'].astype(np.int64) * 1_000_000_000
                + self.fields['header.stamp.nanosec'].astype(np.int64))

    @property
    def stamp_s(self) -> np.ndarray | None:
        """``header.stamp`` [s since the epoch], float64; ``None`` without a header."""
        ns = self.stamp_ns
        return None if ns is None else ns * 1e-9


def sequence_gaps(sequence: np.ndarray) -> tuple[int, int]:
    """Gaps in a per-message counter such as ``ValveState.sequence``.

    Parameters
    ----------
    sequence : numpy.ndarray, shape (n,)
        Counter values in the order recorded.

    Returns
    -------
    tuple of (int, int)
        ``(gaps, lost)``: places where the counter jumps by more than one, and the
        messages missing there. Repeats and backward steps (a restarted publisher) are
        neither gaps nor losses.
    """
    seq = np.asarray(sequence, dtype=np.int64)
    if seq.size < 2:
        return 0, 0
    step = np.diff(seq)
    jumps = step[step > 1]
    return int(jumps.size), int(np.sum(jumps - 1))


# --------------------------------------------------------------------------------------
# flattening messages
# --------------------------------------------------------------------------------------

def _columns(store: Typestore, msgtype: str, prefix: str = '') -> list[tuple[str, str]]:
    """(dotted name, kind) of the leaf fields of ``msgtype``; kind is a base type name,
    ``seq:<base>`` for numeric/string sequences or ``object``."""
    out: list[tuple[str, str]] = []
    for name, (node, sub) in store.fielddefs[msgtype][1]:
        dotted = prefix + name
        if node == Nodetype.BASE:
            out.append((dotted, sub[0]))
        elif node == Nodetype.NAME:
            out.extend(_columns(store, sub, dotted + '.'))
        else:
            inner_node, inner = sub[0]
            out.append((dotted, f'seq:{inner[0]}' if inner_node == Nodetype.BASE else 'object'))
    return out


def _to_array(values: list, kind: str) -> np.ndarray:
    if kind.startswith('seq:'):
        base = kind[4:]
        lengths = {len(v) for v in values}
        if len(lengths) == 1 and base in _NUMPY_BASE and _NUMPY_BASE[base] is not np.str_:
            dtype = _NUMPY_BASE[base]
            if lengths == {0}:
                return np.empty((len(values), 0), dtype=dtype)
            return np.asarray([np.asarray(v) for v in values], dtype=dtype)
        arr = np.empty(len(values), dtype=object)
        arr[:] = [np.asarray(v) if base != 'string' else list(v) for v in values]
        return arr
    if kind == 'object':
        arr = np.empty(len(values), dtype=object)
        arr[:] = [list(v) for v in values]
        return arr
    dtype = _NUMPY_BASE.get(kind)
    return np.asarray(values, dtype=dtype) if dtype is not None else np.asarray(values)


def _concat(blocks: list[np.ndarray]) -> np.ndarray:
    """Join per-block arrays; 2-D blocks of different widths become one object array."""
    if len(blocks) == 1:
        return blocks[0]
    if len({b.shape[1:] for b in blocks}) == 1 and len({b.dtype for b in blocks}) == 1:
        return np.concatenate(blocks)
    out = np.empty(sum(len(b) for b in blocks), dtype=object)
    out[:] = [row for b in blocks for row in (list(b) if b.dtype == object else b)]
    return out


class _Accumulator:
    """Collects one topic's fields; converts to numpy every ``_BLOCK`` messages so a long
    bag does not sit in memory as Python objects."""

    _BLOCK = 65_536

    def __init__(self, topic: str, msgtype: str, store: Typestore) -> None:
        self.topic, self.msgtype, self.store = topic, msgtype, store
        self.columns = _columns(store, msgtype)
        self.getters = [operator.attrgetter(name) for name, _ in self.columns]
        self.values: list[list] = [[] for _ in self.columns]
        self.blocks: list[list[np.ndarray]] = [[] for _ in self.columns]
        self.times: list[int] = []

    def add(self, log_time_ns: int, raw: bytes | memoryview) -> None:
        msg = self.store.deserialize_cdr(raw, self.msgtype)
        self.times.append(log_time_ns)
        for get, col in zip(self.getters, self.values):
            col.append(get(msg))
        if len(self.values[0]) >= self._BLOCK:
            self._convert()

    def _convert(self) -> None:
        for (_, kind), col, blocks in zip(self.columns, self.values, self.blocks):
            if col:
                blocks.append(_to_array(col, kind))
                col.clear()

    def result(self) -> TopicData:
        self._convert()
        t = np.asarray(self.times, dtype=np.int64)
        sorted_ = not np.any(np.diff(t) < 0)
        order = None if sorted_ else np.argsort(t, kind='stable')
        fields = {}
        for (name, _), blocks in zip(self.columns, self.blocks):
            arr = _concat(blocks) if blocks else np.empty(0)
            fields[name] = arr if order is None else arr[order]
        return TopicData(self.topic, self.msgtype, t if order is None else t[order], fields)


# --------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------

def is_complete_bag(path: str | Path) -> bool:
    """True for a bag directory with ``metadata.yaml`` (closed properly, or recovered)."""
    return (Path(path) / 'metadata.yaml').is_file()


def _load_complete(path: Path, topics: set[str] | None) -> dict[str, TopicData]:
    try:
        reader = AnyReader([path])
        reader.open()
    except (AnyReaderError, ReaderError, OSError) as err:
        raise BagFormatError(f'{path} cannot be read as a rosbag2 bag: {err}') from err
    try:
        conns = [c for c in reader.connections if topics is None or c.topic in topics]
        accs: dict[str, _Accumulator] = {}
        for c in conns:
            accs.setdefault(c.topic, _Accumulator(c.topic, c.msgtype, reader.typestore))
        index = 0
        try:
            for conn, timestamp, raw in reader.messages(connections=conns):
                accs[conn.topic].add(timestamp, raw)
                index += 1
        except (BagFormatError, MemoryError):
            raise
        except Exception as err:  # a damaged chunk or message: the libraries raise many
            # types (OverflowError, struct.error, zstd errors, ...); one line for the user
            detail = ' '.join(str(err).split())
            raise BagFormatError(
                f'{path} is damaged after {index} messages ({type(err).__name__}: {detail}); '
                f'`valve_recorder --recover {path}` keeps the intact chunks') from err
    finally:
        with contextlib.suppress(Exception):  # closing a damaged bag may fail as well
            reader.close()
    return {t: a.result() for t, a in accs.items()}


def _load_scanned(path: Path, topics: set[str] | None) -> dict[str, TopicData]:
    scanner = McapScanner(path)
    schemas: dict[int, McapSchema] = {}
    channels: dict[int, McapChannel] = {}
    store: Typestore | None = None
    accs: dict[int, _Accumulator | None] = {}
    for rec in scanner:
        if isinstance(rec, McapSchema):
            schemas[rec.id] = rec
            store = None
        elif isinstance(rec, McapChannel):
            channels[rec.id] = rec
        elif isinstance(rec, McapMessage):
            acc = accs.get(rec.channel_id, False)
            if acc is False:
                ch = channels.get(rec.channel_id)
                if ch is None or ch.schema_id not in schemas or \
                        (topics is not None and ch.topic not in topics):
                    acc = None
                else:
                    if store is None:
                        store = typestore_from_schemas(schemas)
                    acc = _Accumulator(ch.topic, schemas[ch.schema_id].name, store)
                accs[rec.channel_id] = acc
            if acc is not None:
                acc.add(rec.log_time_ns, rec.data)
    if not scanner.report.complete:
        _LOG.warning('%s is incomplete (no metadata.yaml: recorder killed?); read %d messages '
                     'up to offset %d of %d: %s', path, scanner.report.messages,
                     scanner.report.valid_bytes, scanner.report.size_bytes,
                     scanner.report.stop_reason)
    out: dict[str, TopicData] = {}
    for acc in accs.values():
        if acc is None:
            continue
        data = acc.result()
        if acc.topic in out:  # one topic on several channels (several types is an error)
            prev = out[acc.topic]
            t = np.concatenate([prev.log_time_ns, data.log_time_ns])
            order = np.argsort(t, kind='stable')
            data = TopicData(acc.topic, prev.msgtype, t[order],
                             {k: np.concatenate([prev.fields[k], v])[order]
                              for k, v in data.fields.items()})
        out[acc.topic] = data
    return out


def load_bag(path: str | Path, topics: Iterable[str] | None = None, *,
             allow_incomplete: bool = True) -> dict[str, TopicData]:
    """Load a bag into numpy arrays, per topic and field.

    Parameters
    ----------
    path : str or pathlib.Path
        Bag directory (``metadata.yaml`` + ``.mcap`` or ``.db3``), or the ``.mcap`` file
        of a bag whose recorder was killed.
    topics : iterable of str, optional
        Topics to load (with or without leading slash); default all.
    allow_incomplete : bool
        Read a bag without ``metadata.yaml`` up to its last complete MCAP chunk (logs a
        warning). When False such a bag raises :class:`BagFormatError`.

    Returns
    -------
    dict of str to TopicData
        Keyed by topic name with leading slash, e.g. ``data['/valve/state']``. Message
        types are taken from the definitions embedded in the bag, so no ROS install is
        needed.

    Raises
    ------
    BagFormatError
        The path is not a readable bag.

    Examples
    --------
    >>> data = load_bag('valve_bag')                                     # doctest: +SKIP
    >>> state = data['/valve/state']                                     # doctest: +SKIP
    >>> t = state.t_s                      # s since the first stamp     # doctest: +SKIP
    >>> plt.plot(t, state['coil_current'])                               # doctest: +SKIP
    >>> sequence_gaps(state['sequence'])                                 # doctest: +SKIP
    (0, 0)
    """
    p = Path(path)
    wanted = None if topics is None else {t if t.startswith('/') else '/' + t for t in topics}
    if p.is_dir() and is_complete_bag(p):
        return _load_complete(p, wanted)
    if p.is_file() and p.suffix in ('.mcap', '.db3') and is_complete_bag(p.parent):
        return _load_complete(p.parent, wanted)
    if not p.exists():
        raise BagFormatError(f'{p} does not exist')
    if not allow_incomplete:
        raise BagFormatError(f'{p} has no metadata.yaml (recorder killed?); recover it with '
                             f'`valve_recorder --recover {p}` or pass allow_incomplete=True')
    return _load_scanned(p, wanted)


def _storage_id(files: list[str]) -> str:
    kinds = {'.mcap': 'mcap', '.db3': 'sqlite3'}
    return ', '.join(sorted({kinds[Path(f).suffix] for f in files})) or 'unknown'


def bag_info(path: str | Path) -> str:
    """A summary like ``ros2 bag info``: files, duration, messages, topics with QoS.

    Works on complete bags (from ``metadata.yaml``) and on killed ones (by scanning).
    """
    p = Path(path)
    if p.is_dir() and is_complete_bag(p):
        try:
            with Reader(p) as reader:
                files = [f.name for f in p.iterdir() if f.suffix in ('.mcap', '.db3')]
                size = sum(f.stat().st_size for f in p.iterdir() if f.is_file())
                lines = [
                    f'Files:             {", ".join(sorted(files))}',
                    f'Bag size:          {size / 1e6:.2f} MB',
                    f'Storage id:        {_storage_id(files)}',
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
    counts: dict[int, int] = {}
    channels: dict[int, McapChannel] = {}
    schemas: dict[int, McapSchema] = {}
    first, last = 2**63 - 1, 0
    scanner = McapScanner(p)
    for rec in scanner:
        if isinstance(rec, McapMessage):
            counts[rec.channel_id] = counts.get(rec.channel_id, 0) + 1
            first, last = min(first, rec.log_time_ns), max(last, rec.log_time_ns)
        elif isinstance(rec, McapChannel):
            channels[rec.id] = rec
        else:
            schemas[rec.id] = rec
    rep = scanner.report
    total = sum(counts.values())
    lines = [
        f'File:              {rep.path} (no metadata.yaml: '
        f'{"complete MCAP" if rep.complete else "INCOMPLETE, recorder killed?"})',
        f'Readable:          {rep.valid_bytes} of {rep.size_bytes} bytes, {rep.chunks} chunks'
        + ('' if rep.complete else f'; {rep.stop_reason}'),
        f'Duration:          {(last - first) * 1e-9 if total else 0.0:.3f} s',
        f'Messages:          {total}',
        'Topic information:',
    ]
    for cid, ch in sorted(channels.items(), key=lambda kv: kv[1].topic):
        msgtype = schemas[ch.schema_id].name if ch.schema_id in schemas else '?'
        lines.append(f'  Topic: {ch.topic} | Type: {msgtype} | Count: {counts.get(cid, 0)}')
    if not rep.complete:
        lines.append(f'Recover with:      valve_recorder --recover {p}')
    return '\n'.join(lines)
