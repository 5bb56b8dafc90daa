"""What every instrument reader returns: channels on one time axis, in SI units.

A reader opens a file in two steps, so that a 10-million-sample export costs only the
columns that are used: :meth:`Reader.open` reads the header (instrument, channels, units,
the time base the file states) into a :class:`CaptureHeader`; :meth:`Reader.load` reads
the chosen channels' samples into a :class:`Capture`. Units are converted here, by one
table (:data:`UNITS`); a unit the table does not know is refused, naming it.
"""
from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..errors import InstrumentFormatError

__all__ = [
    'UNITS', 'TIME_UNITS', 'OVER_RANGE_ABS', 'ChannelInfo', 'CaptureHeader', 'TimeAxis',
    'Capture', 'unit_factor', 'time_unit_factor', 'normalise_name', 'axis_from_printed',
    'infer_lsb', 'MAX_SAMPLES', 'Resolution', 'parse_number', 'split_unit', 'resolve',
    'channel_aliases',
]

#: Units of a vertical channel as instruments write them -> (SI unit, factor to SI).
UNITS: dict[str, tuple[str, float]] = {
    'v': ('V', 1.0), 'volt': ('V', 1.0), 'volts': ('V', 1.0), 'mv': ('V', 1e-3),
    'millivolt': ('V', 1e-3), 'millivolts': ('V', 1e-3), 'uv': ('V', 1e-6),
    'µv': ('V', 1e-6), 'kv': ('V', 1e3),
    'a': ('A', 1.0), 'amp': ('A', 1.0), 'amps': ('A', 1.0), 'ampere': ('A', 1.0),
    'amperes': ('A', 1.0), 'ma': ('A', 1e-3), 'milliamp': ('A', 1e-3),
    'milliamps': ('A', 1e-3), 'milliampere': ('A', 1e-3), 'ua': ('A', 1e-6),
    'µa': ('A', 1e-6),
}
#: Units of a time axis -> factor to seconds.
TIME_UNITS: dict[str, float] = {
    's': 1.0, 'sec': 1.0, 'second': 1.0, 'seconds': 1.0, 'ms': 1e-3, 'msec': 1e-3,
    'us': 1e-6, 'µs': 1e-6, 'μs': 1e-6, 'usec': 1e-6, 'ns': 1e-9, 'ks': 1e3,
}
#: Sample values at or beyond this magnitude are an instrument's over-range marker
#: (Tektronix writes 9.91E+37, PicoScope an infinity sign).
OVER_RANGE_ABS = 9.0e37
#: Most samples one import reads (of the chosen channels): 3 channels of float64 stay
#: below 0.5 GB.
MAX_SAMPLES = 20_000_000


def normalise_name(name: str) -> str:
    """A channel name as compared: case-folded, spaces collapsed."""
    return ' '.join(name.replace('\u00a0', ' ').split()).casefold()


_NUMBERED_CHANNEL = re.compile(r'^(?:ch|channel)\s*(\d+)$', re.IGNORECASE)


def channel_aliases(name: str) -> tuple[str, ...]:
    """Other names of a numbered channel (``CH1`` -> ``1``, ``CH1``, ``Channel 1``)."""
    m = _NUMBERED_CHANNEL.match(name.strip())
    return (m.group(1), f'CH{m.group(1)}', f'Channel {m.group(1)}') if m else ()


def unit_factor(path: str, line: int | None, unit: str) -> tuple[str, float]:
    """SI unit and factor of a vertical unit as the file writes it (``'mA'`` -> A, 1e-3).

    Raises
    ------
    InstrumentFormatError
        The unit is not a voltage or current unit of :data:`UNITS`.
    """
    key = unit.strip().strip('()[]').strip().casefold().replace('μ', 'µ')
    if key in UNITS:
        return UNITS[key]
    raise InstrumentFormatError(path, line, f'vertical unit {unit!r} is not one this importer '
                                f'converts (V, mV, A, mA and their spellings)')


def time_unit_factor(path: str, line: int | None, unit: str) -> float:
    """Factor to seconds of a time unit as the file writes it (``'ms'`` -> 1e-3)."""
    key = unit.strip().strip('()[]').strip().casefold().replace('μ', 'µ')
    if key in TIME_UNITS:
        return TIME_UNITS[key]
    raise InstrumentFormatError(path, line, f'time unit {unit!r} is not one of s, ms, us, ns '
                                '(a frequency-domain or math export cannot be imported)')


