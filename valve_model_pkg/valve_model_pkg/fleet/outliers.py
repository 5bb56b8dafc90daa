"""Outlier valves: parameters far from the rest of the fleet (robust z-score).

For each parameter, over the valves identified (status ok) with a finite value::

    z = 0.6745 (x - median) / MAD,      MAD = median |x - median|

(Iglewicz and Hoaglin's modified z-score; 0.6745 makes it comparable to a standard score for
normal data). A valve is an outlier when ``|z| > 3.5`` for at least one parameter the data
pin down for that valve. The median and the MAD ignore the few valves that are far off, so
one bad valve cannot hide itself by widening the spread, as it would with mean and standard
deviation. When more than half the valves share one value the MAD is 0; then the mean
absolute deviation from the median stands in (``z = (x - median) / (1.2533 MeanAD)``), and
a parameter all valves share exactly gives z = 0. Fewer than :data:`MIN_VALVES` values say
nothing about a fleet: the verdict is ``cannot tell``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

__all__ = ['THRESHOLD', 'MIN_VALVES', 'OutlierVerdict', 'robust_z', 'flag_outliers']

#: |z| above which a parameter is "far from the fleet" (Iglewicz and Hoaglin's 3.5)
THRESHOLD = 3.5
#: fewest valves with a value for a parameter before anything is flagged
MIN_VALVES = 5
_MAD_SCALE = 0.6745          # Phi^-1(0.75): MAD of a standard normal
_MEANAD_SCALE = 1.253314     # sqrt(pi/2): mean absolute deviation of a standard normal


@dataclass
class OutlierVerdict:
    """One valve's verdict.

    Attributes
    ----------
    flag : str
        ``yes``, ``no`` or ``cannot tell`` (too few valves).
    reason : str
        The parameters beyond the threshold with their z and the fleet median, or why
        nothing can be said; empty for ``no``.
    z : dict
        Robust z-score per parameter (NaN where the valve has no value or the fleet is too
        small).
    """

    flag: str
    reason: str = ''
    z: dict[str, float] = field(default_factory=dict)


def robust_z(values: Sequence[float] | np.ndarray) -> np.ndarray:
    """Modified z-scores of ``values`` (NaN entries stay NaN and are left out of the stats).

    Parameters
    ----------
    values : sequence of float
        One parameter over the fleet, any unit.

    Returns
    -------
    numpy.ndarray
        Dimensionless z per value.
    """
    x = np.asarray(values, dtype=float)
    ok = np.isfinite(x)
    z = np.full(x.shape, np.nan)
    if not ok.any():
        return z
    med = float(np.median(x[ok]))
    dev = np.abs(x[ok] - med)
    mad = float(np.median(dev))
    if mad > 0.0:
        z[ok] = _MAD_SCALE * (x[ok] - med) / mad
    else:
        mean_ad = float(np.mean(dev))
        z[ok] = (x[ok] - med) / (_MEANAD_SCALE * mean_ad) if mean_ad > 0.0 else 0.0
    return z


def flag_outliers(values: Mapping[str, Sequence[float]], *,
                  usable: Mapping[str, Sequence[bool]] | None = None,
                  threshold: float = THRESHOLD, min_valves: int = MIN_VALVES
                  ) -> list[OutlierVerdict]:
    """Flag the valves whose parameters are far from the fleet.

    Parameters
    ----------
    values : mapping str -> sequence of float
        Parameter name -> its value per valve (all sequences the same length, one entry a
        valve; NaN for a valve without a value, e.g. a failed identification).
    usable : mapping str -> sequence of bool, optional
        Whether a valve's value may flag it (False for a parameter its data do not pin
        down: its value is still counted in the fleet's median). Default: all usable.
    threshold : float
        ``|z|`` above which a parameter is far off.
    min_valves : int
        Fewest finite values of a parameter for its z to count.

    Returns
    -------
    list of OutlierVerdict
        One per valve, in order.
    """
    names = list(values)
    n = len(next(iter(values.values()))) if names else 0
    for name in names:
        if len(values[name]) != n:
            raise ValueError(f'parameter {name}: {len(values[name])} values for {n} valves')
    zs = {name: robust_z(values[name]) for name in names}
    counts = {name: int(np.isfinite(np.asarray(values[name], dtype=float)).sum())
              for name in names}
    verdicts = []
    for k in range(n):
        z_k = {name: float(zs[name][k]) for name in names}
        judged = [name for name in names
                  if counts[name] >= min_valves and math.isfinite(z_k[name])]
        if not judged:
            short = min(counts.values()) if counts else 0
            verdicts.append(OutlierVerdict(
                'cannot tell', f'{short} valves with parameters, fewer than {min_valves}',
                {name: math.nan for name in names}))
            continue
        far = [name for name in judged if abs(z_k[name]) > threshold
               and (usable is None or bool(usable[name][k]))]
        if not far:
            verdicts.append(OutlierVerdict('no', '', z_k))
            continue
        med = {name: float(np.nanmedian(np.asarray(values[name], dtype=float)))
               for name in far}
        reason = '; '.join(f'{name} = {float(values[name][k]):.4g} (z {z_k[name]:+.1f}, '
                           f'fleet median {med[name]:.4g})' for name in far)
        verdicts.append(OutlierVerdict('yes', reason, z_k))
    return verdicts
