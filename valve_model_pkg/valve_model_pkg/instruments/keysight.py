"""Keysight (Agilent) InfiniiVision CSV exports (1000/2000/3000/4000 X-series).

Two header rows, then one row per sample::

    x-axis,1,2
    second,Volt,Volt
    -1.000000E-03,+0.0E+00,-402.010E-06

The columns are named by channel number (``1``, ``2``) and the second row gives the
units. The file states no sample interval: the printed times give it (they must lie on
one grid within their printed precision, else they are kept as printed).
"""
from __future__ import annotations

from ..errors import InstrumentFormatError
from .base import Head, Loaded
from .capture import (
    CaptureHeader, ChannelInfo, axis_from_printed, channel_aliases, time_unit_factor,
    unit_factor,
)
from .text import header_fields, read_columns

__all__ = ['KeysightReader']


class KeysightReader:
    """Keysight InfiniiVision CSV: ``x-axis,1,2`` then ``second,Volt,Volt``."""

    key = 'keysight'
    title = 'Keysight InfiniiVision CSV'

    def sniff(self, head: Head) -> bool:
        if len(head.lines) < 2:
            return False
        first, second = header_fields(head.lines[0], ','), header_fields(head.lines[1], ',')
        return (len(first) >= 2 and first[0].casefold() == 'x-axis' and bool(second)
                and second[0].casefold() in ('second', 'seconds', 's'))

    def open(self, head: Head) -> CaptureHeader:
        path = head.path
        first, second = header_fields(head.lines[0], ','), header_fields(head.lines[1], ',')
        if len(second) < len(first):
            raise InstrumentFormatError(path, 2, f'row 2 has {len(second)} units for '
                                        f'{len(first)} columns; expected "second,Volt,..."')
        channels = []
        for j in range(1, len(first)):
            si, factor = unit_factor(path, 2, second[j])
            name = first[j]
            aliases = channel_aliases(name) + ((f'CH{name}', f'Channel {name}')
                                               if name.isdigit() else ())
            channels.append(ChannelInfo(name=name, aliases=aliases, file_unit=second[j],
                                        si_unit=si, factor=factor, source=path, key=j))
        return CaptureHeader(
            path=path, format=self.key, instrument='Keysight InfiniiVision',
            channels=tuple(channels), reader=self,
            extra={'time_factor': time_unit_factor(path, 2, second[0]),
                   'n_fields': len(first), 'expected': ','.join(first)})

    def load(self, header: CaptureHeader, channels: list[ChannelInfo],
             time_channel: ChannelInfo | None = None) -> Loaded:
        path = header.path
        cols = read_columns(path, 2, [0] + [c.key for c in channels], delimiter=',',
                            n_fields=header.extra['n_fields'],
                            expected=header.extra['expected'])
        t = cols.values[0] * header.extra['time_factor']
        axis = axis_from_printed(path, t, cols.first_row, stated_dt_s=None, what='')
        return Loaded.from_columns(axis, channels, cols)
