"""Residual analysis: where the model misses, what the miss looks like, whether it is noise.

The residual is measured minus simulated current. It is studied per file:

* **Phases of the stroke**, from the *simulated* spool position and the measured voltage:
  ``idle`` (before the first voltage edge), ``before_motion`` (voltage on, spool still
  closed), ``during_motion`` (the opening stroke), ``after_stroke`` (the first 3 ms on the
  open stop), ``steady_state`` (the rest of the on-time), ``release`` (after the voltage
  is switched off, closing stroke included). For each: RMS, mean, share of the residual's
  energy, RMS relative to the noise.
* **Whiteness**: Ljung-Box Q over 20 lags and the lag-1 autocorrelation. White noise gives
  ``p > 0.01``; a missing effect leaves a correlated residual.
* **Shape**: the dominant frequency, the share of energy below 1 kHz, the largest
  excursion and when it happens.
* **Structure**: the residual's energy beyond the noise, ``mean(r^2) - sigma^2``, with the
  noise ``sigma`` from first differences, the quantisation of a coarse instrument counted
  (:func:`sensitivity.noise_estimate`: ``sigma^2 = noise^2 + LSB^2 / 12``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from .measurement import Measurement
from .sensitivity import noise_estimate

__all__ = ['DRIVE_PHASES', 'PHASES', 'ResidualReport', 'FileResidual', 'analyse_residuals',
           'drive_phase_masks', 'phase_masks', 'ljung_box']

PHASES = ('idle', 'before_motion', 'during_motion', 'after_stroke', 'steady_state',
          'release')
_AFTER_STROKE_S = 3e-3
_LB_LAGS = 20
#: Phases of the drive cycle, from the record alone (:func:`drive_phase_masks`).
DRIVE_PHASES = ('peak_phase', 'hold', 'voltage_on', 'release', 'at_rest')
#: After the voltage is off, the release lasts until the measured current first falls
#: below this share of the record's largest current; then the coil is at rest.
_REST_SHARE = 0.02


def _on_at(m: Measurement) -> np.ndarray:
    """Whether the main PWM (records through the electronics) or the coil voltage is on in
    each sample's interval (at its middle for interval means), shape (n,)."""
    t = m.t_s
    if m.drive is None:
        v = m.voltage_v
        return np.abs(v) > 0.05 * max(float(np.max(np.abs(v))), 1e-9)
    if m.sampling == 'interval_mean':
        t = t - 0.5 * np.diff(t, prepend=0.0)
    d = m.drive
    k = np.searchsorted(d.period_starts_s, t, side='right') - 1
    kk = np.clip(k, 0, None)
    return (k >= 0) & (t < d.high_until_s[kk])


def drive_phase_masks(m: Measurement) -> dict[str, np.ndarray]:
    """Boolean masks of the phases of the drive cycle of one record, from the record alone.

    Through the drive electronics each high phase of the main PWM is split at the largest
    measured current in it: ``peak_phase`` up to that sample (boost and stroke), ``hold``
    after it (the chopper holds a lower current), whatever form the electronics have. A
    bare coil's voltage on is ``voltage_on``. After the voltage goes off, ``release`` lasts
    until the measured current first falls below 2 % of the record's largest, then
    ``at_rest`` until the voltage is on again (also before it first is).
    """
    on = _on_at(m)
    cur = np.where(np.isfinite(m.current_a), m.current_a, 0.0)
    rest_a = _REST_SHARE * max(float(np.max(np.abs(cur))), 1e-12)
    phase = np.full(m.t_s.size, 'at_rest', dtype=object)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], on.astype(np.int8), [0]))))
    starts, stops = edges[::2], edges[1::2]
    for j, (a, b) in enumerate(zip(starts, stops)):   # each run of the voltage on
        if m.drive is None:
            phase[a:b] = 'voltage_on'
        else:
            top = a + int(np.argmax(cur[a:b]))
            phase[a:top + 1] = 'peak_phase'
            phase[top + 1:b] = 'hold'
        nxt = int(starts[j + 1]) if j + 1 < starts.size else m.t_s.size
        quiet = np.flatnonzero(np.abs(cur[b:nxt]) < rest_a)
        phase[b:b + int(quiet[0]) if quiet.size else nxt] = 'release'
    return {p: phase == p for p in DRIVE_PHASES}


