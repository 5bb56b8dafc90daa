"""Measured valve data in memory: the record every reader returns, and its rules.

A :class:`Measurement` is one measured trace, whatever it was read from: a CSV file of the
measured-data format (:mod:`.csv_reader`), a rosbag2 bag (:mod:`.bag_reader`,
:mod:`.topic_map`). Records through the drive electronics carry their main PWM commands
as a :class:`DriveInput` (reconstructed by :mod:`.pwm_grid`).

Rules every reader applies: at least :data:`MIN_SAMPLES` samples, a time axis that
increases strictly from at or after zero (:func:`check_time_axis`), some excitation
(:func:`check_excitation`), one pressure per record (:func:`median_pressure`). Nothing is
dropped silently: a sample whose current is missing is kept as ``nan`` (and excluded from
the error integrals), gaps in the time axis are counted, and every such finding is listed
in :attr:`Measurement.notes`.

A coarse instrument's current takes values on a grid (an 8-bit scope: 10-20 mA steps):
:func:`with_current_lsb` sets :attr:`Measurement.current_lsb_a` from the record's header
(``current_lsb_a``, which ``valve_import`` writes) or from the samples, and the noise model
of the identification counts the quantisation (:func:`.sensitivity.noise_estimate`).

Records with different sample rates are combined by keeping each on its own time base:
the model is simulated at its own step and sampled at each record's sample times, and the
error integrals are integrals over time, so a 1 kHz record and a 50 kHz one weigh by
duration, not by sample count.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from valve_model_pkg import dataformat

from ..errors import MeasurementFormatError

__all__ = ['CurrentResponse', 'DriveInput', 'MIN_SAMPLES', 'MIN_LSB_LEVELS', 'Measurement',
           'RESPONSE_NOISE_SIGMAS', 'RESPONSE_SHARE_OF_V_OVER_R', 'check_current_response',
           'check_excitation', 'current_response',
           'check_time_axis', 'hold_out', 'mean_voltage_column', 'median_pressure', 'refused_bag',
           'window', 'with_current_lsb']

#: Fewest samples a record must have.
MIN_SAMPLES = 10
#: Fewest distinct current values from which a quantisation step is inferred: fewer leave
#: the step unknown (two or three levels fit many grids).
MIN_LSB_LEVELS = 8
#: Most steps of an inferred grid over the record's current range: a finer grid is the
#: print rounding of the file (beyond a 16-bit converter), not the instrument's, and its
#: variance is negligible.
_MAX_LSB_STEPS = 1 << 16
#: A coil voltage at or below this everywhere counts as no excitation [V].
MIN_EXCITATION_V = 1e-3
#: The current while the coil voltage is on must depart from its rest level by more than
#: this many standard deviations of the record's noise (:func:`check_current_response`).
RESPONSE_NOISE_SIGMAS = 5.0
#: ... and by more than this share of the steady current V/R of the parameter set's coil
#: resistance: less would take a coil of 100 times that resistance.
RESPONSE_SHARE_OF_V_OVER_R = 0.01
#: A sample counts as "voltage on" at or above this share of the record's largest |voltage|.
_ON_SHARE = 0.5
#: Percentile of |current - rest level| over the samples while on taken as the response.
_RESPONSE_PERCENTILE = 90.0
#: A command is given this long before the period start it must be latched at [s] (the
#: model latches commands at the next period start).
_LATCH_LEAD_S = 1e-6
#: A first period start this close to t = 0 is at t = 0 [s] (a grid shifted by a rounding
#: error would need a lead-in period of that length, i.e. an absurd frequency).
_AT_ZERO_S = 1e-9


def _lead(period_s: float) -> float:
    return min(_LATCH_LEAD_S, 0.25 * period_s)


def _merge_zero_length_periods(starts: Sequence[float], duty: Sequence[float],
                               freq: Sequence[float]
                               ) -> tuple[list[float], list[float], list[float]]:
    """Period starts [s], duty [1] and frequency [Hz] with every start that does not follow
    the kept one before by more than :data:`_AT_ZERO_S` merged into it (its duty and
    frequency replace the earlier ones)."""
    out_s: list[float] = []
    out_d: list[float] = []
    out_f: list[float] = []
    for s, d, f in zip(starts, duty, freq):
        if out_s and s - out_s[-1] <= _AT_ZERO_S:
            out_d[-1], out_f[-1] = d, f
            continue
        out_s.append(float(s))
        out_d.append(float(d))
        out_f.append(float(f))
    return out_s, out_d, out_f


@dataclass(frozen=True)
class DriveInput:
    """Main PWM commands through the drive electronics, as the model's ``pwm_commands``.

    Built by the readers so that the model latches each command at the period start the
    record shows (:func:`~valve_model_pkg.identification.pwm_grid.drive_from_in_force`,
    :func:`~valve_model_pkg.identification.pwm_grid.drive_from_main_pwm`), through
    :meth:`from_periods` and :meth:`with_offs`.

    Attributes
    ----------
    t_s, duty, pwm_frequency_hz, supply_voltage_v : numpy.ndarray, shape (n,)
        Arguments of ``InputTrace.pwm_commands``: command times [s], duty [1], main PWM
        frequency [Hz], drive supply voltage [V].
    period_starts_s : numpy.ndarray, shape (m,)
        The main PWM period starts the reader reconstructed [s].
    high_until_s : numpy.ndarray, shape (m,)
        End of the high phase of each period [s] (for the phases of the residual).
    period_duty, period_freq_hz : numpy.ndarray, shape (m,), optional
        Duty [1] and frequency [Hz] of each period.
    phase_range_s : tuple of float
        Shifts of the period grid [s] the record allows (its changes bound the phase).
    off_times_s, off_freq_hz : numpy.ndarray, optional
        Immediate switch-offs (duty 0 acts at once) [s] and the frequency then [Hz].
    """

    t_s: np.ndarray
    duty: np.ndarray
    pwm_frequency_hz: np.ndarray
    supply_voltage_v: np.ndarray
    period_starts_s: np.ndarray
    high_until_s: np.ndarray
    period_duty: np.ndarray | None = None
    period_freq_hz: np.ndarray | None = None
    phase_range_s: tuple[float, float] = (0.0, 0.0)
    off_times_s: np.ndarray | None = None
    off_freq_hz: np.ndarray | None = None

    def shifted(self, delta_s: float) -> 'DriveInput':
        """The same commands on a period grid moved by ``delta_s`` [s]."""
        starts = self.period_starts_s + delta_s
        keep = starts >= 0.0
        out = DriveInput.from_periods(list(starts[keep]), list(self.period_duty[keep]),
                                      list(self.period_freq_hz[keep]),
                                      float(self.supply_voltage_v[0]))
        if self.off_times_s is not None and self.off_times_s.size:
            out = out.with_offs(self.off_times_s, self.off_freq_hz)
        lo, hi = self.phase_range_s
        return replace(out, phase_range_s=(lo - delta_s, hi - delta_s))

    def main_pwm_level(self, t_s: np.ndarray) -> np.ndarray:
        """Supply voltage where the main PWM is high at ``t_s``, else 0 [V], shape (n,)."""
        k = np.searchsorted(self.period_starts_s, t_s, side='right') - 1
        ok = k >= 0
        kk = np.clip(k, 0, None)
        started = self.high_until_s[kk] > self.period_starts_s[kk]
        high = ok & (t_s < self.high_until_s[kk]) & started
        v = np.interp(t_s, self.t_s, self.supply_voltage_v)
        return np.where(high, v, 0.0)

    @classmethod
    def from_periods(cls, starts: list[float], duty: list[float], freq: list[float],
                     supply_v: float) -> 'DriveInput':
        """Commands that make the model latch each period's (duty, f) at its start.

        Parameters
        ----------
        starts : list of float
            Main PWM period starts [s], increasing.
        duty, freq : list of float
            Duty [1] and frequency [Hz] of each period.
        supply_v : float
            Drive supply voltage [V].

        A period start that does not follow the one before by more than
        :data:`_AT_ZERO_S` ends a period of zero length: the two are merged (the later
        start's duty and frequency hold from the earlier start), so no zero-length period
        reaches the model.
        """
        ts: list[float] = []
        dd: list[float] = []
        ff: list[float] = []
        starts, duty, freq = _merge_zero_length_periods(starts, duty, freq)
        if 0.0 < starts[0] <= _AT_ZERO_S:
            starts = [0.0] + list(starts[1:])
        s0 = starts[0]
        if s0 > 0.0:
            # duty 0 until the first period start, with a pre-period that ends exactly there
            n = max(1, int(math.ceil(s0 / 1e-3)))
            ts.append(0.0)
            dd.append(0.0)
            ff.append(n / s0)
            prev_f = n / s0
        else:
            prev_f = None
        last = (None, None)
        for s, d, f in zip(starts, duty, freq):
            if (d, f) == last:
                continue
            t_cmd = 0.0 if s <= 0.0 else s - _lead(1.0 / prev_f)
            if ts and t_cmd <= ts[-1]:
                t_cmd = ts[-1] + 0.5 * (s - ts[-1])
            ts.append(t_cmd)
            dd.append(d)
            ff.append(f)
            last = (d, f)
            prev_f = f
        st = np.asarray(starts)
        high = st + np.asarray(duty) / np.asarray(freq)
        return cls(t_s=np.asarray(ts), duty=np.asarray(dd), pwm_frequency_hz=np.asarray(ff),
                   supply_voltage_v=np.full(len(ts), float(supply_v)),
                   period_starts_s=st, high_until_s=high, period_duty=np.asarray(duty),
                   period_freq_hz=np.asarray(freq))

    def with_offs(self, t_off: np.ndarray, f_at: np.ndarray) -> 'DriveInput':
        """These commands with immediate duty-0 commands at ``t_off`` [s] merged in; ``f_at``
        [Hz] is the record's frequency at each switch-off."""
        drive = self
        # A switch-off must not move the period grid, and the model latches its frequency at
        # the next period start: it carries the frequency of the model's command in force (in
        # the lead-in before the first period start, the lead-in's, not the record's f_at).
        k_cmd = np.clip(np.searchsorted(drive.t_s, t_off, side='right') - 1, 0, None)
        f_cmd = drive.pwm_frequency_hz[k_cmd]
        # The period commands skip repeats of the (duty, f) before; after a switch-off the
        # next non-zero period must be commanded again, or the model stays off for it.
        re_t, re_d, re_f = [], [], []
        if drive.period_duty is not None:
            starts = drive.period_starts_s
            for t0, t1 in zip(t_off, np.append(t_off[1:], np.inf)):
                j = int(np.searchsorted(starts, t0, side='right'))
                if j >= starts.size or starts[j] >= t1 or drive.period_duty[j] <= 0.0:
                    continue
                if not np.any((drive.t_s > t0) & (drive.t_s < starts[j])):
                    re_t.append(max(starts[j] - _lead(1.0 / drive.period_freq_hz[j]),
                                    0.5 * (t0 + starts[j])))
                    re_d.append(float(drive.period_duty[j]))
                    re_f.append(float(drive.period_freq_hz[j]))
        ts = np.concatenate((drive.t_s, t_off, re_t))
        order = np.argsort(ts, kind='stable')
        out = replace(
            drive, t_s=ts[order],
            duty=np.concatenate((drive.duty, np.zeros(t_off.size), re_d))[order],
            pwm_frequency_hz=np.concatenate((drive.pwm_frequency_hz, f_cmd, re_f))[order],
            supply_voltage_v=np.full(ts.size, float(drive.supply_voltage_v[0])),
            off_times_s=t_off, off_freq_hz=f_at)
        k = np.searchsorted(out.period_starts_s, t_off, side='right') - 1
        high = out.high_until_s.copy()
        ok = k >= 0
        high[k[ok]] = np.minimum(high[k[ok]], t_off[ok])
        return replace(out, high_until_s=high)


@dataclass(frozen=True)
class Measurement:
    """One measured trace, whatever file it came from.

    Attributes
    ----------
    source : str
        File (or bag directory) the trace was read from.
    t_s : numpy.ndarray, shape (n,)
        Sample times [s], strictly increasing, starting at or after 0.
    voltage_v : numpy.ndarray, shape (n,)
        Voltage at the coil terminals [V]. Between samples it is held (zero-order hold).
    current_a : numpy.ndarray, shape (n,)
        Measured coil current [A]; ``nan`` marks a missing value.
    supply_pressure_pa : float or None
        Supply pressure, gauge [Pa]; ``None`` when the file does not say.
    output_pressure_pa : float
        Output port pressure, gauge [Pa] (0 when the file does not say).
    experiment : str
        ``step`` or ``pwm`` (``unknown`` when the file does not say).
    position_m : numpy.ndarray or None, shape (n,)
        Measured spool position [m] when available.
    metadata : dict
        All metadata as read (unknown keys kept).
    notes : tuple of str
        Everything the reader noticed and kept: missing values, gaps, rate mismatches.
    n_missing_values : int
        Number of samples whose current is missing (``nan``).
    n_gaps : int
        Number of steps of the time axis longer than 1.5 nominal periods.
    drive : DriveInput or None
        Main PWM commands through the drive electronics; ``None`` drives the bare coil
        with ``voltage_v``.
    sampling : str
        ``instant`` or ``interval_mean``: how the current was sampled (interval means over
        ``(t[k-1], t[k]]``, over ``[0, t[0]]`` for the first sample).
    exclude_before_s : float
        Samples before this time do not enter the errors [s].
    held_out_from_s : float or None
        Start of the hold-out of a split record [s].
    coil_voltage_mean_v : numpy.ndarray or None, shape (n,)
        Measured mean voltage across the coil terminals over the same interval as the
        current [V] (``nan`` where missing), when the record carries it.
    voltage_hold : str
        How ``voltage_v`` drives the bare coil: ``sample`` (value ``k`` held from ``t[k]``
        to ``t[k+1]``) or ``interval_mean`` (value ``k`` is the mean over ``(t[k-1],
        t[k]]``, over ``[0, t[0]]`` for the first, and is held over that interval).
    current_lsb_a : float or None
        Quantisation step of the current [A] (:func:`with_current_lsb`): ``None`` not yet
        examined, 0 no grid (or not one worth counting).
    """

    source: str
    t_s: np.ndarray
    voltage_v: np.ndarray
    current_a: np.ndarray
    supply_pressure_pa: float | None
    output_pressure_pa: float = 0.0
    experiment: str = 'unknown'
    position_m: np.ndarray | None = None
    metadata: dict[str, str] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    n_missing_values: int = 0
    n_gaps: int = 0
    drive: DriveInput | None = None
    sampling: str = 'instant'
    exclude_before_s: float = 0.0
    held_out_from_s: float | None = None
    coil_voltage_mean_v: np.ndarray | None = None
    voltage_hold: str = 'sample'
    current_lsb_a: float | None = None

    @property
    def through_electronics(self) -> bool:
        """True when the model runs the drive electronics from the main PWM commands."""
        return self.drive is not None

    @property
    def name(self) -> str:
        """Short name of the source (file name without directories)."""
        return Path(self.source).name

    @property
    def n_samples(self) -> int:
        """Number of samples (rows), missing values included."""
        return int(self.t_s.size)

    @property
    def duration_s(self) -> float:
        """Time span of the trace [s]."""
        return float(self.t_s[-1] - self.t_s[0]) if self.t_s.size else 0.0

    @property
    def sample_rate_hz(self) -> float:
        """Actual sample rate [Hz] from the median sampling period."""
        if self.t_s.size < 2:
            return float('nan')
        return 1.0 / float(np.median(np.diff(self.t_s)))

    @property
    def valid(self) -> np.ndarray:
        """Samples that enter the errors, shape (n,): a measured current, and not in the
        discarded start (``exclude_before_s``: a record that starts in motion, or the fit
        part of a record whose hold-out this is)."""
        return np.isfinite(self.current_a) & (self.t_s >= self.exclude_before_s)

    @property
    def in_service(self) -> bool:
        """True for a record of a valve in service (long: held out, windowed): through the
        drive electronics, or around them through its mean coil voltage. A bench step
        driven by its mean voltage is a bench record."""
        return self.drive is not None or (self.voltage_hold == 'interval_mean'
                                          and self.experiment == 'operation')

    @property
    def has_coil_voltage_mean(self) -> bool:
        """True when every sample carries a finite measured mean coil voltage."""
        v = self.coil_voltage_mean_v
        return v is not None and v.shape == self.t_s.shape and bool(np.all(np.isfinite(v)))

    def samples(self, keep: np.ndarray) -> 'Measurement':
        """The record cut to the samples where ``keep`` (bool, shape (n,)) is true: every
        per-sample array and the missing-value count."""
        v_mean = self.coil_voltage_mean_v
        return replace(self, t_s=self.t_s[keep], voltage_v=self.voltage_v[keep],
                       current_a=self.current_a[keep],
                       position_m=None if self.position_m is None else self.position_m[keep],
                       coil_voltage_mean_v=None if v_mean is None else v_mean[keep],
                       n_missing_values=int(np.count_nonzero(
                           ~np.isfinite(self.current_a[keep]))))

    def with_current(self, current_a: np.ndarray, source: str | None = None) -> 'Measurement':
        """Return a copy whose current is replaced (used for residuals and for tests).

        Parameters
        ----------
        current_a : numpy.ndarray, shape (n,)
            New current trace [A].
        source : str, optional
            New source name; by default the old one.
        """
        cur = np.asarray(current_a, dtype=float)
        if cur.shape != self.t_s.shape:
            raise ValueError(f'current has shape {cur.shape}, expected {self.t_s.shape}')
        return replace(self, source=self.source if source is None else source,
                       current_a=cur, metadata=dict(self.metadata),
                       n_missing_values=int(np.count_nonzero(~np.isfinite(cur))))

    def summary(self) -> str:
        """One line a person can read in a progress log."""
        p = ('unknown' if self.supply_pressure_pa is None
             else f'{self.supply_pressure_pa / 1e5:.2f} bar')
        v = self.voltage_v
        return (f'{self.name}: {self.n_samples} samples, {self.duration_s * 1e3:.1f} ms at '
                f'{self.sample_rate_hz / 1e3:.3g} kHz, voltage {v.min():.3g}..{v.max():.3g} V, '
                f'supply {p}, {self.n_missing_values} missing values, {self.n_gaps} gaps')


def check_time_axis(path: str, t: np.ndarray, linenos: Sequence[int] | None) -> None:
    """Refuse a time axis that does not increase strictly from at or after zero.

    The measured-data format's rule (:func:`valve_model_pkg.dataformat.check_time_axis`),
    raised as :class:`~valve_model_pkg.errors.MeasurementFormatError`.

    Parameters
    ----------
    path : str
        Named in the error.
    t : numpy.ndarray, shape (n,)
        Sample times [s].
    linenos : sequence of int or None
        File line of each sample; ``None`` for bag messages (the message is named).
    """
    try:
        dataformat.check_time_axis(path, t, linenos)
    except dataformat.DataFormatError as err:
        raise MeasurementFormatError(err.path, err.line, err.reason) from err


def check_excitation(source: str, voltage: np.ndarray, line_numbers: np.ndarray | None
                     ) -> None:
    """Refuse a record whose coil voltage is zero throughout: it excites nothing to fit.

    Checked before any simulation, so such a record is refused at once instead of being
    fitted for minutes.
    """
    if np.any(np.abs(voltage) > MIN_EXCITATION_V):
        return
    where = (f' (lines {int(line_numbers[0])}..{int(line_numbers[-1])})'
             if line_numbers is not None and len(line_numbers) else '')
    raise MeasurementFormatError(
        source, None, f'has no excitation: the coil voltage is 0 V in all {voltage.size} '
        f'samples{where}; nothing to identify')


@dataclass(frozen=True)
class CurrentResponse:
    """How far a record's current follows its coil voltage (:func:`current_response`).

    Attributes
    ----------
    n_on : int
        Samples with the voltage on (at least half the largest |voltage|).
    voltage_on_v : float
        Median |voltage| while on [V].
    rest_a : float
        Rest level of the current [A]: the median before the first sample on (0 when
        fewer than :data:`MIN_SAMPLES` samples precede it).
    response_a : float
        The 90th percentile of |current - rest| over the samples on and the sample after
        each (the current of a sample-and-hold record answers one sample later) [A].
    noise_a : float
        Standard deviation of the current's noise [A]: robust (MAD) over the rest samples,
        or over the sample-to-sample differences / sqrt(2) without enough rest samples.
    lsb_a : float
        Quantisation step of the current [A] (0: none known).
    expected_a : float or None
        The steady current V/R of the coil resistance given [A]; None without one.
    threshold_a : float
        The response a current that follows its voltage exceeds [A]: the largest of
        :data:`RESPONSE_NOISE_SIGMAS` noise deviations, two LSB and
        :data:`RESPONSE_SHARE_OF_V_OVER_R` of ``expected_a``.
    """

    n_on: int
    voltage_on_v: float
    rest_a: float
    response_a: float
    noise_a: float
    lsb_a: float
    expected_a: float | None
    threshold_a: float

    @property
    def responds(self) -> bool:
        """True when the current departs from rest by more than the threshold."""
        return self.response_a > self.threshold_a


def _robust_sigma(x: np.ndarray) -> float:
    """Standard deviation of Gaussian noise from the median absolute deviation."""
    return 1.4826 * float(np.median(np.abs(x - np.median(x)))) if x.size else 0.0


def current_response(m: Measurement, resistance_ohm: float | None = None
                     ) -> CurrentResponse | None:
    """How far the current of ``m`` follows its coil voltage; None without voltage on.

    Physics: a coil under a voltage V carries a current that rises towards V/R (eq. 5,
    tau = L/R of milliseconds), so while the voltage is on the current leaves its rest
    level by a good part of V/R within a few time constants. A record whose current stays
    within its noise (or its quantisation step) of rest while on, or below
    :data:`RESPONSE_SHARE_OF_V_OVER_R` of V/R, does not measure the coil's current.

    Parameters
    ----------
    m : Measurement
        The record (``voltage_v`` [V], ``current_a`` [A], ``current_lsb_a``).
    resistance_ohm : float or None
        Coil resistance R of the parameter set [ohm], for the scale V/R; None: the noise
        and the quantisation alone set the threshold.
    """
    v = np.abs(np.asarray(m.voltage_v, dtype=float))
    i = np.asarray(m.current_a, dtype=float)
    finite_v = np.isfinite(v)
    if not np.any(finite_v) or float(np.max(v[finite_v])) <= MIN_EXCITATION_V:
        return None
    on = finite_v & (v >= _ON_SHARE * float(np.max(v[finite_v])))
    answer = on.copy()
    answer[1:] |= on[:-1]
    answer &= np.isfinite(i)
    first_on = int(np.argmax(on))
    rest = i[:first_on][np.isfinite(i[:first_on])]
    rest_a = float(np.median(rest)) if rest.size >= MIN_SAMPLES else 0.0
    if m.drive is not None:
        # through drive electronics the current moves with the chopper and the valve before
        # the first command too: its spread there is no noise figure
        noise_a = 0.0
    elif rest.size >= MIN_SAMPLES:
        noise_a = _robust_sigma(rest)
    else:
        noise_a = _robust_sigma(np.diff(i[np.isfinite(i)])) / math.sqrt(2.0)
    response_a = (float(np.percentile(np.abs(i[answer] - rest_a), _RESPONSE_PERCENTILE))
                  if np.any(answer) else 0.0)
    voltage_on_v = float(np.median(v[on]))
    lsb_a = float(m.current_lsb_a or 0.0)
    expected_a = (voltage_on_v / resistance_ohm
                  if resistance_ohm is not None and resistance_ohm > 0.0 else None)
    threshold_a = max(RESPONSE_NOISE_SIGMAS * noise_a, 2.0 * lsb_a,
                      RESPONSE_SHARE_OF_V_OVER_R * expected_a if expected_a else 0.0)
    return CurrentResponse(n_on=int(np.count_nonzero(on)), voltage_on_v=voltage_on_v,
                           rest_a=rest_a, response_a=response_a, noise_a=noise_a,
                           lsb_a=lsb_a, expected_a=expected_a, threshold_a=threshold_a)


def check_current_response(m: Measurement, resistance_ohm: float | None = None) -> None:
    """Refuse a record whose current does not respond to its coil voltage.

    The criterion is :func:`current_response` (the physics and the threshold are stated
    there): while the voltage is on, the current must leave its rest level by more than
    the largest of :data:`RESPONSE_NOISE_SIGMAS` noise deviations, two quantisation steps
    and :data:`RESPONSE_SHARE_OF_V_OVER_R` of V/R. A real but small current (a low
    voltage, a large coil resistance) passes as long as it stands out of its noise.
    Checked before any simulation: such a record (a broken current channel, a step that
    did not happen) has nothing to identify.

    Raises
    ------
    MeasurementFormatError
        One line naming the record, the voltage, the response and the threshold.
    """
    r = current_response(m, resistance_ohm)
    if r is None or r.responds:
        return
    scale = (f', {100 * RESPONSE_SHARE_OF_V_OVER_R:g} % of V/R = {r.expected_a:.3g} A'
             if r.expected_a else '')
    raise MeasurementFormatError(
        m.source, None, f'the current does not respond to the coil voltage: while '
        f'{r.voltage_on_v:.3g} V is on ({r.n_on} samples) the current leaves its rest level '
        f'{1e3 * r.rest_a:.3g} mA by {1e3 * r.response_a:.3g} mA ({_RESPONSE_PERCENTILE:g}th '
        f'percentile), not more than {1e3 * r.threshold_a:.3g} mA (the largest of '
        f'{RESPONSE_NOISE_SIGMAS:g} x its noise {1e3 * r.noise_a:.3g} mA, 2 LSB '
        f'{2e3 * r.lsb_a:.3g} mA{scale}); nothing to identify (a broken current channel or '
        'an excitation that did not happen)')


def median_pressure(values: np.ndarray | None, name: str, default: float | None,
                    notes: list[str]) -> float | None:
    """The one pressure [Pa] the model takes per record: the median of ``values`` [Pa].

    ``default`` when there is no finite value; a note is appended to ``notes`` when the
    values vary by more than 1 % (of at least 1 kPa).
    """
    if values is None:
        return default
    ok = values[np.isfinite(values)]
    if ok.size == 0:
        return default
    med = float(np.median(ok))
    if np.ptp(ok) > 0.01 * max(abs(med), 1e3):
        notes.append(f'{name} varies {ok.min():.0f}..{ok.max():.0f} Pa; the model takes one '
                     f'pressure per run: the median {med:.0f} Pa is used')
    return med


def mean_voltage_column(values: np.ndarray | None, where: str, notes: list[str]
                        ) -> np.ndarray | None:
    """A record's measured interval-mean coil voltage [V] as the Measurement keeps it.

    ``None`` when the record has none (no column or field, or ``nan`` throughout: a source
    that does not measure it); missing values are kept as ``nan``, counted in ``notes``
    (the identification then runs the drive electronics for that record, see
    :mod:`.mean_voltage`).

    Parameters
    ----------
    values : numpy.ndarray or None, shape (n,)
        The column [V].
    where : str
        Where it was read (column, field or topic), for the notes.
    notes : list of str
        Appended to.
    """
    if values is None:
        return None
    v = np.asarray(values, dtype=float).copy()
    missing = int(np.count_nonzero(~np.isfinite(v)))
    if missing == v.size:
        notes.append(f'{where} carries no value (nan throughout): the record has no '
                     'measured mean coil voltage')
        return None
    if missing:
        notes.append(f'{where}: {missing} of {v.size} samples without a value (kept as '
                     'nan): the mean coil voltage does not drive this record')
    return v


def hold_out(m: Measurement, fraction: float = 0.3, fit_window_s: float | None = None
             ) -> tuple[Measurement, Measurement]:
    """Split one record into a fit part and a hold-out for validation.

    The last ``fraction`` of the record (by time) is held out. The fit part is the record
    up to there (at most ``fit_window_s`` after its discarded start); the validation part
    is the whole record with everything before the hold-out left out of its errors (the
    model is simulated from t = 0 through the fit part, so the hold-out starts from the
    state the fitted model reaches).
    """
    t = m.t_s
    split = float(t[0] + (1.0 - fraction) * (t[-1] - t[0]))
    end = split if fit_window_s is None else min(split, m.exclude_before_s + fit_window_s)
    keep = t <= end
    fit = replace(m.samples(keep),
                  notes=m.notes + (f'fit part: {t[0]:.3g}..{end:.3g} s of the record '
                                   f'(the last {100 * fraction:.0f} % from {split:.3g} s is '
                                   'held out for validation)',),
                  held_out_from_s=split)
    val = replace(m, exclude_before_s=max(m.exclude_before_s, split), held_out_from_s=split,
                  notes=m.notes + (f'validation part: the hold-out {split:.3g}..'
                                   f'{t[-1]:.3g} s (the last {100 * fraction:.0f} %), never '
                                   'seen by the fit',))
    return fit, val


def window(m: Measurement, span_s: float) -> Measurement:
    """``m`` cut to ``span_s`` after the start of its compared part (a long record)."""
    end = max(m.exclude_before_s, float(m.t_s[0])) + span_s
    if m.t_s[-1] <= end:
        return m
    keep = m.t_s <= end
    return replace(m.samples(keep),
                   notes=m.notes + (f'compared up to {end:.3g} s of {m.t_s[-1]:.3g} s (the '
                                    f'first {span_s:g} s of its compared part)',))


def _header_lsb(m: Measurement) -> float | None:
    """The header's ``current_lsb_a`` [A]: None when absent, 0 when the importer found no
    grid (``current_resolution``); refused when not a positive number."""
    text = m.metadata.get('current_lsb_a')
    if text is None:
        return 0.0 if 'current_resolution' in m.metadata else None
    try:
        lsb = float(text)
    except ValueError:
        lsb = math.nan
    if not (math.isfinite(lsb) and lsb > 0.0):
        raise MeasurementFormatError(m.source, None, f'metadata current_lsb_a: {text!r} is '
                                     'not a positive number of amperes')
    return lsb


def _inferred_lsb(m: Measurement) -> tuple[float, str]:
    """The current's grid step [A] found in the samples (0: none), and a note."""
    from ..instruments.capture import infer_lsb
    cur = m.current_a[np.isfinite(m.current_a)]
    levels = int(np.unique(cur).size)
    if levels < MIN_LSB_LEVELS:
        return 0.0, (f'the current takes only {levels} distinct values: too few to infer '
                     'a quantisation step; none assumed (state current_lsb_a in the header)')
    res = infer_lsb(cur)
    if res is None or np.ptp(cur) > _MAX_LSB_STEPS * res.lsb:
        return 0.0, ''
    return res.lsb, (f'the current lies on a grid of {1e3 * res.lsb:.4g} mA ({res.levels_used} '
                     'levels used): taken as its quantisation step')


def with_current_lsb(m: Measurement) -> Measurement:
    """``m`` with :attr:`~Measurement.current_lsb_a` set, and a note saying where from.

    The header's ``current_lsb_a`` [A] when there is one (``valve_import`` writes it from
    the raw samples, before any decimation, and ``current_resolution`` when it found no
    grid); else the step of the grid the current's values lie on
    (:func:`valve_model_pkg.instruments.infer_lsb`), when at least :data:`MIN_LSB_LEVELS`
    distinct values show one. A record already examined is returned as it is.

    Raises
    ------
    MeasurementFormatError
        A header ``current_lsb_a`` that is not a positive number (names the file).
    """
    if m.current_lsb_a is not None:
        return m
    lsb = _header_lsb(m)
    if lsb is None:
        lsb, note = _inferred_lsb(m)
    elif lsb > 0.0:
        note = (f'the current is quantised in steps of {1e3 * lsb:.4g} mA (header '
                'current_lsb_a)')
    else:
        note = ''
    notes = m.notes + ((note + '; the noise model counts LSB^2/12',) if lsb > 0.0 else
                       (note,) if note else ())
    return replace(m, current_lsb_a=lsb, notes=notes)


def refused_bag(source: str, err: BaseException) -> MeasurementFormatError:
    """A bag's refusal by :mod:`valve_model_pkg.recording` as the identification's error:
    one line naming ``source``."""
    reason = ' '.join(str(err).split())
    if reason.startswith(source):
        reason = reason[len(source):].lstrip(':').lstrip()
    return MeasurementFormatError(source, None, reason)
