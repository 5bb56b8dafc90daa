"""Chosen numeric fields of a bag's topics as time series: ``TOPIC`` or ``TOPIC.FIELD``.

A user's firmware publishes the coil current on a topic of its own, as a
``std_msgs/msg/Float64`` (``/coil/current``: its ``data``) or as one field of a message of
its own (``/drive/telemetry.coil.current``: nested fields with dots, ``/js.position[0]``:
one element of a sequence). :func:`read_fields` reads such fields from any bag
:func:`~.reader.load_bag` reads and times each by the message's ``header.stamp`` when its
type has a header (and the stamps are set), else by the bag's receive (log) time; the
returned record says which in its notes.
"""
from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import BagFormatError
from .arrays import TopicData
from .reader import load_bag_contents

__all__ = ['FieldRecord', 'FieldSeries', 'FieldSpec', 'read_fields']

_TOPIC = re.compile(r'~?/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*')
_FIELD = re.compile(r'[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*(\[(\d+)\])?')
#: Field of a message without a named field: std_msgs Float32/Float64/Int*/Bool.
DEFAULT_FIELD = 'data'
#: How a series is timed (see :attr:`FieldSeries.time_source`).
HEADER_STAMP = 'header stamps'
RECEIVE_TIME = 'receive times'


@dataclass(frozen=True)
class FieldSpec:
    """One numeric field of a topic.

    Attributes
    ----------
    topic : str
        Topic name with leading slash.
    field : str
        Dotted field name (``data``, ``coil_current``, ``coil.current``).
    index : int or None
        Element of a sequence field (``position[0]``); ``None`` for a scalar field.
    """

    topic: str
    field: str = DEFAULT_FIELD
    index: int | None = None

    @classmethod
    def parse(cls, text: str) -> 'FieldSpec':
        """``TOPIC`` (its ``data`` field) or ``TOPIC.FIELD`` (dots for nested fields, an
        optional ``[N]`` for one element of a sequence).

        Raises
        ------
        ValueError
            Not of that form (the message repeats the text).
        """
        spec = text.strip()
        topic, dot, fld = spec.partition('.')
        if not _TOPIC.fullmatch(topic):
            raise ValueError(f'{text!r}: {topic!r} is not a topic name; expected TOPIC or '
                             'TOPIC.FIELD such as /coil/current or /valve/state.coil_current')
        if not dot:
            fld = DEFAULT_FIELD
        m = _FIELD.fullmatch(fld)
        if m is None:
            raise ValueError(f'{text!r}: {fld!r} is not a field name; expected TOPIC.FIELD '
                             'with dots for nested fields and [N] for a sequence element, '
                             'such as /valve/state.coil_current or /js.position[0]')
        name = fld[:m.start(2)] if m.group(2) else fld
        index = int(m.group(3)) if m.group(3) is not None else None
        return cls('/' + topic.lstrip('/~'), name, index)

    def __str__(self) -> str:
        return f'{self.topic}.{self.field}' + ('' if self.index is None else f'[{self.index}]')


@dataclass(frozen=True)
class FieldSeries:
    """The values of one field over the messages of its topic.

    Attributes
    ----------
    spec : FieldSpec
        What was read.
    msgtype : str
        The topic's message type.
    time_ns : numpy.ndarray of int64, shape (n,)
        Message times [ns]: ``header.stamp`` or the receive time (:attr:`time_source`).
    values : numpy.ndarray of float64, shape (n,)
        The field's values in the message's units.
    time_source : str
        ``header stamps`` or ``receive times``.
    """

    spec: FieldSpec
    msgtype: str
    time_ns: np.ndarray
    values: np.ndarray
    time_source: str

    def __len__(self) -> int:
        return int(self.values.size)


@dataclass(frozen=True)
class FieldRecord:
    """Series read from one bag.

    Attributes
    ----------
    source : str
        The bag.
    series : dict of str to FieldSeries
        By the names the caller gave (``current``, ``voltage``, ...).
    notes : tuple of str
        What the reader noticed: how each series is timed, a reindexed or cut-off bag.
    """

    source: str
    series: dict[str, FieldSeries]
    notes: tuple[str, ...] = ()


def _describe(values: np.ndarray) -> str:
    if values.dtype.kind in 'US':
        return 'text'
    if values.dtype == object:
        first = next((v for v in values if v is not None), None)
        if isinstance(first, np.ndarray) and first.dtype.kind in 'biuf':
            return 'a sequence of numbers of varying length'
        return 'a sequence of messages or strings'
    if values.ndim == 2:
        return f'a sequence of {values.shape[1]} numbers per message'
    return f'of type {values.dtype}'


