"""How a bench ``pwm`` record through the drive electronics is compared with the model.

A ``pwm`` record without a coil voltage that resolves the chopper runs the model's drive
electronics from its main PWM column (:func:`.pwm_grid.drive_from_main_pwm`). Two things
decide how its current can be compared:

* **Where it starts.** The model starts at rest. A record cut out of running operation
  (the second half of a longer record) starts with current in the coil: the first periods
  are left out of the errors (:func:`.pwm_grid.discard_for`), as for an operational record.
* **Whether the chopper's phase can be followed.** The chopper switches at tens of kHz.
  Sample by sample, the model follows it only when every chopper period holds at least
  :data:`SAMPLES_PER_CHOPPER_PERIOD` samples; otherwise the samples alias its ripple,
  whose phase the record does not give, and the ripple stands in the residual as structure
  no parameter can remove. Such a record is compared in interval means over
  :data:`INTERVAL_MEAN_S`: block means of the measured samples against the model's means
  over the same intervals, in which the chopper's ripple averages out and the coil's
  voltage balance (eq. 1) holds whatever the chopper did inside.

:func:`pwm_comparison` applies both; :func:`comparison_statement` says in the report which
comparison was used.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..model import ElectronicsConfig
from .measurement import Measurement
from .pwm_grid import discard_for

__all__ = ['INTERVAL_MEAN_S', 'SAMPLES_PER_CHOPPER_PERIOD', 'COMPARISON_KEY',
           'ComparisonStatement', 'pwm_comparison', 'comparison_statement',
           'starts_in_motion', 'interval_means']

#: Samples per period of the model's chopper needed to follow its phase sample by sample.
SAMPLES_PER_CHOPPER_PERIOD = 4
#: Length of the intervals a record whose chopper cannot be followed is compared over [s]:
#: several ripple periods of a current regulator (20 kHz PWM, or a 1-3 kHz hysteresis
#: limit cycle), short against the peak phase (3-5 ms).
INTERVAL_MEAN_S = 0.5e-3
#: Mean |current| of the first samples above this share of the record's largest |current|:
#: the record starts with current in the coil (in motion), not at rest.
_MOVING_SHARE = 0.05
_FIRST_SAMPLES = 3
#: Metadata key naming the comparison the record gets (value: ``samples`` or
#: ``interval_means``).
COMPARISON_KEY = 'current_comparison'


def _applies(m: Measurement) -> bool:
    """A bench ``pwm`` record through the drive electronics with instantaneous samples."""
    return m.drive is not None and m.experiment == 'pwm' and m.sampling == 'instant'


def starts_in_motion(m: Measurement) -> bool:
    """True when the first samples of ``m`` carry current: the record was cut out of
    running operation (the model, starting at rest, cannot match its first periods)."""
    i = m.current_a[np.isfinite(m.current_a)]
    if i.size < _FIRST_SAMPLES:
        return False
    peak = float(np.max(np.abs(i)))
    return peak > 0.0 and float(np.mean(np.abs(i[:_FIRST_SAMPLES]))) > _MOVING_SHARE * peak


def chopper_followed(m: Measurement, electronics: ElectronicsConfig | None = None) -> bool:
    """True when the record samples every period of the model's chopper at least
    :data:`SAMPLES_PER_CHOPPER_PERIOD` times (the PI or open-loop chopper at
    ``chopper_frequency_hz``, the hysteresis comparator at ``comparator_frequency_hz``)."""
    cfg = electronics or ElectronicsConfig()
    clock_hz = (cfg.comparator_frequency_hz if cfg.hold == 'hysteresis'
                else cfg.chopper_frequency_hz)
    return m.sample_rate_hz >= SAMPLES_PER_CHOPPER_PERIOD * clock_hz * (1.0 - 1e-9)


def interval_means(m: Measurement, interval_s: float = INTERVAL_MEAN_S) -> Measurement:
    """``m`` as interval means: block means of ``N = round(interval_s * rate)`` samples.

    Sample ``k`` at ``t[k]`` stands for ``[t[k] - dt/2, t[k] + dt/2)``, so a block's mean is
    the mean current over the interval ending half a sample after its last sample; that
    end is its time, and the model is compared as its mean over the same interval
    (``sampling = 'interval_mean'``, over ``(t[j-1], t[j]]``). The first block only opens
    the first interval and is left out of the errors. A block with fewer than half of its
    samples measured is missing. The current's quantisation grid does not survive the
    means (``current_lsb_a = 0``).
    """
    dt = 1.0 / m.sample_rate_hz
    n = max(2, int(round(interval_s / dt)))
    nb = m.t_s.size // n
    t_end = m.t_s[n - 1:nb * n:n] + 0.5 * dt
    blocks = m.current_a[:nb * n].reshape(nb, n)
    good = np.isfinite(blocks)
    count = good.sum(axis=1)
    with np.errstate(invalid='ignore'):
        mean = np.where(count >= 0.5 * n, np.where(good, blocks, 0.0).sum(axis=1)
                        / np.maximum(count, 1), np.nan)
    left = m.t_s.size - nb * n
    note = (f'compared in interval means of {n} samples ({1e3 * n * dt:.3g} ms): the '
            f'{m.sample_rate_hz / 1e3:.3g} kHz samples do not follow the chopper\'s phase '
            f'(fewer than {SAMPLES_PER_CHOPPER_PERIOD} samples per chopper period), its '
            'ripple averages out in the means')
    if left:
        note += f'; the last {left} samples (an incomplete interval) are left out'
    meta = dict(m.metadata)
    meta[COMPARISON_KEY] = 'interval_means'
    meta['comparison_interval_s'] = f'{n * dt:.6g}'
    return replace(m, t_s=t_end, voltage_v=m.drive.main_pwm_level(t_end), current_a=mean,
                   position_m=None, sampling='interval_mean',
                   exclude_before_s=max(m.exclude_before_s, float(t_end[min(1, nb - 1)])),
                   n_missing_values=int(np.count_nonzero(~np.isfinite(mean))),
                   current_lsb_a=0.0, metadata=meta, notes=m.notes + (note,))


def pwm_comparison(m: Measurement, electronics: ElectronicsConfig | None = None
                   ) -> Measurement:
    """``m`` prepared for comparison (see the module notes); other records unchanged.

    Parameters
    ----------
    m : Measurement
        A record as read.
    electronics : ElectronicsConfig, optional
        The drive electronics the model runs (default: the paper's driver), for its
        chopper clock.
    """
    if not _applies(m):
        return m
    if starts_in_motion(m):
        cut, notes = discard_for(m.drive, float(m.t_s[0]), at_rest=False)
        m = replace(m, exclude_before_s=max(m.exclude_before_s, cut),
                    notes=m.notes + tuple(n.replace('starts in motion', 'starts with current '
                                                    'in the coil (in motion)')
                                          for n in notes))
    if chopper_followed(m, electronics):
        meta = dict(m.metadata)
        meta[COMPARISON_KEY] = 'samples'
        return replace(m, metadata=meta, notes=m.notes + (
            f'compared sample by sample: the {m.sample_rate_hz / 1e3:.3g} kHz samples '
            f'follow the chopper ({SAMPLES_PER_CHOPPER_PERIOD} or more per chopper period)',))
    return interval_means(m)


@dataclass(frozen=True)
class ComparisonStatement:
    """How the pwm records' current was compared (:func:`comparison_statement`).

    Attributes
    ----------
    kind : str
        ``samples``, ``interval_means`` or ``mixed``.
    interval_s : float or None
        Length of the intervals of the interval-mean comparison [s].
    text : str
        One sentence for the report.
    """

    kind: str
    interval_s: float | None
    text: str

    def to_json(self) -> dict[str, object]:
        return {'kind': self.kind, 'interval_s': self.interval_s, 'text': self.text}


def comparison_statement(files: list[Measurement]) -> ComparisonStatement | None:
    """Which comparison the pwm records through the electronics got; None without any."""
    kinds = [m.metadata.get(COMPARISON_KEY) for m in files]
    kinds = [k for k in kinds if k]
    if not kinds:
        return None
    intervals = [float(m.metadata['comparison_interval_s']) for m in files
                 if m.metadata.get(COMPARISON_KEY) == 'interval_means']
    interval = max(intervals) if intervals else None
    if all(k == 'samples' for k in kinds):
        return ComparisonStatement('samples', None, 'the current is compared sample by '
                                   'sample: the records follow the chopper\'s phase')
    text = (f'the current is compared in interval means of {1e3 * interval:.3g} ms: the '
            'samples cannot follow the chopper\'s phase, whose ripple averages out in the '
            'means (errors and NRMSE are of the interval means)')
    if all(k == 'interval_means' for k in kinds):
        return ComparisonStatement('interval_means', interval, text)
    return ComparisonStatement('mixed', interval, text.replace(
        'the current is compared', 'the records whose samples cannot follow the chopper '
        'are compared').replace('the samples cannot', 'they cannot')
        + '; the others sample by sample')
