"""Which format a file is, from its content alone, and reading the chosen channels.

Detection looks at the first 64 KiB: binary signatures first (TDMS lead-in ``TDSm``,
MATLAB headers), then the first text rows, in this order: the suite's own measured-data
format (``# key: value`` rows and a ``t`` column), Tektronix TDS (``Record Length`` in
column 1 with numbers in columns 4-5), Tektronix MSO (``Model`` row and a ``TIME`` row),
Rigol (``X,...,Start,Increment`` over ``Sequence``), Keysight (``x-axis`` over
``second``), PicoScope (``Time`` over a row of ``(units)``), and last a plain CSV (a row of
names over a row of numbers). The file name is never looked at.
"""
from __future__ import annotations

import os
from collections.abc import Sequence

from ..errors import InstrumentFormatError
from .base import Head
from .capture import Capture, CaptureHeader, ChannelInfo, resolve, split_unit
from .keysight import KeysightReader
from .picoscope import PicoCsvReader, PicoMatReader
from .plain import TIME_NAMES, PlainCsvReader
from .rigol import RigolReader
from .tdms import TdmsReader
from .tektronix import MsoReader, TdsReader
from .text import MAX_LINE_CHARS

__all__ = ['READERS', 'SUITE_FORMAT', 'read_head', 'detect', 'open_export', 'read_capture',
           'is_suite_record']

#: Readers in the order detection tries them.
READERS = (TdmsReader(), PicoMatReader(), TdsReader(), MsoReader(), RigolReader(),
           KeysightReader(), PicoCsvReader(), PlainCsvReader())
#: What detection calls the suite's own CSV format.
SUITE_FORMAT = 'measured-data'
_HEAD_BYTES = 1 << 16
_HEAD_LINES = 80


def read_head(path: str | os.PathLike[str]) -> Head:
    """The first 64 KiB of a file and, if it is text, its first rows.

    Raises
    ------
    InstrumentFormatError
        The file does not exist, is a directory or is empty.
    """
    spath = str(path)
    if os.path.isdir(spath):
        raise InstrumentFormatError(spath, None, 'is a directory; expected an instrument '
                                    'export file')
    try:
        with open(spath, 'rb') as fh:
            raw = fh.read(_HEAD_BYTES)
    except OSError as err:
        raise InstrumentFormatError(spath, None, f'cannot be read: {err.strerror}') from err
    if not raw:
        raise InstrumentFormatError(spath, None, 'is empty; expected an instrument export')
    return Head(spath, raw, _text_lines(raw))


def _text_lines(raw: bytes) -> tuple[str, ...]:
    if b'\x00' in raw[:4096]:
        return ()
    body = raw if len(raw) < _HEAD_BYTES else raw[:raw.rfind(b'\n') + 1]
    # Bytes that are not UTF-8 are replaced here; reading the rows refuses them by row.
    text = body.decode('utf-8-sig', errors='replace')
    lines = text.replace('\r', '').split('\n')[:_HEAD_LINES]
    if lines and any(len(ln) > MAX_LINE_CHARS for ln in lines):
        return ()
    return tuple(ln for ln in lines) if any(ln.strip() for ln in lines) else ()


def is_suite_record(head: Head) -> bool:
    """True for a file of the suite's measured-data format (``# key: value``, ``t`` column)."""
    rows = [ln.strip() for ln in head.lines if ln.strip()]
    meta = [r for r in rows if r.startswith('#')]
    body = [r for r in rows if not r.startswith('#')]
    if not body:
        return False
    columns = [c.strip() for c in body[0].split(',')]
    keyed = bool(meta) and all(':' in r for r in meta)
    return ('t' in columns and 'current' in columns) or (keyed and 'duty' in columns)


def detect(head: Head) -> object:
    """The reader for a file's content.

    Raises
    ------
    InstrumentFormatError
        Naming the first row and the formats that were expected.
    """
    for reader in READERS:
        if reader.sniff(head):
            return reader
    first = head.lines[0][:60] if head.lines else f'binary, first bytes {head.raw[:8]!r}'
    titles = ', '.join(r.title for r in READERS)
    raise InstrumentFormatError(head.path, 1 if head.lines else None,
                                f'not an instrument export this importer knows ({first!r}); '
                                f'expected one of: {titles}')