def _element(source: str, name: str, spec: FieldSpec, values: np.ndarray) -> np.ndarray:
    """Element ``spec.index`` of a sequence field, per message."""
    i = spec.index
    if values.ndim == 2 and values.dtype.kind in 'biuf':
        if i >= values.shape[1]:
            raise BagFormatError(f'{source}: {spec} ({name}): the field holds {values.shape[1]} '
                                 f'numbers per message; expected an index below that')
        return values[:, i].astype(np.float64)
    if values.dtype == object and all(isinstance(v, np.ndarray) and v.dtype.kind in 'biuf'
                                      for v in values):
        short = next((k for k, v in enumerate(values) if v.size <= i), None)
        if short is not None:
            raise BagFormatError(f'{source}: {spec} ({name}): message {short} holds '
                                 f'{values[short].size} numbers; expected at least {i + 1}')
        return np.array([v[i] for v in values], dtype=np.float64)
    raise BagFormatError(f'{source}: {spec} ({name}) is {_describe(values)}; expected a '
                         'sequence of numbers')


def _series(source: str, name: str, spec: FieldSpec, data: TopicData) -> FieldSeries:
    if not len(data):
        raise BagFormatError(f'{source}: topic {spec.topic} ({data.msgtype}) has no messages; '
                             f'expected the {name} on it')
    values = data.fields.get(spec.field)
    if values is None:
        numeric = sorted(k for k, v in data.fields.items() if v.dtype.kind in 'biuf')
        raise BagFormatError(f'{source}: topic {spec.topic} ({data.msgtype}) has no field '
                             f'{spec.field!r} for the {name}; its numeric fields: '
                             f'{", ".join(numeric) or "none"}')
    if spec.index is not None:
        values = _element(source, name, spec, values)
    elif values.ndim != 1 or values.dtype.kind not in 'biuf':
        raise BagFormatError(f'{source}: {spec} ({data.msgtype}, the {name}) is '
                             f'{_describe(values)}; expected a number per message')
    stamps = data.stamp_ns
    if stamps is not None and np.any(stamps != 0):
        return FieldSeries(spec, data.msgtype, stamps, values.astype(np.float64), HEADER_STAMP)
    return FieldSeries(spec, data.msgtype, data.log_time_ns, values.astype(np.float64),
                       RECEIVE_TIME)


def _time_note(name: str, s: FieldSeries, has_header: bool) -> str:
    if s.time_source == HEADER_STAMP:
        how = 'timed by its header stamps'
    elif has_header:
        how = 'timed by the receive times (its header stamps are all zero)'
    else:
        how = 'timed by the receive times (the type has no header)'
    return f'{name} from {s.spec} ({s.msgtype}, {len(s)} messages), {how}'


def read_fields(path: str | Path, specs: Mapping[str, FieldSpec | str]) -> FieldRecord:
    """Read numeric fields of a bag's topics as time series.

    Parameters
    ----------
    path : str or pathlib.Path
        Any bag :func:`~.reader.load_bag` reads.
    specs : mapping of str to FieldSpec or str
        Name (``current``, ...) -> field (``/coil/current``, ``/valve/state.coil_current``,
        see :meth:`FieldSpec.parse`).

    Returns
    -------
    FieldRecord
        One series per name, with notes on how each is timed.

    Raises
    ------
    BagFormatError
        The bag cannot be read, or a topic is missing or empty, or a field is missing or
        not a number (one line naming the bag, the topic and field, and what was expected).
    ValueError
        A spec is not ``TOPIC`` or ``TOPIC.FIELD``.
    """
    source = str(path)
    parsed = {name: s if isinstance(s, FieldSpec) else FieldSpec.parse(s)
              for name, s in specs.items()}
    contents = load_bag_contents(path, {s.topic for s in parsed.values()})
    series: dict[str, FieldSeries] = {}
    notes = list(contents.notes)
    for name, spec in parsed.items():
        data = contents.topics.get(spec.topic)
        if data is None:
            have = ', '.join(f'{t} ({m})' for t, m in sorted(contents.available.items()))
            raise BagFormatError(f'{source}: no topic {spec.topic} for the {name}; the bag '
                                 f'has {have or "no topic"}')
        series[name] = _series(source, name, spec, data)
        notes.append(_time_note(name, series[name], data.stamp_ns is not None))
    return FieldRecord(source, series, tuple(notes))