@dataclass(frozen=True)
class ChannelInfo:
    """A channel as the file names and describes it (no samples yet).

    Attributes
    ----------
    name : str
        The name the file gives it (``CH2``, ``Channel B``, ``Measurement/Coil current``).
    aliases : tuple of str
        Other names a user may give for it (``2`` for ``CH2``, ``B`` for ``Channel B``).
    file_unit : str or None
        The unit as the file states it (``Volt``, ``(mA)``); ``None`` when it states none.
    si_unit : str or None
        ``V`` or ``A`` after conversion; ``None`` when the file states no unit.
    factor : float
        Multiplies the file's values to give ``si_unit``.
    source : str
        The file holding the channel.
    key : object
        What the reader needs to find the samples (column index, variable, channel object).
    stated : dict of str to str
        Facts the file states about the channel (vertical scale, probe, label).
    """

    name: str
    aliases: tuple[str, ...] = ()
    file_unit: str | None = None
    si_unit: str | None = None
    factor: float = 1.0
    source: str = ''
    key: object = None
    stated: dict[str, str] = field(default_factory=dict)

    def names(self) -> tuple[str, ...]:
        """Every name that selects this channel, normalised."""
        return tuple(dict.fromkeys(normalise_name(n) for n in (self.name,) + self.aliases))


@dataclass(frozen=True)
class CaptureHeader:
    """A file's header: what it is and what it holds, before its samples are read.

    Attributes
    ----------
    path : str
    format : str
        Format key (``tektronix-tds``, ``rigol``, ``picoscope-mat`` ...).
    instrument : str
        Instrument family and model as far as the file says (``Tektronix TDS2024B``).
    channels : tuple of ChannelInfo
    stated : dict of str to str
        Time-base facts the file states (record length, sample interval, trigger point).
    sample_interval_s : float or None
        Stated sample interval [s]; ``None`` when the file gives only printed times.
    n_samples : int or None
        Stated number of samples.
    reader : object
        The reader that made it (its ``load`` reads the samples).
    extra : dict
        Reader-private facts needed to load (first data row, delimiter, time column).
    """

    path: str
    format: str
    instrument: str
    channels: tuple[ChannelInfo, ...]
    stated: dict[str, str] = field(default_factory=dict)
    sample_interval_s: float | None = None
    n_samples: int | None = None
    reader: object = None
    extra: dict = field(default_factory=dict)

    def channel_list(self) -> str:
        """The channels as a message lists them: ``CH1 (V), CH2 (A)``."""
        return ', '.join(f'{c.name} ({c.file_unit or "no unit"})' for c in self.channels)