def open_export(path: str | os.PathLike[str]) -> CaptureHeader:
    """Detect a file's format and read its header (instrument, channels, time base)."""
    head = read_head(path)
    if head.lines and is_suite_record(head):
        raise InstrumentFormatError(head.path, 1, 'is already a record of the measured-data '
                                    'format; valve_identify reads it as it is')
    return detect(head).open(head)


def _time_channel(header: CaptureHeader, wanted: str | None) -> ChannelInfo | None:
    if wanted is not None:
        return resolve(header, wanted, 'time')
    if header.format not in ('plain-csv',):
        return None
    found = [c for c in header.channels
             if split_unit(c.name)[0].strip().casefold() in TIME_NAMES]
    if len(found) != 1:
        raise InstrumentFormatError(header.path, header.extra.get('skip'), 'which column is '
                                    'time? name it with --time (columns: '
                                    f'{header.channel_list()})')
    return found[0]


def read_capture(paths: Sequence[str | os.PathLike[str]], wanted: dict[str, str],
                 time: str | None = None) -> Capture:
    """Read the named channels of one capture from one or several files.

    Parameters
    ----------
    paths : sequence of path-like
        Files of one capture (one per channel for Tektronix TDS-style files).
    wanted : dict of str to str
        Role (``voltage``, ``current``) -> channel name as the file names it.
    time : str, optional
        The time column (plain CSV) or channel (TDMS without waveform properties).

    Returns
    -------
    Capture
        The channels by role name (``voltage``, ``current``) on one time axis.

    Raises
    ------
    InstrumentFormatError
        A file that cannot be read, a channel missing or ambiguous (listing the channels
        the files have), files whose time bases differ.
    """
    headers = [open_export(p) for p in paths]
    pool = [(h, c) for h in headers for c in h.channels]
    chosen: dict[str, tuple[CaptureHeader, ChannelInfo]] = {}
    for role, name in wanted.items():
        if len(headers) == 1:
            ch = resolve(headers[0], name, role)
            chosen[role] = (headers[0], ch)
            continue
        merged = CaptureHeader(path=', '.join(h.path for h in headers), format='',
                               instrument='', channels=tuple(c for _, c in pool))
        ch = resolve(merged, name, role)
        chosen[role] = (next(h for h, c in pool if c is ch), ch)
    names = {role: ch.name for role, (_, ch) in chosen.items()}
    if len(set(id(ch) for _, ch in chosen.values())) < len(chosen):
        raise InstrumentFormatError(headers[0].path, None, f'the same channel is named for '
                                    f'{" and ".join(chosen)}: {names}')
    return _load(headers, chosen, time)


def _load(headers: list[CaptureHeader], chosen: dict, time: str | None) -> Capture:
    values, channels, over, first_row, notes = {}, {}, {}, {}, []
    axis = None
    used = []
    for header in headers:
        mine = [(role, ch) for role, (h, ch) in chosen.items() if h is header]
        if not mine:
            notes.append(f'{header.path}: no chosen channel; not used')
            continue
        used.append(header.path)
        tch = _time_channel(header, time)
        loaded = header.reader.load(header, [ch for _, ch in mine], tch)
        if axis is None:
            axis = loaded.time
        else:
            _same_base(header.path, headers[0].path, axis, loaded.time)
        for role, ch in mine:
            values[role] = loaded.values[ch.name]
            channels[role] = ch
            over[role] = loaded.over_range.get(ch.name, 0)
            if loaded.first_row is not None:
                first_row[role] = loaded.first_row
        notes += loaded.notes
    return Capture(header=headers[0], paths=tuple(used), time=axis, values=values,
                   channels=channels, over_range=over, first_row=first_row,
                   notes=tuple(notes))


def _same_base(path: str, first: str, a, b) -> None:  # noqa: ANN001 - TimeAxis
    if a.n != b.n or (a.dt_s is None) != (b.dt_s is None) or (
            a.dt_s is not None and (abs(a.dt_s - b.dt_s) > 1e-9 * a.dt_s
                                    or abs(a.t0_s - b.t0_s) > 0.5 * a.dt_s)):
        raise InstrumentFormatError(path, None, f'time base {b.n} samples from {b.t0_s:.9g} s '
                                    f'every {b.dt_s or 0:.6g} s differs from {first} ({a.n} '
                                    f'samples from {a.t0_s:.9g} s every {a.dt_s or 0:.6g} s): '
                                    'not files of one capture')
