"""From an instrument capture to a record of the measured-data format.

The stages, each a function with a named result:

1. :func:`scaled_signals`: the chosen channels in V and A (the file's units converted,
   then the probe factors ``--voltage-scale``/``--current-scale``); a channel whose unit
   does not fit its role (a current channel in V) needs its factor, never a guess.
2. :func:`window`: the samples between ``--start`` and ``--stop`` (file time, trigger 0).
3. :func:`find_step`: the first voltage edge (half-way between the level before and the
   largest excursion), in file time.
4. :func:`choose_decimation`: ``auto`` keeps the step's dynamics: block means of ``N``
   samples with ``N x dt <= min(20 us, current rise 10-90 % / 100)``; ``N`` given is
   used as given; 1 keeps every sample.
5. :func:`decimate`: block means of ``N`` samples stamped at the block's centre time
   (a zero-phase boxcar: volt-seconds kept, the current's noise averaged); the last
   incomplete block is left out and counted in the header.
6. the time axis is shifted so that the record starts at ``t = 0`` (the format's rule);
   pre-trigger time is kept, the shift is stated (``time_offset_s``).

The header states the source files, instrument, channels, units, factors, sample
interval, window, step, decimation and the vertical resolution (LSB) found in the samples.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import dataformat
from ..errors import InstrumentFormatError
from .capture import OVER_RANGE_ABS, Capture, Resolution, TimeAxis, infer_lsb

__all__ = ['ImportOptions', 'ImportedRecord', 'Signals', 'Step', 'Decimation',
           'scaled_signals', 'window', 'find_step', 'choose_decimation', 'decimate',
           'build_record', 'write_record', 'AUTO_TARGET_INTERVAL_S', 'EXPERIMENTS']

#: Experiments an import can write.
EXPERIMENTS = ('step', 'pwm', 'operation')
#: ``--decimate auto`` never makes the sample interval longer than this [s] (50 kHz: the
#: paper's bench rate, 20 samples over the shortest spool transit of a small valve).
AUTO_TARGET_INTERVAL_S = 20e-6
#: ... nor longer than the current's 10-90 % rise after the step over this.
AUTO_RISE_FRACTION = 100.0
#: An edge must exceed this [V] to count as the step.
_MIN_STEP_V = 0.5
_ROLE_UNIT = {'voltage': 'V', 'current': 'A'}
_ROLE_OPTION = {'voltage': '--voltage-scale V_PER_UNIT', 'current': '--current-scale A_PER_UNIT'}


@dataclass(frozen=True)
class ImportOptions:
    """What the user asked for (the command line's options, in SI units).

    Attributes
    ----------
    current : str
        Current channel as the file names it.
    voltage : str or None
        Voltage channel (``None`` only for ``operation`` is refused: the PWM is needed).
    time : str or None
        Time column (plain CSV) or channel (TDMS without waveform properties).
    voltage_scale, current_scale : float or None
        Probe factors [V per file unit], [A per file unit], applied after the file's units
        are converted; ``None``: 1 where the unit fits the role.
    experiment : str
        ``step``, ``pwm`` or ``operation``.
    supply_pressure_pa, output_pressure_pa : float or None
        Gauge pressures [Pa] for the header.
    start_s, stop_s : float or None
        Window in the file's time [s].
    decimate : int or None
        Block length; ``None`` for ``auto``.
    """

    current: str
    voltage: str | None = None
    time: str | None = None
    voltage_scale: float | None = None
    current_scale: float | None = None
    experiment: str = 'step'
    supply_pressure_pa: float | None = None
    output_pressure_pa: float | None = None
    start_s: float | None = None
    stop_s: float | None = None
    decimate: int | None = None

    def channels(self) -> dict[str, str]:
        """Role -> channel name, for :func:`~.detect.read_capture`."""
        out = {'current': self.current}
        if self.voltage is not None:
            out['voltage'] = self.voltage
        return out


@dataclass(frozen=True)
class Signals:
    """The chosen channels in SI units on the capture's time axis.

    Attributes
    ----------
    time : TimeAxis
    voltage_v, current_a : numpy.ndarray, shape (n,)
    meta : dict of str to str
        Channel, unit and factor facts for the header.
    notes : list of str
    """

    time: TimeAxis
    voltage_v: np.ndarray
    current_a: np.ndarray
    meta: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def _scale(capture: Capture, role: str, given: float | None) -> tuple[float, str]:
    ch = capture.channels[role]
    want = _ROLE_UNIT[role]
    if given is not None and (not math.isfinite(given) or given == 0.0):
        raise InstrumentFormatError(ch.source, None, f'{_ROLE_OPTION[role].split()[0]} '
                                    f'{given!r} must be a finite, non-zero factor')
    if ch.si_unit is None:
        factor = 1.0 if given is None else given
        return factor, (f'{ch.name}: the file states no unit; values taken as {want}'
                        + (f' x {factor:g}' if given is not None else ''))
    if ch.si_unit != want and given is None:
        raise InstrumentFormatError(
            ch.source, None, f'{role} channel {ch.name} is in {ch.file_unit} (as the file '
            f'states it); give {_ROLE_OPTION[role]} (the probe\'s or shunt\'s factor)')
    factor = 1.0 if given is None else given
    return factor, (f'{ch.name}: {ch.file_unit} -> {ch.si_unit} x {ch.factor:g}'
                    + (f', then x {factor:g} {want}/{ch.si_unit}' if given is not None
                       else ''))


def scaled_signals(capture: Capture, options: ImportOptions) -> Signals:
    """The voltage and current in V and A, over-range samples handled.

    Raises
    ------
    InstrumentFormatError
        A unit that does not fit its role without a factor, an over-range voltage sample
        (naming the row), a current beyond the format's plausible range.
    """
    meta: dict[str, str] = {}
    notes: list[str] = []
    out = {}
    for role in ('voltage', 'current'):
        ch = capture.channels[role]
        factor, how = _scale(capture, role, getattr(options, f'{role}_scale'))
        values = capture.values[role] * factor
        bad = ~np.isfinite(values) | (np.abs(values) >= OVER_RANGE_ABS * abs(factor))
        n_bad = int(np.count_nonzero(bad))
        if n_bad and role == 'voltage':
            k = int(np.flatnonzero(bad)[0])
            row = capture.first_row.get(role)
            raise InstrumentFormatError(ch.source, None if row is None else row + k,
                                        f'voltage channel {ch.name} is over range or missing '
                                        f'at sample {k}; capture with a larger V/div')
        if n_bad:
            values = np.where(bad, np.nan, values)
            notes.append(f'{n_bad} current samples over range or missing: kept as missing '
                         'values')
        out[role] = values
        meta[f'{role}_channel'] = ch.name
        meta[f'{role}_unit_in_file'] = ch.file_unit or 'not stated'
        meta[f'{role}_scale_{_ROLE_UNIT[role].lower()}_per_unit'] = f'{factor:.10g}'
        meta[f'{role}_conversion'] = how
        for key, value in ch.stated.items():
            meta[f'{role}_{key.replace(" ", "_").casefold()}'] = value
    peak = float(np.nanmax(np.abs(out['current']))) if np.isfinite(out['current']).any() else 0
    if peak > dataformat.MAX_ABS_CURRENT_A:
        ch = capture.channels['current']
        raise InstrumentFormatError(ch.source, None, f'current channel {ch.name} reaches '
                                    f'{peak:.4g} A, beyond a coil current '
                                    f'({dataformat.MAX_ABS_CURRENT_A:g} A); check '
                                    '--current-scale and the channel\'s unit')
    return Signals(capture.time, out['voltage'], out['current'], meta, notes)


@dataclass(frozen=True)
class Window:
    """Samples ``start:stop`` of the capture kept for the record."""

    start: int
    stop: int
    text: str


def window(path: str, axis: TimeAxis, start_s: float | None, stop_s: float | None
           ) -> Window:
    """The samples between ``start_s`` and ``stop_s`` (file time, inclusive) [s].

    Raises
    ------
    InstrumentFormatError
        The window is empty or outside the capture.
    """
    a = 0 if start_s is None else axis.index_at(start_s, 'left')
    b = axis.n if stop_s is None else axis.index_at(stop_s, 'right')
    first, last = float(axis.times(0, 1)[0]), float(axis.times(axis.n - 1)[0])
    if b - a < 10:
        raise InstrumentFormatError(path, None, f'window --start {start_s} --stop {stop_s} s '
                                    f'holds {max(b - a, 0)} samples; the capture runs from '
                                    f'{first:.9g} s to {last:.9g} s')
    if start_s is None and stop_s is None:
        return Window(a, b, 'the whole capture')
    return Window(a, b, f'file time {float(axis.times(a, a + 1)[0]):.9g} s to '
                  f'{float(axis.times(b - 1, b)[0]):.9g} s')


@dataclass(frozen=True)
class Step:
    """The first voltage edge: index in the window, levels before and after [V]."""

    index: int
    before_v: float
    after_v: float


def find_step(voltage_v: np.ndarray) -> Step | None:
    """The first voltage edge: the first of three samples in a row beyond half-way from
    the level before (median of the first samples, at most 2 % and 64 of them) to the
    largest excursion from it.

    Returns
    -------
    Step or None
        ``None`` when the voltage never moves by more than 0.5 V for three samples.
    """
    n = voltage_v.size
    before = float(np.median(voltage_v[:max(3, min(n // 50, 64))]))
    dev = voltage_v - before
    hi, lo = float(np.max(dev)), float(np.min(dev))
    amp = hi if abs(hi) >= abs(lo) else lo
    if abs(amp) < _MIN_STEP_V:
        return None
    beyond = dev * math.copysign(1.0, amp) > 0.5 * abs(amp)
    run = beyond[:-2] & beyond[1:-1] & beyond[2:]
    crossed = np.flatnonzero(run)
    if not crossed.size:
        return None
    k = int(crossed[0])
    after = voltage_v[k:k + max(5, min((n - k) // 50, 64))]
    return Step(k, before, float(np.median(after)))


@dataclass(frozen=True)
class Decimation:
    """Block length and how it was chosen."""

    factor: int
    text: str


def _rise_time_s(t: np.ndarray, i: np.ndarray, v: np.ndarray, step: Step) -> float | None:
    """10-90 % rise of the current after the step, towards its level late in the on-phase."""
    on = np.abs(v[step.index:] - step.before_v) > 0.5 * abs(step.after_v - step.before_v)
    off = np.flatnonzero(~on)
    end = step.index + (int(off[0]) if off.size else on.size)
    seg = i[step.index:end]
    if seg.size < 20 or not np.isfinite(seg).any():
        return None
    i0 = float(np.nanmedian(i[:max(1, step.index)]))
    final = float(np.nanmedian(seg[-max(3, seg.size // 10):]))
    swing = final - i0
    if abs(swing) <= 0.0:
        return None
    frac = (seg - i0) / swing
    k10 = np.flatnonzero(frac >= 0.1)
    k90 = np.flatnonzero(frac >= 0.9)
    if not k10.size or not k90.size:
        return None
    tt = t[step.index:end]
    return float(tt[k90[0]] - tt[k10[0]])


def choose_decimation(sig: Signals, win: Window, step: Step | None, asked: int | None
                      ) -> Decimation:
    """The block length: as asked, or by the ``auto`` rule (module notes)."""
    axis = sig.time
    dt = axis.dt_s if axis.dt_s is not None else float(
        np.median(np.diff(axis.times(win.start, min(win.stop, win.start + 100_000)))))
    if asked is not None:
        return Decimation(asked, f'{asked} (as asked)' if asked > 1 else '1 (every sample)')
    target = AUTO_TARGET_INTERVAL_S
    rise = None
    if step is not None:
        t = axis.times(win.start, win.stop)
        rise = _rise_time_s(t, sig.current_a[win.start:win.stop],
                            sig.voltage_v[win.start:win.stop], step)
        if rise is not None and rise > 0.0:
            target = min(target, rise / AUTO_RISE_FRACTION)
    n = max(1, int(math.floor(target / dt + 1e-9)))
    basis = (f'rise 10-90 % {rise:.3g} s' if rise is not None else 'no current rise found')
    return Decimation(n, f'{n} (auto: interval <= min(20 us, current rise 10-90 % / 100) = '
                      f'{target:.3g} s; {basis}; sample interval {dt:.6g} s)')


def decimate(t: np.ndarray, columns: dict[str, np.ndarray], factor: int
             ) -> tuple[np.ndarray, dict[str, np.ndarray], int]:
    """Block means of ``factor`` samples, stamped at the mean time of each block.

    Returns
    -------
    t, columns, left_out
        The decimated times and columns, and the samples of the last incomplete block.
    """
    if factor == 1:
        return t, columns, 0
    m = t.size // factor
    left = t.size - m * factor
    out = {k: v[:m * factor].reshape(m, factor).mean(axis=1) for k, v in columns.items()}
    return t[:m * factor].reshape(m, factor).mean(axis=1), out, left


@dataclass(frozen=True)
class PwmInForce:
    """Main PWM duty and frequency in force at each sample, derived from its voltage."""

    duty: np.ndarray
    frequency_hz: np.ndarray
    supply_v: float
    n_periods: int


def pwm_in_force(path: str, t: np.ndarray, v: np.ndarray) -> PwmInForce:
    """Duty and frequency of the main PWM at each sample, period by period.

    A period runs from a rising edge (half-way between the 5th and 95th percentile) to
    the next; its duty is the high time over the period. Before the first rising edge the
    first period's duty and frequency hold if the voltage is high there (the PWM was
    running), else the duty is 0; after the last one, the last period's hold. The supply
    voltage is the median of the high samples.

    Raises
    ------
    InstrumentFormatError
        No PWM (the voltage moves less than 0.5 V) or fewer than two rising edges.
    """
    lo, hi = float(np.percentile(v, 5)), float(np.percentile(v, 95))
    if hi - lo < _MIN_STEP_V:
        raise InstrumentFormatError(path, None, f'no PWM in the voltage channel (it stays '
                                    f'between {lo:.3g} V and {hi:.3g} V)')
    high = v > 0.5 * (lo + hi)
    rises = np.flatnonzero(high[1:] & ~high[:-1]) + 1
    falls = np.flatnonzero(~high[1:] & high[:-1]) + 1
    if rises.size < 2:
        raise InstrumentFormatError(path, None, f'{rises.size} rising PWM edges in the '
                                    'voltage channel; an operation record needs at least two '
                                    'whole periods')
    duty = np.zeros(v.size)
    freq = np.empty(v.size)
    for a, b in zip(rises[:-1], rises[1:]):
        period = float(t[b] - t[a])
        f = falls[(falls > a) & (falls < b)]
        high_s = float(t[f[0]] - t[a]) if f.size else period
        duty[a:b] = high_s / period
        freq[a:b] = 1.0 / period
    freq[:rises[0]] = freq[rises[0]]
    if high[:rises[0]].any():
        duty[:rises[0]] = duty[rises[0]]
    duty[rises[-1]:] = duty[rises[-1] - 1]
    freq[rises[-1]:] = freq[rises[-1] - 1]
    return PwmInForce(duty, freq, float(np.median(v[high])), int(rises.size - 1))


@dataclass(frozen=True)
class ImportedRecord:
    """A record ready to be written: the header and the columns of the format.

    Attributes
    ----------
    metadata : dict of str to str
        ``# key: value`` rows in order.
    columns : dict of str to numpy.ndarray, shape (n,)
    notes : tuple of str
        What the import did that a user should know (also in the header).
    """

    metadata: dict[str, str]
    columns: dict[str, np.ndarray]
    notes: tuple[str, ...]

    @property
    def n_rows(self) -> int:
        return int(self.columns['t'].size)


def _resolution_meta(role: str, unit: str, res: Resolution | None) -> dict[str, str]:
    if res is None:
        return {f'{role}_resolution': 'no quantisation grid found in the samples'}
    return {f'{role}_lsb_{unit.lower()}': f'{res.lsb:.6g}',
            f'{role}_lsb_source': f'inferred from the samples ({res.levels_used} levels '
                                  f'used on a grid of {res.lsb:.6g} {unit}, before '
                                  'decimation)'}


def _columns(options: ImportOptions, path: str, t: np.ndarray, v: np.ndarray,
             i: np.ndarray, dec: Decimation) -> tuple[np.ndarray, dict, dict, int]:
    """Decimated columns of the format for the experiment, and extra header keys."""
    extra: dict[str, str] = {}
    if options.experiment != 'operation':
        t_d, cols, left = decimate(t, {'voltage': v, 'current': i}, dec.factor)
        return t_d, cols, extra, left
    pwm = pwm_in_force(path, t, v)
    t_d, cols, left = decimate(t, {'current': i}, dec.factor)
    centre = np.arange(t_d.size) * dec.factor + (dec.factor - 1) // 2
    cols = {'duty': pwm.duty[centre], 'pwm_frequency_hz': pwm.frequency_hz[centre],
            'current': cols['current']}
    extra['supply_voltage_v'] = f'{pwm.supply_v:.6g}'
    extra['pwm_from'] = (f'{pwm.n_periods} periods of the voltage channel (rising edge to '
                         'rising edge); supply voltage = median high level')
    return t_d, cols, extra, left


def build_record(capture: Capture, options: ImportOptions) -> ImportedRecord:
    """The record of the measured-data format for a capture (stages in the module notes).

    Raises
    ------
    InstrumentFormatError
        Bad factors or units, an empty window, no voltage step in a ``step`` record, more
        rows than the format allows.
    """
    path = capture.header.path
    sig = scaled_signals(capture, options)
    win = window(path, sig.time, options.start_s, options.stop_s)
    t = sig.time.times(win.start, win.stop)
    v = sig.voltage_v[win.start:win.stop]
    i = sig.current_a[win.start:win.stop]
    step = find_step(v)
    vname = capture.channels['voltage'].name
    if step is None and options.experiment == 'step':
        raise InstrumentFormatError(path, None, f'no voltage step in channel {vname} (it '
                                    f'moves less than {_MIN_STEP_V} V): a step record needs '
                                    'one; check --voltage')
    res_v, res_i = infer_lsb(v), infer_lsb(i)
    dec = choose_decimation(sig, win, step, options.decimate)
    t_d, cols, extra, left = _columns(options, path, t, v, i, dec)
    if t_d.size > dataformat.MAX_ROWS:
        raise InstrumentFormatError(path, None, f'{t_d.size} rows after decimation by '
                                    f'{dec.factor}; the format holds at most '
                                    f'{dataformat.MAX_ROWS}: use --decimate or a window')
    t0 = float(t[0])
    t_out = np.maximum(t_d - t0, 0.0)
    notes = list(capture.notes) + sig.notes
    meta = _header(capture, options, sig, win, dec, t_out, t0)
    meta.update(extra)
    if step is not None:
        meta['step_time_s'] = f'{float(t[step.index]) - t0:.10g}'
        meta['step_time_in_file_s'] = f'{float(t[step.index]):.10g}'
        meta['step_levels_v'] = f'{step.before_v:.4g} -> {step.after_v:.4g}'
        if step.index >= 5:
            meta['current_before_step_a'] = f'{float(np.nanmedian(i[:step.index])):.4g}'
        if step.index < 5 and options.experiment == 'step':
            notes.append('the voltage is on from the first sample: the valve may not be at '
                         'rest at t = 0 (capture some pre-trigger time)')
    meta.update(_resolution_meta('voltage', 'V', res_v))
    meta.update(_resolution_meta('current', 'A', res_i))
    if left:
        meta['samples_left_out'] = f'{left} (the last, incomplete decimation block)'
    for k, note in enumerate(notes, start=1):
        meta[f'import_note_{k}'] = note
    return ImportedRecord(meta, {'t': t_out, **cols}, tuple(notes))


def _header(capture: Capture, options: ImportOptions, sig: Signals, win: Window,
            dec: Decimation, t_out: np.ndarray, t0: float) -> dict[str, str]:
    """The record's header rows: the format's keys first, then the import's."""
    meta: dict[str, str] = {'experiment': options.experiment}
    if options.supply_pressure_pa is not None:
        meta['supply_pressure_pa'] = f'{options.supply_pressure_pa:.10g}'
    if options.output_pressure_pa is not None:
        meta['output_pressure_pa'] = f'{options.output_pressure_pa:.10g}'
    if t_out.size > 1:
        interval = float(t_out[-1] - t_out[0]) / (t_out.size - 1)
        meta['sample_rate_hz'] = f'{1.0 / interval:.10g}'
    header = capture.header
    meta['source_files'] = ', '.join(capture.paths)
    meta['instrument'] = header.instrument
    meta['export_format'] = header.reader.title if header.reader is not None else ''
    meta.update(sig.meta)
    if sig.time.dt_s is not None:
        meta['sample_interval_in_file_s'] = f'{sig.time.dt_s:.10g}'
    meta['time_base'] = sig.time.how
    meta['window'] = win.text
    meta['time_offset_s'] = f'{-t0:.10g}'
    meta['time_note'] = (f'file time {t0:.10g} s is t = 0 here (t = file time + '
                         f'{-t0:.10g} s); negative file time is pre-trigger')
    meta['decimation'] = dec.text
    if dec.factor > 1:
        meta['decimation_method'] = (f'block means of {dec.factor} samples stamped at the '
                                     'block centre time')
    return meta


def write_record(path: str | os.PathLike[str], record: ImportedRecord) -> Path:
    """Write the record with the format's writer (via a temporary file, then renamed)."""
    out = Path(path)
    tmp = out.with_name(out.name + '.part')
    try:
        dataformat.write_table(tmp, record.metadata, record.columns)
        os.replace(tmp, out)
    finally:
        if tmp.exists():
            tmp.unlink()
    return out
