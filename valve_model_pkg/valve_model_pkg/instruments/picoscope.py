"""PicoScope exports: the CSV/text file and the MATLAB file (v4, v5, v7.3).

CSV (comma) or text (tab), as PicoScope 6 and 7 write them::

    Time,Channel A,Channel B
    (ms),(V),(mA)

    -0.50000000,0.01234567,-0.00123456

a names row, a units row in parentheses, a blank row, then one row per sample;
over-range samples are written as an infinity sign.

MATLAB file: variables ``Tstart``, ``Tinterval``, ``Length`` (or a time array ``T``) and
one array per channel named ``A`` to ``H``; the time of sample ``n`` is
``Tstart + n x Tinterval`` [s]. PicoScope 6 writes version 4; versions 5 (read by scipy)
and 7.3 (an HDF5 file, read by h5py) are read too. The MATLAB file states no units.
"""
from __future__ import annotations

import re
import struct

import numpy as np

from ..errors import InstrumentFormatError
from .base import Head, Loaded
from .capture import (
    CaptureHeader, ChannelInfo, TimeAxis, axis_from_printed, time_unit_factor, unit_factor,
)
from .text import header_fields, read_columns, split_fields

__all__ = ['PicoCsvReader', 'PicoMatReader', 'mat_version']

_PICO_CHANNEL = re.compile(r'^channel\s+([a-h])$', re.IGNORECASE)
_MAT_CHANNELS = tuple('ABCDEFGH')
_HDF5_SIGNATURE = b'\x89HDF\r\n\x1a\n'


def _delimiter(line: str) -> str:
    return '\t' if line.count('\t') > line.count(',') else ','


def _aliases(name: str) -> tuple[str, ...]:
    m = _PICO_CHANNEL.match(name.strip())
    if m:
        letter = m.group(1).upper()
        return (letter, f'Channel {letter}', f'CH{letter}', f'CH {letter}')
    if len(name.strip()) == 1 and name.strip().upper() in _MAT_CHANNELS:
        letter = name.strip().upper()
        return (f'Channel {letter}', f'CH{letter}', f'CH {letter}')
    return ()


def _units_row(line: str, delimiter: str) -> list[str] | None:
    fields = header_fields(line, delimiter)
    if len(fields) < 2 or not all(f.startswith('(') and f.endswith(')') for f in fields):
        return None
    return [f[1:-1].strip() for f in fields]


class PicoCsvReader:
    """PicoScope CSV or tab-separated text: names, ``(units)``, a blank row, samples."""

    key = 'picoscope-csv'
    title = 'PicoScope CSV'

    def sniff(self, head: Head) -> bool:
        if len(head.lines) < 2:
            return False
        delimiter = _delimiter(head.lines[0])
        names = split_fields(head.lines[0], delimiter)
        return names[0].casefold() == 'time' and _units_row(head.lines[1], delimiter) is not None

    def open(self, head: Head) -> CaptureHeader:
        path = head.path
        delimiter = _delimiter(head.lines[0])
        names = header_fields(head.lines[0], delimiter)
        units = _units_row(head.lines[1], delimiter) or []
        if len(units) != len(names):
            raise InstrumentFormatError(path, 2, f'{len(units)} units for {len(names)} '
                                        f'columns; expected one "(unit)" per column')
        channels = []
        for j in range(1, len(names)):
            si, factor = unit_factor(path, 2, units[j])
            channels.append(ChannelInfo(name=names[j], aliases=_aliases(names[j]),
                                        file_unit=units[j], si_unit=si, factor=factor,
                                        source=path, key=j))
        return CaptureHeader(
            path=path, format=self.key, instrument='PicoScope', channels=tuple(channels),
            reader=self,
            extra={'delimiter': delimiter, 'time_factor': time_unit_factor(path, 2, units[0]),
                   'n_fields': len(names), 'expected': delimiter.join(names),
                   'skip': 3 if len(head.lines) > 2 and not head.lines[2].strip() else 2})

    def load(self, header: CaptureHeader, channels: list[ChannelInfo],
             time_channel: ChannelInfo | None = None) -> Loaded:
        path = header.path
        cols = read_columns(path, header.extra['skip'], [0] + [c.key for c in channels],
                            delimiter=header.extra['delimiter'],
                            n_fields=header.extra['n_fields'],
                            expected=header.extra['expected'])
        t = cols.values[0] * header.extra['time_factor']
        axis = axis_from_printed(path, t, cols.first_row, stated_dt_s=None, what='')
        return Loaded.from_columns(axis, channels, cols)


# --- MATLAB files ---------------------------------------------------------------------------
def mat_version(raw: bytes) -> str | None:
    """``'4'``, ``'5'`` or ``'7.3'`` for a MATLAB file's first bytes; ``None`` otherwise."""
    if raw.startswith(b'MATLAB 7.3 MAT-file') and raw[512:520] == _HDF5_SIGNATURE:
        return '7.3'
    if raw.startswith(b'MATLAB 5.0 MAT-file') and raw[126:128] in (b'IM', b'MI'):
        return '5'
    if len(raw) >= 20:
        mopt, mrows, ncols, imagf, namlen = struct.unpack('<5i', raw[:20])
        if (mopt in (0, 10, 20, 30, 40, 50) and mrows >= 1 and ncols >= 1 and imagf == 0
                and 1 < namlen <= 64 and len(raw) >= 20 + namlen):
            name = raw[20:20 + namlen]
            if name.endswith(b'\x00') and name[:-1].isascii() and name[:-1].isalnum():
                return '4'
    return None