def phase_masks(m: Measurement, position_m: np.ndarray, stroke_m: float
                ) -> dict[str, np.ndarray]:
    """Boolean masks of the stroke phases of one file (see module notes).

    Parameters
    ----------
    m : Measurement
        The file (its voltage decides on/off).
    position_m : numpy.ndarray, shape (n,)
        Simulated spool position at the file's samples [m].
    stroke_m : float
        Open end stop x_max [m].
    """
    t, v = m.t_s, m.voltage_v
    vmax = max(float(np.max(np.abs(v))), 1e-9)
    on = np.abs(v) > 0.05 * vmax
    n = t.size
    phase = np.full(n, 'idle', dtype=object)
    ever_on = np.cumsum(on) > 0
    closed = position_m <= 1e-3 * stroke_m
    at_open = position_m >= (1.0 - 1e-3) * stroke_m
    # Walk through the samples once; the last open-stop arrival time decides after_stroke.
    arrived_at = -math.inf
    moved_since_on = False
    for k in range(n):
        if not ever_on[k]:
            continue
        if on[k]:
            if k > 0 and not on[k - 1]:
                moved_since_on = False
                arrived_at = -math.inf
            if at_open[k]:
                if not math.isfinite(arrived_at):
                    arrived_at = t[k]
                phase[k] = 'after_stroke' if t[k] - arrived_at <= _AFTER_STROKE_S \
                    else 'steady_state'
            elif closed[k] and not moved_since_on:
                phase[k] = 'before_motion'
            else:
                moved_since_on = True
                phase[k] = 'during_motion'
        else:
            phase[k] = 'release'
    return {p: phase == p for p in PHASES}


def ljung_box(r: np.ndarray, lags: int = _LB_LAGS) -> tuple[float, float, float]:
    """Ljung-Box Q, its p-value and the lag-1 autocorrelation of ``r`` (nan removed)."""
    x = r[np.isfinite(r)]
    x = x - x.mean()
    n = x.size
    if n <= lags + 2:
        return math.nan, math.nan, math.nan
    den = float(x @ x)
    if den == 0.0:
        return 0.0, 1.0, 0.0
    acf = np.array([float(x[:-k] @ x[k:]) / den for k in range(1, lags + 1)])
    q = float(n * (n + 2) * np.sum(acf ** 2 / (n - np.arange(1, lags + 1))))
    return q, float(stats.chi2.sf(q, lags)), float(acf[0])


@dataclass
class FileResidual:
    """Residual findings of one file."""

    name: str
    noise_std_a: float
    rms_a: float
    structured_rms_a: float
    ljung_box_q: float
    ljung_box_p: float
    lag1_autocorrelation: float
    white: bool
    dominant_frequency_hz: float
    low_frequency_share: float
    peak_a: float
    peak_time_s: float
    phases: dict[str, dict[str, float]]
    current_lsb_a: float = 0.0
    quantisation_share: float = 0.0

    def to_json(self) -> dict[str, object]:
        return dict(self.__dict__)


@dataclass
class ResidualReport:
    """Residual findings of a set of files, with a summary in words."""

    files: list[FileResidual]
    phase_share: dict[str, float]
    dominant_phase: str
    white: bool
    structured_rms_a: float
    noise_std_a: float
    summary: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, object]:
        return {
            'white': self.white,
            'noise_std_a': self.noise_std_a,
            'structured_rms_a': self.structured_rms_a,
            'phase_share_of_energy': self.phase_share,
            'dominant_phase': self.dominant_phase,
            'summary': self.summary,
            'files': [f.to_json() for f in self.files],
        }


def _shape(t: np.ndarray, r: np.ndarray) -> tuple[float, float]:
    """Dominant frequency [Hz] and share of energy below 1 kHz of a residual."""
    ok = np.isfinite(r)
    if ok.sum() < 16:
        return math.nan, math.nan
    dt = float(np.median(np.diff(t)))
    grid = np.arange(t[0], t[-1], dt)
    x = np.interp(grid, t[ok], r[ok])
    x = (x - x.mean()) * np.hanning(x.size)
    spec = np.abs(np.fft.rfft(x)) ** 2
    freq = np.fft.rfftfreq(x.size, dt)
    if spec[1:].sum() == 0:
        return math.nan, math.nan
    k = 1 + int(np.argmax(spec[1:]))
    return float(freq[k]), float(spec[freq < 1e3].sum() / spec.sum())


