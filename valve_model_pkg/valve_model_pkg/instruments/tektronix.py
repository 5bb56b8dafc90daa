"""Tektronix CSV exports: the TDS-style spreadsheet file and the MSO 4/5/6 series file.

TDS-style (TDS1000/2000/3000, TBS1000 and scopes that copy it): one file per channel.
Every row has five fields (a sixth, empty, after the trailing comma): columns 1-2 carry
the metadata on the first rows (``Record Length``, ``Sample Interval``, ``Trigger Point``,
``Source``, ``Vertical Units``, ``Vertical Scale``, ``Horizontal Units``, ``Probe Atten``,
``Model Number``, ...), columns 4-5 the time [s] and the value on every row, the first
included. The channel is named by the ``Source`` row (``CH1``); several files of one
capture are given together.

MSO 4/5/6 series (and the MDO3, MSO/DPO 2000/3000/4000 files of the same layout): a header
block of ``key,value[,value...]`` rows (``Model``, ``Firmware Version``, ``Waveform
Type``, ``Horizontal Units``, ``Sample Interval``, ``Record Length``, ``Vertical Units``
per channel, ``Label``), then ``TIME,CH1,CH2,...`` and one row per sample.

Both state the sample interval; the printed times (7 significant digits: on long records
neighbouring times print alike) are checked against ``t0 + n x Sample Interval``, which
is used.
"""
from __future__ import annotations

from ..errors import InstrumentFormatError as InstrumentError
from .base import Head, Loaded
from .capture import (
    CaptureHeader, ChannelInfo, axis_from_printed, channel_aliases, parse_number,
    time_unit_factor, unit_factor,
)
from .text import TextFile, is_number, split_fields

__all__ = ['TdsReader', 'MsoReader']

_TDS_KEYS = ('record length', 'sample interval', 'trigger point', 'source')
#: Metadata rows of a TDS file sit in the first rows; the data goes on below them.
_TDS_HEADER_ROWS = 40


def _vertical(path: str, row: int | None, unit: str | None) -> tuple[str | None, float]:
    if unit is None or not unit.strip() or unit.strip().upper() == 'U':
        return None, 1.0
    return unit_factor(path, row, unit)


class TdsReader:
    """Tektronix TDS-style CSV: metadata in columns 1-2, time and value in columns 4-5."""

    key = 'tektronix-tds'
    title = 'Tektronix TDS-style CSV'

    def sniff(self, head: Head) -> bool:
        if not head.lines:
            return False
        fields = split_fields(head.lines[0], ',')
        return (len(fields) >= 5 and fields[0].casefold() == 'record length'
                and is_number(fields[3]) and is_number(fields[4]))

    def open(self, head: Head) -> CaptureHeader:
        path = head.path
        meta: dict[str, tuple[str, int]] = {}
        with TextFile(path) as f:
            for _ in range(_TDS_HEADER_ROWS):
                line = f.readline()
                if line is None:
                    break
                fields = split_fields(line, ',')
                if fields[0]:
                    meta[fields[0].casefold()] = (fields[1] if len(fields) > 1 else '', f.row)
        for key in ('record length', 'sample interval', 'source'):
            if key not in meta:
                raise _missing(path, key)
        length = parse_number(path, meta['record length'][1], meta['record length'][0],
                              'Record Length')
        interval = parse_number(path, meta['sample interval'][1], meta['sample interval'][0],
                                'Sample Interval')
        if length < 1 or length != int(length) or interval <= 0.0:
            raise _bad_base(path, meta, length, interval)
        hunit = meta.get('horizontal units')
        factor = time_unit_factor(path, hunit[1], hunit[0]) if hunit else 1.0
        source = meta['source'][0]
        vunit = meta.get('vertical units', (None, None))
        si, vfactor = _vertical(path, vunit[1], vunit[0])
        stated = {k: v for k, (v, _) in meta.items()}
        model = stated.get('model number', '')
        channel = ChannelInfo(
            name=source, aliases=channel_aliases(source), file_unit=vunit[0] or None,
            si_unit=si, factor=vfactor, source=path, key=4,
            stated={k: stated[k] for k in ('vertical scale', 'vertical offset',
                                           'probe atten', 'yzero') if k in stated})
        return CaptureHeader(
            path=path, format=self.key, instrument=f'Tektronix {model}'.strip(),
            channels=(channel,), stated=stated, sample_interval_s=interval * factor,
            n_samples=int(length), reader=self, extra={'time_factor': factor})

    def load(self, header: CaptureHeader, channels: list[ChannelInfo],
             time_channel: ChannelInfo | None = None) -> Loaded:
        path = header.path
        with TextFile(path) as f:
            cols = f.columns((3, 4), delimiter=',', n_fields=5,
                             expected='key,value,,time,value,', max_rows=header.n_samples)
        t, y = cols.values
        if t.size != header.n_samples:
            raise _short(path, cols.first_row + t.size, t.size, header.n_samples)
        t *= header.extra['time_factor']
        axis = axis_from_printed(path, t, cols.first_row, stated_dt_s=header.sample_interval_s,
                                 what='Sample Interval')
        ch = header.channels[0]
        return Loaded(time=axis, values={ch.name: y * ch.factor},
                      over_range={ch.name: cols.n_over_range[1]}, first_row=cols.first_row)