class PicoMatReader:
    """PicoScope MATLAB export: ``Tstart``, ``Tinterval``, ``Length``, arrays ``A``-``H``."""

    key = 'picoscope-mat'
    title = 'PicoScope MATLAB file'

    def sniff(self, head: Head) -> bool:
        return mat_version(head.raw) is not None

    def open(self, head: Head) -> CaptureHeader:
        path = head.path
        version = mat_version(head.raw)
        names = _mat_names(path, version)
        missing = [k for k in ('Tstart', 'Tinterval', 'Length') if k not in names]
        if missing and 'T' not in names:
            raise InstrumentFormatError(path, None, f'MATLAB file (v{version}) without '
                                        f'{", ".join(missing)}: expected a PicoScope export '
                                        f'(Tstart, Tinterval, Length, arrays A-D); it has '
                                        f'{", ".join(sorted(names)) or "no variables"}')
        channels = tuple(ChannelInfo(name=c, aliases=_aliases(c), source=path, key=c)
                         for c in _MAT_CHANNELS if c in names)
        if not channels:
            raise InstrumentFormatError(path, None, f'MATLAB file (v{version}) has no channel '
                                        f'arrays A-H; it has {", ".join(sorted(names))}')
        return CaptureHeader(path=path, format=self.key,
                             instrument=f'PicoScope (MATLAB v{version} file)',
                             channels=channels, reader=self, extra={'version': version},
                             stated={'mat_version': version})

    def load(self, header: CaptureHeader, channels: list[ChannelInfo],
             time_channel: ChannelInfo | None = None) -> Loaded:
        path = header.path
        wanted = [c.name for c in channels] + ['Tstart', 'Tinterval', 'Length', 'T']
        data = _mat_read(path, header.extra['version'], wanted)
        notes = []
        arrays = {}
        for c in channels:
            arr = np.asarray(data[c.name], dtype=np.float64).ravel()
            arrays[c.name] = arr
        n = arrays[channels[0].name].size
        if 'Tinterval' in data:
            t0 = _scalar(path, data, 'Tstart')
            dt = _scalar(path, data, 'Tinterval')
            length = _scalar(path, data, 'Length')
            if dt <= 0.0:
                raise InstrumentFormatError(path, None, f'Tinterval {dt!r} must be a positive '
                                            'sample interval [s]')
            axis = TimeAxis(n, t0, dt, how=f'Tstart {t0:.9g} s + n x Tinterval {dt:.9g} s')
        else:
            t = np.asarray(data['T'], dtype=np.float64).ravel()
            length = float(t.size)
            axis = axis_from_printed(path, t, 1, stated_dt_s=None, what='')
            notes.append('times from the array T')
        for name, arr in arrays.items():
            if arr.size != int(length):
                raise InstrumentFormatError(path, None, f'variable {name!r} has {arr.size} '
                                            f'samples; Length states {int(length)} (a '
                                            'truncated export)')
        over = {name: int(np.count_nonzero(np.isinf(arr))) for name, arr in arrays.items()}
        return Loaded(time=axis, values=arrays, over_range=over, notes=notes)


def _scalar(path: str, data: dict, name: str) -> float:
    if name not in data:
        raise InstrumentFormatError(path, None, f'variable {name!r} is missing')
    arr = np.asarray(data[name], dtype=np.float64).ravel()
    if arr.size != 1 or not np.isfinite(arr[0]):
        raise InstrumentFormatError(path, None, f'variable {name!r} should be one finite '
                                    f'number, has shape {arr.shape}')
    return float(arr[0])


def _mat_names(path: str, version: str) -> set[str]:
    try:
        if version == '7.3':
            import h5py
            with h5py.File(path, 'r') as f:
                return {k for k in f.keys() if not k.startswith('#')}
        import scipy.io
        return {name for name, _, _ in scipy.io.whosmat(path)}
    except (OSError, ValueError, TypeError, KeyError, struct.error) as err:
        raise InstrumentFormatError(path, None, f'MATLAB v{version} file cannot be read '
                                    f'(truncated or corrupt): {err}') from err


def _mat_read(path: str, version: str, names: list[str]) -> dict:
    try:
        if version == '7.3':
            import h5py
            with h5py.File(path, 'r') as f:
                return {k: f[k][()] for k in names if k in f}
        import scipy.io
        present = {name for name, _, _ in scipy.io.whosmat(path)}
        return scipy.io.loadmat(path, variable_names=[n for n in names if n in present])
    except (OSError, ValueError, TypeError, KeyError, struct.error) as err:
        raise InstrumentFormatError(path, None, f'MATLAB v{version} file cannot be read '
                                    f'(truncated or corrupt): {err}') from err
