"""Features of one static curve x_avg/x_max (duty): dead band, saturation, effective range.

A curve is the periodic-steady-state average spool position, as a fraction of the stroke
x_max, sampled on an ascending grid of duties from 0 to 1. The definitions (Section 5 of
the paper, made exact for a sampled curve):

* **closed**: a grid point whose average opening is at most ``stop_tolerance`` (fraction of
  x_max). With plastic end stops a spool that never leaves the closed stop averages exactly
  0, so the tolerance only absorbs rounding.
* **dead band**: the duties ``[0, dead_band_duty]``, where ``dead_band_duty`` is the highest
  grid duty such that it and every lower grid duty are closed. ``opening_duty`` is the next
  grid duty, the first one at which the valve leaves its closed stop. The true edge lies
  between the two (a map generated with edge refinement also records it to within the
  refinement tolerance).
* **saturation**: the duties ``[saturation_duty, 1]``, the lowest grid duty from which on
  every grid point averages at least ``1 - stop_tolerance``: the spool never leaves the open
  stop.
* **effective range**: ``(dead_band_duty, saturation_duty)``, the duties that modulate the
  opening; its width is ``saturation_duty - dead_band_duty``.
* ``first_saturation_duty``: the lowest grid duty that reaches the open stop for good in
  its period (``>= 1 - stop_tolerance``). It equals ``saturation_duty`` unless the curve
  leaves the open stop again at some higher duties (an *island*, seen in the model at
  200 Hz and 5 bar); the flow inversion, which takes the lowest duty for an opening, never
  uses duties above it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ['DEFAULT_STOP_TOLERANCE', 'CurveFeatures', 'curve_features', 'monotone_envelope']

#: Average opening (fraction of x_max) up to which a grid point counts as on a stop.
DEFAULT_STOP_TOLERANCE = 1e-6


@dataclass(frozen=True)
class CurveFeatures:
    """Dead band, saturation and effective range of one curve (duties as fractions [1]).

    Attributes
    ----------
    dead_band_duty : float
        Highest grid duty at which (and below which) the valve stays on its closed stop.
        1.0 if the valve never opens.
    opening_duty : float
        First grid duty above the dead band (the valve opens); nan if it never opens.
    saturation_duty : float
        Lowest grid duty from which on the spool stays on its open stop; nan if the curve
        never reaches the open stop.
    effective_width : float
        ``saturation_duty - dead_band_duty``; nan without saturation.
    first_saturation_duty : float
        Lowest grid duty at the open stop (nan if none).
    max_decrease : float
        Largest fall of the curve between neighbouring duties (0 for a monotone curve),
        fraction of x_max.
    """

    dead_band_duty: float
    opening_duty: float
    saturation_duty: float
    effective_width: float
    max_decrease: float
    first_saturation_duty: float = math.nan

    @property
    def opens(self) -> bool:
        """True if some duty of the grid lifts the spool off its closed stop."""
        return not math.isnan(self.opening_duty)

    def as_dict(self) -> dict[str, float | None]:
        """Plain dict with nan as None (for JSON)."""
        return {k: (None if isinstance(v, float) and math.isnan(v) else float(v))
                for k, v in self.__dict__.items()}


def curve_features(duty: np.ndarray, position_fraction: np.ndarray,
                   stop_tolerance: float = DEFAULT_STOP_TOLERANCE) -> CurveFeatures:
    """Find the dead band, saturation and effective width of one curve.

    Parameters
    ----------
    duty : numpy.ndarray, shape (n,)
        Ascending duties [1].
    position_fraction : numpy.ndarray, shape (n,)
        x_avg / x_max at each duty [1].
    stop_tolerance : float
        Fraction of x_max within which a point counts as on a stop.

    Returns
    -------
    CurveFeatures
    """
    d = np.asarray(duty, dtype=float)
    f = np.asarray(position_fraction, dtype=float)
    if d.shape != f.shape or d.ndim != 1 or d.size < 2:
        raise ValueError(f'duty and position_fraction must be equal 1-D arrays of at least 2 '
                         f'points, got shapes {d.shape} and {f.shape}')
    closed = f <= stop_tolerance
    open_ = f >= 1.0 - stop_tolerance
    n = d.size
    # length of the leading run of closed points
    k = int(np.argmin(closed)) if not closed.all() else n
    if k == 0:
        dead_band, opening = 0.0, float(d[0])  # opens at the lowest duty already
    elif k == n:
        dead_band, opening = float(d[-1]), math.nan
    else:
        dead_band, opening = float(d[k - 1]), float(d[k])
    # start of the trailing run of open points
    m = n - int(np.argmin(open_[::-1])) if not open_.all() else 0
    saturation = float(d[m]) if m < n else math.nan
    first_sat = float(d[int(np.argmax(open_))]) if open_.any() else math.nan
    width = saturation - dead_band if not math.isnan(saturation) else math.nan
    drops = f[:-1] - f[1:]
    return CurveFeatures(dead_band_duty=dead_band, opening_duty=opening,
                         saturation_duty=saturation, effective_width=width,
                         max_decrease=float(max(0.0, drops.max())),
                         first_saturation_duty=first_sat)


def monotone_envelope(position_fraction: np.ndarray) -> np.ndarray:
    """Running maximum along the last axis: the non-decreasing curve the inversion uses."""
    return np.maximum.accumulate(np.asarray(position_fraction, dtype=float), axis=-1)
