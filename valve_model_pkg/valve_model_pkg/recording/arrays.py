"""Messages into numpy arrays: one :class:`TopicData` per topic, one array per field.

Nested messages are flattened to dotted names (``header.stamp.sec``); numbers keep their
numpy type, strings become ``str`` arrays, fixed-length numeric sequences 2-D arrays,
ragged numeric sequences object arrays of 1-D arrays, string sequences and sequences of
messages object arrays of lists.
"""
from __future__ import annotations

import operator
from dataclasses import dataclass, field

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.typesys.store import Typestore

__all__ = ['BLOCK_MESSAGES', 'TopicAccumulator', 'TopicData', 'sequence_gaps']

#: Messages a :class:`TopicAccumulator` holds as Python objects before it converts them to
#: numpy, so a long bag does not sit in memory as Python objects.
BLOCK_MESSAGES = 65_536

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


class PublisherSequenceGaps:
    """Messages lost before a subscriber, from the DDS publication sequence numbers.

    The numbers are per writer, and a received message does not say which writer sent it,
    so they are compared only while exactly one writer is matched: messages of several
    writers interleave their numbering, and a number kept from a writer that has left says
    nothing about the next one. The matched count is the subscription's own (DDS), which
    knows a writer before its first message arrives; the graph can lag it.
    """

    def __init__(self) -> None:
        self.lost = 0                   # messages missing between consecutive numbers
        self._last: int | None = None   # the single writer's last number

    def observe(self, sequence_number: int | None, matched_publishers: int) -> None:
        """Take one message's ``publication_sequence_number`` and the matched writers."""
        if sequence_number is None or matched_publishers != 1:
            self._last = None
            return
        last = self._last
        if last is not None and sequence_number > last + 1:
            self.lost += sequence_number - last - 1
        self._last = sequence_number


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


class TopicAccumulator:
    """Collects one topic's messages and returns them as a :class:`TopicData`.

    Converts to numpy every :data:`BLOCK_MESSAGES` messages, so a long bag does not sit in
    memory as Python objects.

    Parameters
    ----------
    topic : str
        Topic name (with leading slash).
    msgtype : str
        ``pkg/msg/Name``; ``store`` must know it.
    store : rosbags Typestore
        Deserialises the CDR payloads.
    """

    def __init__(self, topic: str, msgtype: str, store: Typestore) -> None:
        self.topic, self.msgtype, self.store = topic, msgtype, store
        self.block = BLOCK_MESSAGES
        self.columns = _columns(store, msgtype)
        self.getters = [operator.attrgetter(name) for name, _ in self.columns]
        self.values: list[list] = [[] for _ in self.columns]
        self.blocks: list[list[np.ndarray]] = [[] for _ in self.columns]
        self.times: list[int] = []

    def add(self, log_time_ns: int, raw: bytes | memoryview) -> None:
        """Deserialise one CDR message received at ``log_time_ns`` [ns] and keep it."""
        msg = self.store.deserialize_cdr(raw, self.msgtype)
        self.times.append(log_time_ns)
        for get, col in zip(self.getters, self.values):
            col.append(get(msg))
        if len(self.times) % self.block == 0:
            self._convert()

    def _convert(self) -> None:
        for (_, kind), col, blocks in zip(self.columns, self.values, self.blocks):
            if col:
                blocks.append(_to_array(col, kind))
                col.clear()

    def result(self) -> TopicData:
        """Everything added, in bag-time order (a stable sort keeps the order of equal
        timestamps)."""
        self._convert()
        t = np.asarray(self.times, dtype=np.int64)
        sorted_ = not np.any(np.diff(t) < 0)
        order = None if sorted_ else np.argsort(t, kind='stable')
        fields = {}
        for (name, _), blocks in zip(self.columns, self.blocks):
            arr = _concat(blocks) if blocks else np.empty(0)
            fields[name] = arr if order is None else arr[order]
        return TopicData(self.topic, self.msgtype, t if order is None else t[order], fields)
