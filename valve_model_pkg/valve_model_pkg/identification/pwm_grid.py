"""Main PWM commands of records through the drive electronics, reconstructed.

A record of a valve in service (``operation``) gives the duty and frequency *in force*
per sample, a bench ``pwm`` record the main PWM voltage itself; the model needs commands
it latches at the period starts the valve saw (``InputTrace.pwm_commands``). This module
rebuilds the main PWM period grid from the record: :func:`drive_from_in_force` from the
samples at which the command in force changes, :func:`drive_from_main_pwm` from the edges
of the main PWM column. :func:`discard_for` leaves the start of a record in motion out of
the errors (the model starts at rest). :func:`operation_measurement` builds the
measurement of an operational record from a bag's columns.
"""
from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from ..errors import MeasurementFormatError
from .measurement import DriveInput, Measurement

__all__ = ['DISCARD_MIN_S', 'DISCARD_PERIODS', 'discard_for', 'drive_from_in_force',
           'drive_from_main_pwm', 'interval_time_axis', 'operation_measurement']

_LOG = logging.getLogger(__name__)

#: A record that starts in motion: the model starts at rest, so the errors leave out the
#: first ``max(DISCARD_PERIODS main PWM periods, DISCARD_MIN_S)`` of it.
DISCARD_PERIODS = 3
DISCARD_MIN_S = 0.05
#: An interval-mean current at most this is exactly 0 (the coil never energised) [A].
_REST_MEAN_A = 1e-9
#: Time tolerance of the phase candidates [s].
_PHASE_TOL_S = 1e-9


