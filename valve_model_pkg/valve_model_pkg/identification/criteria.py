"""The selection's criteria: when an extra term pays for its parameters.

One home for the rule every augmentation is judged by, a listed effect's refit
(:mod:`.diagnosis`) and the open-ended sparse term (:mod:`.unlisted`) alike:

* the Bayesian information criterion of a Laplace (absolute-error) likelihood,
  ``dBIC = sum_f 2 n_f ln(MAE_aug,f / MAE_base,f) + p ln(n)``, below
  :data:`DBIC_THRESHOLD` (strong evidence), on the fit data and on the hold-out data;
* with ``n_f`` the file's samples divided by the correlation time of the residual of the
  model under test (:func:`effective_counts`), and each MAE raised by a resolution floor
  (:func:`resolution_floors`: a share of the current range, at least half the LSB of a
  quantised current);
* on the hold-out data a fall of the mean absolute error by at least
  :data:`MIN_VALIDATION_GAIN`.
"""
from __future__ import annotations

import math

import numpy as np

from ..model.parameters import ValveParameters
from .problem import FitData
from .sensitivity import noise_std

__all__ = ['DBIC_THRESHOLD', 'MIN_VALIDATION_GAIN', 'MIN_EXPLAINED', 'MAE_FLOOR_FRACTION',
           'delta_bic', 'effective_counts', 'resolution_floors', 'noise_per_file',
           'structured_energy', 'structured_energy_of']

#: Strong evidence on the BIC scale (Kass & Raftery: > 10).
DBIC_THRESHOLD = -10.0
#: Smallest relative fall of the validation mean absolute error worth an effect.
MIN_VALIDATION_GAIN = 0.02
#: Share of the validation residual's structured energy an effect must explain.
MIN_EXPLAINED = 0.5
#: Resolution floor, relative to each file's current range (0.1 %: 1.1 mA on a 24 V step
#: of the Table 2 valve): below it two models are equal and a residual is not structure.
#: It is the accuracy of the current sensing such records come from (shunt + ADC, 0.1-1 %
#: of range) and of the order of the baseline search's own tolerance. It adds to the MAEs
#: the BIC compares and floors the noise estimate, so that on a noise-free record a
#: sub-milliampere extrapolation miss of the baseline (0.03 % of range) is not read as
#: thousands of times the noise. Noisy records (noise >= 1 mA) hardly move.
MAE_FLOOR_FRACTION = 1e-3


def delta_bic(base_mae: dict[str, float], aug_mae: dict[str, float], counts: dict[str, float],
              p: int, floors: dict[str, float] | None = None) -> float:
    """Laplace-likelihood BIC difference, augmented minus baseline.

    Parameters
    ----------
    base_mae, aug_mae : dict
        Mean absolute error of each file [A] of the baseline and the augmented model.
    counts : dict
        Independent samples of each file (:func:`effective_counts`).
    p : int
        Extra parameters of the augmented model.
    floors : dict, optional
        Resolution floor of each file [A], added to both MAEs.
    """
    total = sum(counts.values())
    d = 0.0
    for name, n in counts.items():
        f = floors.get(name, 0.0) if floors else 0.0
        b, a = base_mae[name] + f, aug_mae[name] + f
        if b > 0 and a > 0:
            d += 2.0 * n * math.log(a / b)
    return d + p * math.log(max(total, 2.0))


def effective_counts(data: FitData, params: ValveParameters) -> dict[str, float]:
    """Samples of each file divided by the correlation time ``(1 + rho) / (1 - rho)`` of
    the residual of ``params`` (rho: lag-1 autocorrelation, capped at 0.999): a smooth,
    correlated residual (a noise-free record, a structured misfit) has few independent
    samples, and the BIC must not count every one of them as evidence."""
    out = {}
    for m, v, r in zip(data.measurements, data.valid, data.residuals(params)):
        x = r[np.isfinite(r)]
        rho = 0.0
        if x.size > 4:
            x = x - x.mean()
            den = float(x @ x)
            rho = float(x[:-1] @ x[1:]) / den if den > 0 else 0.999
        rho = min(max(rho, 0.0), 0.999)
        out[m.name] = int(v.sum()) * (1.0 - rho) / (1.0 + rho)
    return out


def _range_floors(data: FitData) -> dict[str, float]:
    """:data:`MAE_FLOOR_FRACTION` of each file's current range [A]."""
    out = {}
    for m, v in zip(data.measurements, data.valid):
        c = m.current_a[v]
        out[m.name] = MAE_FLOOR_FRACTION * float(np.ptp(c)) if c.size else 0.0
    return out


def resolution_floors(data: FitData) -> dict[str, float]:
    """Resolution floor of each file [A]: :data:`MAE_FLOOR_FRACTION` of its current range,
    at least half the quantisation step of a quantised current (``current_lsb_a``): the
    instrument rounds every value by up to half a step, so two models closer than that are
    equal to it, and a residual within it is its rounding (smooth, hence not white, where
    the noise does not dither the steps), not structure."""
    floors = _range_floors(data)
    for m in data.measurements:
        if m.current_lsb_a:
            floors[m.name] = max(floors[m.name], 0.5 * m.current_lsb_a)
    return floors


def noise_per_file(data: FitData, params: ValveParameters) -> list[float]:
    """Noise of each file, estimated once from the baseline residual [A], the quantisation
    of its current counted (:func:`.sensitivity.noise_estimate`), at least
    :data:`MAE_FLOOR_FRACTION` of its current range."""
    floors = _range_floors(data)
    return [max(noise_std(r, m.current_lsb_a), floors[m.name])
            for m, r in zip(data.measurements, data.residuals(params))]


def structured_energy_of(residuals: list[np.ndarray], noise: list[float]) -> float:
    """Mean over files of the residual energy beyond the noise [A^2]."""
    vals = []
    for r, s in zip(residuals, noise):
        ok = np.isfinite(r)
        vals.append(max(float(np.mean(r[ok] ** 2)) - s ** 2, 0.0))
    return float(np.mean(vals))


def structured_energy(data: FitData, params: ValveParameters, noise: list[float]) -> float:
    """Mean over files of the residual energy of ``params`` beyond the noise [A^2].

    The same noise estimate (the baseline's) is used for every model compared, so the
    difference between two models is not blurred by two noise estimates.
    """
    return structured_energy_of(data.residuals(params), noise)