class MsoReader:
    """Tektronix MSO 4/5/6 series CSV: a header block, then ``TIME,CH1,...`` rows."""

    key = 'tektronix-mso'
    title = 'Tektronix MSO 4/5/6 series CSV'

    def sniff(self, head: Head) -> bool:
        if not head.lines or split_fields(head.lines[0], ',')[0].casefold() != 'model':
            return False
        keys = {split_fields(ln, ',')[0].casefold() for ln in head.lines}
        return 'time' in keys and bool(keys & {'sample interval', 'record length',
                                               'waveform type', 'horizontal units'})

    def open(self, head: Head) -> CaptureHeader:
        path = head.path
        meta: dict[str, tuple[list[str], int]] = {}
        names: list[str] | None = None
        with TextFile(path) as f:
            while True:
                line = f.readline()
                if line is None:
                    break
                fields = split_fields(line, ',')
                if fields[0].casefold() == 'time':
                    names, names_row = fields, f.row
                    break
                if fields[0] and fields[0].casefold() not in meta:
                    meta[fields[0].casefold()] = (fields[1:], f.row)
                if f.row > 200:
                    break
        if names is None:
            raise InstrumentError(path, None, 'no "TIME,CH1,..." row after the header block '
                                  '(expected within the first 200 rows)')
        if 'sample interval' not in meta:
            raise _missing(path, 'sample interval')
        interval = parse_number(path, meta['sample interval'][1],
                                meta['sample interval'][0][0], 'Sample Interval')
        length = None
        if 'record length' in meta:
            length = parse_number(path, meta['record length'][1], meta['record length'][0][0],
                                  'Record Length')
        if interval <= 0.0 or (length is not None and (length < 1 or length != int(length))):
            raise _bad_base(path, {k: (v[0][0] if v[0] else '', r) for k, (v, r) in meta.items()},
                            length or 1, interval)
        hunit = meta.get('horizontal units')
        factor = time_unit_factor(path, hunit[1], hunit[0][0]) if hunit and hunit[0] else 1.0
        block = []
        for j, name in enumerate(names[1:], start=1):
            if not name or name.casefold() == 'time':
                break
            block.append((j, name))
        units = meta.get('vertical units', ([], names_row))
        labels = meta.get('label', ([], names_row))
        channels = []
        for j, name in block:
            unit = units[0][j - 1] if j - 1 < len(units[0]) and units[0][j - 1] else None
            si, vfactor = _vertical(path, units[1], unit)
            label = labels[0][j - 1] if j - 1 < len(labels[0]) else ''
            stated = {k: v[j - 1] for k, (v, _) in meta.items()
                      if k in ('vertical scale', 'vertical offset', 'vertical position',
                               'probe attenuation') and j - 1 < len(v) and v[j - 1]}
            if label:
                stated['label'] = label
            channels.append(ChannelInfo(
                name=name, aliases=channel_aliases(name) + ((label,) if label else ()),
                file_unit=unit, si_unit=si, factor=vfactor, source=path, key=j,
                stated=stated))
        model = meta.get('model', ([''], 1))[0]
        return CaptureHeader(
            path=path, format=self.key, instrument=f'Tektronix {model[0] if model else ""}'
            .strip(), channels=tuple(channels),
            stated={k: (v[0] if v else '') for k, (v, _) in meta.items()},
            sample_interval_s=interval * factor,
            n_samples=None if length is None else int(length), reader=self,
            extra={'time_factor': factor, 'n_fields': len(block) + 1,
                   'names': ','.join(names[:len(block) + 1])})

    def load(self, header: CaptureHeader, channels: list[ChannelInfo],
             time_channel: ChannelInfo | None = None) -> Loaded:
        path = header.path
        with TextFile(path) as f:
            while True:
                line = f.readline()
                if line is None or split_fields(line, ',')[0].casefold() == 'time':
                    break
            cols = f.columns([0] + [c.key for c in channels], delimiter=',',
                             n_fields=header.extra['n_fields'],
                             expected=header.extra['names'], max_rows=header.n_samples)
        t = cols.values[0] * header.extra['time_factor']
        if header.n_samples is not None and t.size != header.n_samples:
            raise _short(path, cols.first_row + t.size, t.size, header.n_samples)
        axis = axis_from_printed(path, t, cols.first_row, stated_dt_s=header.sample_interval_s,
                                 what='Sample Interval')
        return Loaded.from_columns(axis, channels, cols)


def _missing(path: str, key: str) -> InstrumentError:
    return InstrumentError(path, None, f'no "{key.title()}" row in the header; expected a '
                           'Tektronix export that states it')


def _bad_base(path: str, meta: dict, length: float, interval: float) -> InstrumentError:
    row = meta.get('sample interval', ('', None))[1] if interval <= 0.0 else \
        meta.get('record length', ('', None))[1]
    return InstrumentError(path, row, f'time base Record Length {length:g}, Sample Interval '
                           f'{interval:g}: expected a whole number of samples and a '
                           'positive interval')


def _short(path: str, row: int, n: int, stated: int) -> InstrumentError:
    return InstrumentError(path, row, f'file ends after {n} samples; the header states Record '
                           f'Length {stated} (a truncated export)')
