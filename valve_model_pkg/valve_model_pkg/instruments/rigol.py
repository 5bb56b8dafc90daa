"""Rigol CSV exports (DS1000Z, MSO/DS2000, MSO5000 and scopes of that layout).

Two header rows, then one row per sample, every row ending in a comma::

    X,CH1,CH2,Start,Increment,
    Sequence,Volt,Volt,-1.200000e-03,2.000000e-06
    0,4.72e-01,2.40e+01,
    1,4.64e-01,2.40e+01,

The first column is the sample number ``n``; time is ``Start + n x Increment`` [s]. The
values are printed with three significant digits (the scope's 8-bit samples).
"""
from __future__ import annotations

import numpy as np

from ..errors import InstrumentFormatError
from .base import Head, Loaded
from .capture import (
    CaptureHeader, ChannelInfo, TimeAxis, channel_aliases, parse_number, unit_factor,
)
from .text import header_fields, read_columns

__all__ = ['RigolReader']


class RigolReader:
    """Rigol CSV: ``X,CH1,...,Start,Increment,`` then ``Sequence,Volt,...,start,increment``."""

    key = 'rigol'
    title = 'Rigol CSV'

    def sniff(self, head: Head) -> bool:
        if len(head.lines) < 2:
            return False
        first, second = header_fields(head.lines[0], ','), header_fields(head.lines[1], ',')
        lower = [f.casefold() for f in first]
        return (len(first) >= 4 and lower[0] == 'x' and 'start' in lower
                and 'increment' in lower and bool(second)
                and second[0].casefold() == 'sequence')

    def open(self, head: Head) -> CaptureHeader:
        path = head.path
        first, second = header_fields(head.lines[0], ','), header_fields(head.lines[1], ',')
        lower = [f.casefold() for f in first]
        i_start, i_inc = lower.index('start'), lower.index('increment')
        if len(second) <= max(i_start, i_inc):
            raise InstrumentFormatError(path, 2, f'row 2 has {len(second)} fields; expected '
                                        f'Sequence, a unit per channel, Start and Increment')
        start = parse_number(path, 2, second[i_start], 'Start')
        increment = parse_number(path, 2, second[i_inc], 'Increment')
        if increment <= 0.0:
            raise InstrumentFormatError(path, 2, f'Increment {second[i_inc]!r} must be a '
                                        'positive sample interval [s]')
        channels = []
        for j in range(1, min(i_start, i_inc)):
            unit = second[j] if j < len(second) else ''
            si, factor = unit_factor(path, 2, unit) if unit else (None, 1.0)
            channels.append(ChannelInfo(
                name=first[j], aliases=channel_aliases(first[j]), file_unit=unit or None,
                si_unit=si, factor=factor, source=path, key=j))
        return CaptureHeader(
            path=path, format=self.key, instrument='Rigol', channels=tuple(channels),
            stated={'start': second[i_start], 'increment': second[i_inc]},
            sample_interval_s=increment, reader=self,
            extra={'start': start, 'n_fields': len(channels) + 1,
                   'expected': ','.join(['n'] + [c.name for c in channels]) + ','})

    def load(self, header: CaptureHeader, channels: list[ChannelInfo],
             time_channel: ChannelInfo | None = None) -> Loaded:
        path = header.path
        cols = read_columns(path, 2, [0] + [c.key for c in channels], delimiter=',',
                            n_fields=header.extra['n_fields'],
                            expected=header.extra['expected'])
        seq = cols.values[0]
        n = seq.size
        bad = np.flatnonzero(seq != np.arange(n, dtype=np.float64))
        if bad.size:
            k = int(bad[0])
            raise InstrumentFormatError(path, cols.first_row + k, f'sample number '
                                        f'{seq[k]:.10g}, expected {k} (rows must number the '
                                        'samples 0, 1, 2, ... without gaps)')
        axis = TimeAxis(n, header.extra['start'], header.sample_interval_s,
                        how=f'Start {header.extra["start"]:.9g} s + n x Increment '
                        f'{header.sample_interval_s:.9g} s')
        return Loaded.from_columns(axis, channels, cols)