@dataclass(frozen=True)
class TimeAxis:
    """Sample times of a capture [s], as the file's clock gives them (trigger at 0).

    Uniform axes are kept as ``t0_s + n * dt_s``; others as the printed times.

    Attributes
    ----------
    n : int
    t0_s : float
        First sample time [s] (negative: pre-trigger).
    dt_s : float or None
        Sample interval [s] of a uniform axis; ``None`` for printed, non-uniform times.
    t_s : numpy.ndarray or None, shape (n,)
        The printed times [s] of a non-uniform axis.
    how : str
        Where the axis comes from (for the header).
    """

    n: int
    t0_s: float
    dt_s: float | None
    t_s: np.ndarray | None = None
    how: str = ''

    def times(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Times of samples ``start:stop`` [s], shape (stop - start,)."""
        stop = self.n if stop is None else stop
        if self.t_s is not None:
            return self.t_s[start:stop]
        return self.t0_s + self.dt_s * np.arange(start, stop, dtype=np.float64)

    def index_at(self, t: float, side: str) -> int:
        """First sample at or after ``t`` (``side='left'``) or after it (``'right'``)."""
        if self.t_s is not None:
            return int(np.searchsorted(self.t_s, t, side=side))
        k = (t - self.t0_s) / self.dt_s
        k = math.ceil(k - 1e-9) if side == 'left' else math.floor(k + 1e-9) + 1
        return int(min(max(k, 0), self.n))


@dataclass(frozen=True)
class Capture:
    """Chosen channels of one capture, sampled on one time axis, in the file's units.

    Attributes
    ----------
    header : CaptureHeader
        Of the first file (several files of one capture share the time base).
    paths : tuple of str
        Every file the capture came from.
    time : TimeAxis
    values : dict of str to numpy.ndarray, shape (n,)
        Samples by channel name, multiplied by the channel's ``factor`` (SI where the file
        states a unit); over-range samples are ``nan``.
    channels : dict of str to ChannelInfo
    over_range : dict of str to int
        Over-range samples per channel (now ``nan``).
    first_row : dict of str to int
        File row of each channel's first sample (text files; for messages).
    notes : tuple of str
    """

    header: CaptureHeader
    paths: tuple[str, ...]
    time: TimeAxis
    values: dict[str, np.ndarray]
    channels: dict[str, ChannelInfo]
    over_range: dict[str, int] = field(default_factory=dict)
    first_row: dict[str, int] = field(default_factory=dict)
    notes: tuple[str, ...] = ()


# --- time axes ------------------------------------------------------------------------------
#: Printed times may differ from the sample grid by this fraction of their value (7
#: significant digits print to 5e-7; engineering notation with 6 to 5e-6) plus half an
#: interval.
_PRINT_RELATIVE = 5e-6


def axis_from_printed(path: str, printed: np.ndarray, first_row: int, *,
                      stated_dt_s: float | None, what: str) -> TimeAxis:
    """A time axis from printed times, uniform where they allow it.

    Parameters
    ----------
    path : str
    printed : numpy.ndarray, shape (n,)
        Times as printed [s].
    first_row : int
        File row of the first sample (for messages).
    stated_dt_s : float or None
        The sample interval the file states; printed times must then lie on
        ``printed[0] + n * dt`` within their printed precision.
    what : str
        How the file names the interval (for messages), e.g. ``'Sample Interval'``.

    Returns
    -------
    TimeAxis
        Uniform when the times lie on a grid (the stated interval, else the mean interval);
        else the printed times, which must then increase strictly.

    Raises
    ------
    InstrumentFormatError
        A printed time off the stated grid, or non-increasing printed times.
    """
    n = printed.size
    if n == 0:
        raise InstrumentFormatError(path, first_row, 'no samples after the header')
    if not np.all(np.isfinite(printed)):
        k = int(np.flatnonzero(~np.isfinite(printed))[0])
        raise InstrumentFormatError(path, first_row + k, f'time {printed[k]!r} is not finite')
    t0 = float(printed[0])
    dt = stated_dt_s
    if dt is None:
        dt = float(printed[-1] - printed[0]) / (n - 1) if n > 1 else 0.0
        if n > 1 and dt <= 0.0:
            raise InstrumentFormatError(path, first_row + n - 1, f'the last time '
                                        f'{printed[-1]:.9g} s is not after the first '
                                        f'{t0:.9g} s')
    if n == 1:
        return TimeAxis(n, t0, stated_dt_s or 1.0, how=f'one sample; {what}')
    off = _grid_offsets(printed, t0, dt)
    if off is None:
        how = (f'{what} {dt:.9g} s; printed times agree' if stated_dt_s else
               f'printed times, uniform: interval {dt:.9g} s')
        return TimeAxis(n, t0, dt, how=how)
    if stated_dt_s is not None:
        k = off
        raise InstrumentFormatError(
            path, first_row + k, f'time {printed[k]:.9g} s is off the sample grid '
            f'{t0:.9g} s + n x {what} {dt:.6g} s (expected {t0 + k * dt:.9g} s): not one '
            'evenly sampled record')
    steps = np.diff(printed)
    bad = np.flatnonzero(steps <= 0.0)
    if bad.size:
        k = int(bad[0]) + 1
        raise InstrumentFormatError(path, first_row + k, f'time {printed[k]:.9g} s does not '
                                    f'increase (previous row {printed[k - 1]:.9g} s)')
    return TimeAxis(n, t0, None, t_s=np.asarray(printed, dtype=np.float64),
                    how='printed times (not evenly sampled; kept as printed)')


def _grid_offsets(printed: np.ndarray, t0: float, dt: float, block: int = 1 << 20
                  ) -> int | None:
    """Index of the first printed time off ``t0 + n dt`` beyond print precision, or None."""
    for a in range(0, printed.size, block):
        b = min(a + block, printed.size)
        grid = t0 + dt * np.arange(a, b, dtype=np.float64)
        tol = 0.5 * dt + _PRINT_RELATIVE * np.abs(grid) + 1e-15
        bad = np.flatnonzero(np.abs(printed[a:b] - grid) > tol)
        if bad.size:
            return a + int(bad[0])
    return None


# --- resolution -----------------------------------------------------------------------------
#: Values are taken as quantised when at least this share of the levels used lies within
#: 0.3 steps of one grid.
_GRID_SHARE = 0.9
_LSB_SAMPLE = 2_000_000


@dataclass(frozen=True)
class Resolution:
    """The vertical resolution found in a channel's samples.

    Attributes
    ----------
    lsb : float
        Step between adjacent levels, in the channel's units.
    levels_used : int
        Distinct levels in the samples.
    """

    lsb: float
    levels_used: int


def infer_lsb(values: np.ndarray) -> Resolution | None:
    """The quantisation step of a channel's samples, if they lie on a grid.

    A candidate step (the median step between adjacent distinct values) numbers each
    distinct value by its whole count of steps from the smallest; the step and the grid's
    offset are then the least-squares line through (count, value), so that the print
    rounding of the extremes does not bend the grid. The samples count as quantised when
    at least 90 % of the distinct values lie within 0.3 steps of that grid (print rounding
    of the file included).

    Parameters
    ----------
    values : numpy.ndarray, shape (n,)
        Samples (``nan`` ignored); at most 2 M evenly spaced ones are examined.

    Returns
    -------
    Resolution or None
        ``None`` when fewer than 3 distinct values or no grid is found.
    """
    v = values[np.isfinite(values)]
    if v.size > _LSB_SAMPLE:
        v = v[:: v.size // _LSB_SAMPLE + 1]
    u = np.unique(v)
    if u.size < 3:
        return None
    step = float(np.median(np.diff(u)))
    span = float(u[-1] - u[0])
    if step <= 0.0 or span <= 0.0:
        return None
    levels = round(span / step)
    if levels < 2 or levels > 1 << 24:
        return None
    counts = np.round((u - u[0]) / step)
    lsb, offset = np.polyfit(counts, u, 1)
    if not lsb > 0.0:
        return None
    r = (u - offset) / lsb
    on_grid = np.abs(r - np.round(r)) < 0.3
    if float(np.mean(on_grid)) < _GRID_SHARE:
        return None
    return Resolution(lsb=float(lsb), levels_used=int(u.size))


def parse_number(path: str, line: int | None, text: str, what: str) -> float:
    """A number stated in a header (``2.500000e+03``), refused with the row if not one."""
    try:
        value = float(text.strip())
    except ValueError:
        raise InstrumentFormatError(path, line, f'{what}: {text.strip()!r} is not a number'
                                    ) from None
    if not math.isfinite(value):
        raise InstrumentFormatError(path, line, f'{what}: {text.strip()!r} is not finite')
    return value


_UNIT_IN_NAME = re.compile(r'^(?P<name>.*?)\s*(?:\[(?P<b>[^\]]*)\]|\((?P<p>[^)]*)\))\s*$')


def split_unit(column: str) -> tuple[str, str | None]:
    """``'current [mA]'`` -> (``'current'``, ``'mA'``); a name without a unit -> (name, None).
    """
    m = _UNIT_IN_NAME.match(column.strip())
    if not m or not m.group('name'):
        return column.strip(), None
    return m.group('name'), (m.group('b') if m.group('b') is not None else m.group('p'))


def resolve(header: CaptureHeader, wanted: str, role: str,
            channels: Sequence[ChannelInfo] | None = None) -> ChannelInfo:
    """The channel a user named (case-insensitive, by name or alias), never a guess.

    Raises
    ------
    InstrumentFormatError
        No channel or more than one has that name; the message lists the file's channels.
    """
    pool = header.channels if channels is None else tuple(channels)
    key = normalise_name(wanted)
    exact = [c for c in pool if normalise_name(c.name) == key]
    found = exact or [c for c in pool if key in c.names()]
    listed = ', '.join(f'{c.name} ({c.file_unit or "no unit"})' for c in pool)
    if not found:
        raise InstrumentFormatError(header.path, None, f'{role} channel {wanted!r} is not in '
                                    f'the file; it has: {listed}')
    if len(found) > 1:
        raise InstrumentFormatError(header.path, None, f'{role} channel {wanted!r} is '
                                    f'ambiguous: it names {", ".join(c.name for c in found)}; '
                                    f'give the full name (channels: {listed})')
    return found[0]