def _phase_from_changes(t: np.ndarray, change_idx: np.ndarray, period_s: float,
                        rise: tuple[float, float] | None = None
                        ) -> tuple[float, tuple[float, float]] | None:
    """First main PWM period start in [t0, t0 + T) consistent with the changes seen.

    A change of the command in force seen at sample ``k`` means a period start in
    ``(t[k-1], t[k]]``. The phase that satisfies most such intervals (the middle of the
    widest set that does) is returned with the range of shifts that satisfy as many
    (the identification refines the phase in it from the current); ``None`` without any
    change. ``rise`` = ``[lo, hi)``: a period start the current shows (the first rise of
    the interval-mean current from exactly 0), kept as a hard constraint when some phase
    meets it. The interval ends are candidates too: a controller whose PWM grid is locked
    to its telemetry grid (the emulator: 20 ms = 20 telemetry periods) starts a period
    exactly at a sample time, which the middle of the range misses by half a sample.
    """
    if change_idx.size == 0:
        return None
    a, b = t[change_idx - 1], t[change_idx]
    ends = [b] + ([np.array([rise[0]])] if rise is not None else [])
    cand = np.sort(np.concatenate(
        [t[0] + period_s * (np.arange(4000) + 0.5) / 4000.0]
        + [t[0] + np.mod(e - t[0], period_s) for e in ends]))
    # 1 ns tolerance: a start at exactly b (or at the rise) stays in (a, b] after mod
    d = np.mod(b[None, :] - cand[:, None] + _PHASE_TOL_S, period_s) - _PHASE_TOL_S
    ok = d < (b - a)[None, :]
    score = ok.sum(axis=1)
    if rise is not None:
        dr = np.mod(cand - rise[0] + _PHASE_TOL_S, period_s) - _PHASE_TOL_S
        meets = dr < rise[1] - rise[0]
        if np.any(meets):
            score = np.where(meets, score, -1)
    best = score == score.max()
    # middle of the longest run of best candidates (circular runs are rare; take linear)
    idx = np.flatnonzero(best)
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    run = max(runs, key=len)
    mid = float(cand[run[len(run) // 2]])
    return mid, (float(cand[run[0]]) - mid, float(cand[run[-1]]) - mid)


def _first_rise(t: np.ndarray, current: np.ndarray | None, duty: np.ndarray,
                end: int) -> tuple[float, float] | None:
    """``[t[j], t[j + 1])``: where the first period start lies if the interval-mean current
    is exactly 0 up to sample j (the coil was never energised before t[j]) and not at j + 1
    (within the first ``end`` samples, with a non-zero duty by then); else None."""
    if current is None:
        return None
    live = np.flatnonzero(~(np.abs(current[:end]) <= _REST_MEAN_A))
    if live.size == 0 or live[0] == 0 or not np.any(duty[:live[0] + 1] > 0.0):
        return None
    j = int(live[0]) - 1
    return float(t[j]), float(t[j + 1])


def drive_from_in_force(t: np.ndarray, duty: np.ndarray, freq: np.ndarray, supply_v: float,
                        current_mean: np.ndarray | None = None
                        ) -> tuple[DriveInput, list[str]]:
    """Commands of an operational record (duty and frequency *in force* per sample).

    The main PWM period grid is reconstructed: its phase from the samples at which the
    command in force changes (each change happens at a period start between the previous
    sample and that one), then period by period with the frequency in force. With
    ``current_mean`` (interval means [A]) the first rise of the current from exactly 0
    narrows the phase (see :func:`_first_rise`).

    Returns
    -------
    drive : DriveInput
    notes : list of str
    """
    notes: list[str] = []
    # A non-zero command is latched at a period start; a duty of 0 acts at once (close
    # semantics), so only changes to a non-zero duty place the period grid.
    change = np.flatnonzero((np.diff(duty) != 0) | (np.diff(freq) != 0)) + 1
    offs = change[duty[change] == 0.0]
    change = change[duty[change] > 0.0]
    f_first = freq[0]
    first_f_change = np.flatnonzero(np.diff(freq) != 0)
    end_first = first_f_change[0] + 1 if first_f_change.size else t.size
    found = _phase_from_changes(t, change[change <= end_first], 1.0 / f_first,
                                _first_rise(t, current_mean, duty, end_first))
    if found is None:
        phase = float(t[0])
        prange = (0.0, 1.0 / f_first)
        notes.append('the command in force never changes: the main PWM phase cannot be '
                     'read from the record; it is found from the current')
    else:
        phase, prange = found
        notes.append(f'main PWM period grid reconstructed from the command changes: first '
                     f'period start at {phase * 1e3:.3f} ms')
    # the period in progress at the first sample started one period before the phase
    s = phase
    while s - 1.0 / f_first >= -_PHASE_TOL_S:
        s -= 1.0 / f_first
    if s < _PHASE_TOL_S:
        s = 0.0  # a start at t = 0 within rounding (a phase on the sample grid)
    starts, dl, fl = [], [], []
    t_end = float(t[-1])
    while s <= t_end:
        k = min(int(np.searchsorted(t, s - 1e-12, side='left')), t.size - 1)
        starts.append(s)
        dl.append(float(duty[k]))
        fl.append(float(freq[k]))
        s += 1.0 / freq[k]
    drive = DriveInput.from_periods(starts, dl, fl, supply_v)
    if offs.size:
        on_samples = found is not None and float(np.min(np.abs(t - phase))) < 1e-6
        if on_samples:
            # The period grid lies on the sample instants: the controller acts on its own
            # telemetry grid (the emulator in lockstep does), so a switch-off seen in an
            # interval acted at its start (its middle would put half an interval of supply
            # too much on the coil).
            t_off = t[offs - 1].astype(float)
            where = 'at the start of the interval in which they were seen (the period grid ' \
                'lies on the sample instants)'
        else:
            # unknown instant within the interval: its middle
            t_off = 0.5 * (t[offs - 1] + t[offs])
            where = 'mid-interval'
        drive = drive.with_offs(t_off, np.interp(t_off, t, freq))
        notes.append(f'{offs.size} switch-offs (duty 0 acts at once) placed {where}')
    return replace(drive, phase_range_s=prange), notes


def drive_from_main_pwm(t: np.ndarray, v: np.ndarray, supply_v: float,
                        freq_hz: float | None) -> DriveInput:
    """Commands of a bench ``pwm`` record from its main PWM voltage column (its edges).

    Parameters
    ----------
    t : numpy.ndarray, shape (n,)
        Sample times [s].
    v : numpy.ndarray, shape (n,)
        Main PWM voltage [V]; high above half its maximum.
    supply_v : float
        Drive supply voltage [V].
    freq_hz : float or None
        Main PWM frequency [Hz] for the last period (else taken from its edges).
    """
    on = v > 0.5 * float(np.max(v))
    rise = np.flatnonzero(on & ~np.concatenate(([False], on[:-1])))
    fall = np.flatnonzero(~on & np.concatenate(([False], on[:-1])))
    tr = t[rise].astype(float)
    tr[tr == t[0]] = 0.0 if t[0] == 0.0 else tr[tr == t[0]]
    starts, dl, fl = [], [], []
    dt = float(np.median(np.diff(t)))
    for j, r in enumerate(tr):
        f_end = t[fall[fall > rise[j]][0]] if np.any(fall > rise[j]) else t[-1] + dt
        if j + 1 < tr.size:
            period = tr[j + 1] - r
        elif freq_hz:
            period = 1.0 / freq_hz
        else:
            period = (f_end - r) * 2.0 if np.any(fall > rise[j]) else (t[-1] - r + dt) * 1.001
        starts.append(float(r))
        fl.append(1.0 / period)
        dl.append(float(min(1.0, max(0.0, (f_end - r) / period))))
    return DriveInput.from_periods(starts, dl, fl, supply_v)


def discard_for(drive: DriveInput, t0: float, at_rest: bool) -> tuple[float, list[str]]:
    """Where the errors of a record starting at ``t0`` [s] begin, and the note saying why.

    A record at rest is compared from its first sample; one in motion from ``max(
    DISCARD_PERIODS`` main PWM periods of ``drive``, ``DISCARD_MIN_S)`` after ``t0``.
    """
    if at_rest:
        return t0, ['assumed to start at rest (duty 0 for at least one PWM period): the '
                    'model starts at rest, every sample is compared']
    periods = drive.period_starts_s
    first = periods[periods >= t0]
    span = (DISCARD_PERIODS / drive.pwm_frequency_hz[-1]) if first.size < DISCARD_PERIODS + 1 \
        else first[DISCARD_PERIODS] - t0
    cut = t0 + max(span, DISCARD_MIN_S)
    return cut, [f'starts in motion: the model starts at rest, so the first {cut - t0:.3g} s '
                 f'(max of {DISCARD_PERIODS} PWM periods and {DISCARD_MIN_S:g} s) are left '
                 'out of the errors']


def interval_time_axis(t: np.ndarray, notes: list[str]) -> np.ndarray:
    """Times [s] of interval means whose first message is at ``t[0] = 0``, moved so that
    time 0 is the start of the first message's interval (one median step before it).

    Each mean covers the interval since the previous message, the first message's too; the
    model starts at rest at time 0, so it then covers every recorded interval (a record of
    a simulation whose first message comes one step after its start is reproduced from its
    first sample). A note says so.
    """
    step = float(np.median(np.diff(t)))
    notes.append(f'time from the start of the first message\'s interval ({step * 1e3:.6g} ms '
                 'before it): each current mean covers the interval since the previous '
                 'message')
    return t - t[0] + step


def operation_measurement(spath: str, t: np.ndarray, duty: np.ndarray, freq: np.ndarray,
                          current: np.ndarray, *, supply_v: float, supply_pa: float | None,
                          output_pa: float, notes: list[str], n_gaps: int,
                          interval_means: bool, described: str,
                          metadata: dict[str, str],
                          coil_voltage_mean: np.ndarray | None = None) -> Measurement:
    """An operational record (drive electronics on) from duty and frequency in force.

    Parameters
    ----------
    spath : str
        The source, named in errors.
    t : numpy.ndarray, shape (n,)
        Sample times [s] from 0 (the first message). With ``interval_means`` the record's
        time 0 is moved to the start of the first message's interval, one sample step
        before it (:func:`interval_time_axis`).
    duty, freq : numpy.ndarray, shape (n,)
        Duty [1] and main PWM frequency [Hz] in force at each sample.
    current : numpy.ndarray, shape (n,)
        Coil current [A]: interval means since the previous sample (``interval_means``),
        else instantaneous samples.
    supply_v : float
        Drive supply voltage [V].
    supply_pa, output_pa : float or None, float
        Supply and output pressure, gauge [Pa].
    notes : list of str
        Notes so far; this record's are appended.
    n_gaps : int
        Gaps of the record (lost messages).
    interval_means : bool
        How the current is compared (``sampling`` of the measurement).
    described : str
        Where the data come from and how they are compared, for the last note.
    metadata : dict
        First metadata entries (experiment, valve or source, topic).
    coil_voltage_mean : numpy.ndarray or None, shape (n,)
        Measured mean coil voltage over each current interval [V] (``nan`` where
        missing), when the source carries it.

    Raises
    ------
    MeasurementFormatError
        A duty outside [0, 1] or a frequency not above 0.
    """
    bad = np.flatnonzero(~np.isfinite(freq) | ~np.isfinite(duty) | (freq <= 0.0)
                         | (duty < 0.0) | (duty > 1.0))
    if bad.size:
        raise MeasurementFormatError(spath, None, f'message {int(bad[0])} has duty '
                                     f'{duty[bad[0]]!r} / pwm_frequency {freq[bad[0]]!r}')
    if interval_means:
        t = interval_time_axis(t, notes)
    drive, dnotes = drive_from_in_force(t, duty, freq, supply_v,
                                        current if interval_means else None)
    notes += dnotes
    moving = np.flatnonzero(duty > 0.0)
    at_rest = bool(moving.size and t[moving[0]] - t[0] >= 1.0 / freq[0])
    cut, cnotes = discard_for(drive, float(t[0]), at_rest)
    notes += cnotes
    n_missing = int(np.count_nonzero(~np.isfinite(current)))
    rate = 1.0 / float(np.median(np.diff(t)))
    notes.append(f'operation record {described}')
    metadata = dict(metadata)
    if supply_pa is not None:
        metadata['supply_pressure_pa'] = f'{supply_pa:g}'
    metadata.update(sample_rate_hz=f'{rate:g}', supply_voltage_v=f'{supply_v:g}',
                    current_averaging='interval_mean' if interval_means else 'instantaneous')
    for note in notes:
        _LOG.info('%s: %s', spath, note)
    return Measurement(
        source=spath, t_s=t, voltage_v=drive.main_pwm_level(t), current_a=current,
        supply_pressure_pa=supply_pa, output_pressure_pa=output_pa, experiment='operation',
        metadata=metadata, notes=tuple(notes), n_missing_values=n_missing, n_gaps=n_gaps,
        drive=drive, sampling='interval_mean' if interval_means else 'instant',
        exclude_before_s=cut, coil_voltage_mean_v=coil_voltage_mean)