def analyse_file(m: Measurement, residual: np.ndarray, position_m: np.ndarray,
                 stroke_m: float) -> FileResidual:
    """Residual analysis of one file (see module notes)."""
    ok = np.isfinite(residual)
    r = residual
    noise = noise_estimate(r, m.current_lsb_a)
    sigma = noise.std_a
    ms = float(np.mean(r[ok] ** 2))
    struct = math.sqrt(max(ms - sigma ** 2, 0.0))
    q, p, rho1 = ljung_box(r)
    f_dom, low = _shape(m.t_s, r)
    masks = phase_masks(m, position_m, stroke_m)
    total = float(np.sum(r[ok] ** 2)) or 1.0
    phases = {}
    for name, mask in masks.items():
        sel = mask & ok
        if not sel.any():
            continue
        rr = r[sel]
        phases[name] = {
            'samples': int(sel.sum()),
            'duration_s': float(sel.sum() * np.median(np.diff(m.t_s))),
            'rms_a': float(np.sqrt(np.mean(rr ** 2))),
            'mean_a': float(np.mean(rr)),
            'energy_share': float(np.sum(rr ** 2) / total),
            'rms_over_noise': float(np.sqrt(np.mean(rr ** 2)) / sigma) if sigma > 0 else None,
        }
    k_peak = int(np.nanargmax(np.abs(np.where(ok, r, 0.0))))
    return FileResidual(
        name=m.name, noise_std_a=sigma, rms_a=math.sqrt(ms), structured_rms_a=struct,
        ljung_box_q=q, ljung_box_p=p, lag1_autocorrelation=rho1,
        white=bool(p > 0.01) if math.isfinite(p) else False,
        dominant_frequency_hz=f_dom, low_frequency_share=low,
        peak_a=float(r[k_peak]), peak_time_s=float(m.t_s[k_peak]), phases=phases,
        current_lsb_a=noise.lsb_a, quantisation_share=noise.quantisation_share)


def analyse_residuals(measurements: list[Measurement], residuals: list[np.ndarray],
                      positions: list[np.ndarray], stroke_m: float) -> ResidualReport:
    """Residual analysis of a set of files.

    Parameters
    ----------
    measurements : list of Measurement
    residuals : list of numpy.ndarray
        Measured minus simulated current of each file [A].
    positions : list of numpy.ndarray
        Simulated spool position of each file [m].
    stroke_m : float
        Open end stop [m].

    Returns
    -------
    ResidualReport
    """
    files = [analyse_file(m, r, x, stroke_m)
             for m, r, x in zip(measurements, residuals, positions)]
    # Energy per phase, each file weighted by its duration (as the cost does).
    share = {p: 0.0 for p in PHASES}
    for f, m in zip(files, measurements):
        w = 1.0 / len(files)
        for p, d in f.phases.items():
            share[p] += w * d['energy_share']
    share = {p: v for p, v in share.items() if v > 0}
    # Which phase holds the most residual *beyond the noise* per unit time.
    excess = {}
    for p in share:
        vals = [f.phases[p]['rms_over_noise'] for f in files
                if p in f.phases and f.phases[p]['rms_over_noise'] is not None]
        excess[p] = max(vals) if vals else 0.0
    dominant = max(excess, key=excess.get) if excess else 'none'
    sigma = float(np.nanmedian([f.noise_std_a for f in files]))
    struct = float(np.sqrt(np.mean([f.structured_rms_a ** 2 for f in files])))
    white = all(f.white for f in files)
    summary = []
    for f in files:
        summary.append(
            f'{f.name}: RMS {f.rms_a * 1e3:.2f} mA against noise {f.noise_std_a * 1e3:.2f} mA '
            + (f'({100 * f.quantisation_share:.0f} % of its variance the quantisation of '
               f'{f.current_lsb_a * 1e3:.3g} mA steps) ' if f.current_lsb_a > 0.0 else '')
            + f'(structured part {f.structured_rms_a * 1e3:.2f} mA); Ljung-Box p = '
            f'{f.ljung_box_p:.3g} -> {"white" if f.white else "not white"}; largest '
            f'{f.peak_a * 1e3:+.1f} mA at {f.peak_time_s * 1e3:.2f} ms; dominant frequency '
            f'{f.dominant_frequency_hz:.0f} Hz')
    ranked = sorted(excess.items(), key=lambda kv: -kv[1])
    summary.append('RMS over noise by phase (worst file): ' + ', '.join(
        f'{p} {v:.2f}' for p, v in ranked))
    return ResidualReport(files=files, phase_share=share, dominant_phase=dominant,
                          white=white, structured_rms_a=struct, noise_std_a=sigma,
                          summary=summary)
