"""Plain CSV with a header row: any logger or script output (comma, semicolon or tab).

``time [s],voltage [V],current [mA]``: units in brackets or parentheses after the name are
honoured (s/ms/us, V/mV, A/mA); a column without a unit is taken as it is (time in
seconds) and the record's header says so. The time column is named with ``--time``; without
it a single column called ``t`` or ``time`` is used. Leading ``#`` comment lines are
skipped.
"""
from __future__ import annotations

from ..errors import InstrumentFormatError
from .base import Head, Loaded
from .capture import (
    CaptureHeader, ChannelInfo, axis_from_printed, normalise_name, split_unit,
    time_unit_factor, unit_factor,
)
from .text import is_number, read_columns, split_fields

__all__ = ['PlainCsvReader', 'TIME_NAMES']

#: Column names taken as the time column when ``--time`` is not given.
TIME_NAMES = ('t', 'time', 'zeit', 'timestamp')


def _delimiter(line: str) -> str:
    counts = {d: line.count(d) for d in (',', ';', '\t')}
    return max(counts, key=counts.get)


def _header_index(lines: tuple[str, ...]) -> int | None:
    """Index of the header row: the first non-comment row, followed by a numeric row."""
    for i, line in enumerate(lines):
        if not line.strip() or line.lstrip().startswith('#'):
            continue
        delimiter = _delimiter(line)
        names = split_fields(line, delimiter)
        if len(names) < 2 or all(is_number(n) for n in names if n):
            return None
        following = [ln for ln in lines[i + 1:] if ln.strip()]
        if not following:
            return None
        fields = split_fields(following[0], delimiter)
        return i if len(fields) >= len(names) and all(is_number(f) for f in fields
                                                      if f) else None
    return None


class PlainCsvReader:
    """A header row of column names (units in brackets), then numeric rows."""

    key = 'plain-csv'
    title = 'plain CSV with a header row'

    def sniff(self, head: Head) -> bool:
        return bool(head.lines) and _header_index(head.lines) is not None

    def open(self, head: Head) -> CaptureHeader:
        path = head.path
        index = _header_index(head.lines)
        line = head.lines[index]
        delimiter = _delimiter(line)
        names = split_fields(line, delimiter)
        while names and names[-1] == '':
            names.pop()
        if len(set(map(normalise_name, names))) != len(names):
            raise InstrumentFormatError(path, index + 1, f'duplicate column names in {names}')
        channels = []
        for j, column in enumerate(names):
            base, unit = split_unit(column)
            si, factor = (None, 1.0)
            if unit:
                key = unit.strip().casefold()
                if key in ('s', 'ms', 'us', 'µs', 'ns', 'sec', 'seconds'):
                    si, factor = 's', time_unit_factor(path, index + 1, unit)
                else:
                    si, factor = unit_factor(path, index + 1, unit)
            channels.append(ChannelInfo(name=column, aliases=(base,) if unit else (),
                                        file_unit=unit, si_unit=si, factor=factor,
                                        source=path, key=j))
        return CaptureHeader(path=path, format=self.key, instrument='plain CSV',
                             channels=tuple(channels), reader=self,
                             extra={'delimiter': delimiter, 'skip': index + 1,
                                    'n_fields': len(names), 'expected': delimiter.join(names)})

    def load(self, header: CaptureHeader, channels: list[ChannelInfo],
             time_channel: ChannelInfo | None = None) -> Loaded:
        path = header.path
        if time_channel is None:
            raise InstrumentFormatError(path, header.extra['skip'], 'no time column: name it '
                                        f'with --time (columns: {header.channel_list()})')
        cols = read_columns(path, header.extra['skip'],
                            [time_channel.key] + [c.key for c in channels],
                            delimiter=header.extra['delimiter'],
                            n_fields=header.extra['n_fields'],
                            expected=header.extra['expected'])
        notes = []
        t = cols.values[0] * time_channel.factor
        if time_channel.file_unit is None:
            notes.append(f'time column {time_channel.name!r} states no unit: taken as seconds')
        axis = axis_from_printed(path, t, cols.first_row, stated_dt_s=None, what='')
        return Loaded.from_columns(axis, channels, cols, notes)
