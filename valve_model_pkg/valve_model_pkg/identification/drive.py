"""The drive electronics' constants that show in the current, identified within bounds.

Operation and ``pwm`` records run the model's drive electronics
(:class:`~valve_model_pkg.model.ElectronicsConfig`: boost with end-of-stroke dip detection,
20 kHz chopper holding a set current, negative release pulse from a capacitor). A real
driver's constants differ from the nominal ones, and three of them leave their mark in
the coil current:

* ``holding_current_a``, the hold set point: the mean current of the hold phase;
* ``dip_threshold_a``, the end-of-boost detection: how long the boost lasts after the
  stroke, so the current peak's width;
* ``capacitor_voltage_v`` and ``capacitor_discharge_time_s``, the release pulse: how fast
  the current falls after the main PWM's falling edge.

They are identified with the valve's parameters held (the model's batch entry point takes
one electronics setting per batch, so each electronics candidate is its own run; runs go
to a thread pool), alternating with the valve fit: hold current first from the data
directly (the PI controller regulates the mean current of the hold phase to it), then a
bounded direct search over all four. Each is reported with its bounds, an interval from
the local sensitivity (widened for a structured residual as the valve parameters' are),
whether it is pinned down and whether it sits at a bound (a sign of misfit).
"""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..model import ElectronicsConfig
from ..model.parameters import ValveParameters
from .problem import FitData, ParameterBound
from .search import SearchSettings, direct_search

__all__ = ['DRIVE_BOUNDS', 'DriveReport', 'estimate_hold_current', 'fit_drive']

#: Search ranges of the electronics constants (SI). Wide: a driver's hold current is set
#: between a few hundred mA and an ampere or two, its release pulse by a capacitor.
DRIVE_BOUNDS: dict[str, tuple[float, float]] = {
    'holding_current_a': (0.1, 2.0),
    'dip_threshold_a': (0.002, 0.1),
    'capacitor_voltage_v': (1.0, 60.0),
    'capacitor_discharge_time_s': (0.05e-3, 5e-3),
}
#: A value within this share of its log range from a bound counts as at the bound.
AT_BOUND_FRACTION = 0.01
_PINNED_CI95_PCT = 5.0


@dataclass
class DriveReport:
    """Identified electronics constants and how well the data pin them down."""

    electronics: ElectronicsConfig
    values: dict[str, float]
    bounds: dict[str, tuple[float, float]]
    ci95_pct: dict[str, float | None]
    pinned: list[str]
    at_bound: list[str]
    carried: dict[str, bool]
    notes: list[str] = field(default_factory=list)
    cost: float = math.nan

    def to_json(self) -> dict[str, object]:
        return {'values': self.values, 'bounds': self.bounds, 'ci95_pct': self.ci95_pct,
                'pinned_down': self.pinned, 'at_search_bound': self.at_bound,
                'carried_by_the_data': self.carried, 'notes': self.notes,
                'nominal': {k: getattr(ElectronicsConfig(), k) for k in DRIVE_BOUNDS}}


@dataclass
class DriveFit:
    """Electronics constants and their cost [A] (:func:`_search_drive`)."""

    electronics: ElectronicsConfig
    cost: float


def _hold_samples(data: FitData) -> list[tuple[np.ndarray, np.ndarray]]:
    """(current, valid) of the hold phase of every period: the last 40 % of high phases
    longer than 8 ms (the boost and stroke are over by then)."""
    out = []
    for m, valid in zip(data.measurements, data.valid):
        d = m.drive
        if d is None:
            continue
        sel = np.zeros(m.t_s.size, dtype=bool)
        for s, h in zip(d.period_starts_s, d.high_until_s):
            if h - s >= 8e-3:
                sel |= (m.t_s >= h - 0.4 * (h - s)) & (m.t_s < h - 1e-3)
        out.append((m.current_a, sel & valid))
    return out


def estimate_hold_current(data: FitData) -> tuple[float | None, int]:
    """Median measured current over the hold phases [A] and the number of samples used
    (``None`` when the records have no hold phase)."""
    vals = [c[s] for c, s in _hold_samples(data)]
    vals = np.concatenate(vals) if vals else np.zeros(0)
    if vals.size < 5:
        return None, int(vals.size)
    return float(np.median(vals)), int(vals.size)


def _carried(data: FitData) -> dict[str, bool]:
    """Which constants the records can show at all."""
    hold = sum(int(s.sum()) for _, s in _hold_samples(data)) >= 5
    falls = False
    for m in data.measurements:
        d = m.drive
        if d is not None and np.any((d.high_until_s > d.period_starts_s)
                                    & (d.high_until_s < m.t_s[-1] - 2e-3)):
            falls = True
    return {'holding_current_a': hold, 'dip_threshold_a': hold,
            'capacitor_voltage_v': falls, 'capacitor_discharge_time_s': falls}


def _costs(data: FitData, raw: np.ndarray, configs: list[ElectronicsConfig]) -> np.ndarray:
    """Cost of one valve parameter vector under each electronics setting."""
    def one(cfg: ElectronicsConfig) -> float:
        view = data.serial()
        view.electronics = cfg
        return float(view.cost(raw[None, :])[0])
    workers = max(1, min(len(configs), data.workers))
    if workers == 1:
        return np.array([one(c) for c in configs])
    with ThreadPoolExecutor(max_workers=workers) as pool:
        return np.array(list(pool.map(one, configs)))


def _search_drive(data: FitData, params: ValveParameters, base: ElectronicsConfig,
                  bounds: list[ParameterBound], effort: int) -> DriveFit:
    """Bounded direct search of the electronics constants of ``bounds`` from ``base``, the
    valve held at ``params``."""
    raw = params.to_vector()

    def configs(u: np.ndarray) -> list[ElectronicsConfig]:
        out = []
        for row in np.atleast_2d(u):
            out.append(base.replace(**{b.name: float(b.from_unit(np.array(x)))
                                       for b, x in zip(bounds, row)}))
        return out

    best = DriveFit(base, float(_costs(data, raw, [base])[0]))
    if bounds:
        u0 = np.array([b.to_unit(getattr(base, b.name)) for b in bounds])
        settings = SearchSettings(global_samples=0, starts=1, max_iterations=effort,
                                  initial_step=0.15, restarts=1, stall_iterations=25,
                                  tolerance=1e-4)
        res = direct_search(lambda u: _costs(data, raw, configs(u)), u0, settings,
                            label='drive electronics')
        if res.cost < best.cost:
            best = DriveFit(configs(res.u)[0], res.cost)
    return best


def _intervals(data: FitData, params: ValveParameters, cfg: ElectronicsConfig,
               names: list[str], noise_a: float | None, inflation: float
               ) -> dict[str, float | None]:
    """95 % half-widths [%] of the constants ``names`` from d(current)/d(ln value), one
    run per +-1 % step (None where the current does not move)."""
    from .sensitivity import noise_std
    raw = params.to_vector()
    values = {n: float(getattr(cfg, n)) for n in names}
    views = []
    for n in names:
        for sgn in (1.0, -1.0):
            v = data.serial()
            v.electronics = cfg.replace(**{n: values[n] * math.exp(sgn * 0.01)})
            views.append(v)
    workers = max(1, min(len(views), data.workers))
    with ThreadPoolExecutor(max_workers=workers) as pool:
        sims = list(pool.map(lambda v: v.simulate(raw[None, :]), views))
    cols = []
    for j in range(len(names)):
        plus, minus = sims[2 * j], sims[2 * j + 1]
        cols.append(np.concatenate([(p[0][0] - q[0][0])[valid] / 0.02
                                    for p, q, valid in zip(plus, minus, data.valid)]))
    jac = np.column_stack(cols)
    view = data.serial()
    view.electronics = cfg
    res_now = view.residuals(params)
    sigma = noise_a if noise_a else float(np.nanmedian(
        [noise_std(r, m.current_lsb_a) for m, r in zip(view.measurements, res_now)]))
    if not math.isfinite(sigma) or sigma <= 0:
        sigma = 1e-3
    fim = jac.T @ jac / sigma ** 2
    try:
        cov = np.linalg.pinv(fim)
        std = 100.0 * np.sqrt(np.maximum(np.diag(cov), 0.0)) * inflation
    except np.linalg.LinAlgError:
        std = np.full(len(names), np.inf)
    return {n: (None if fim[j, j] <= 0.0 else float(1.96 * std[j]))
            for j, n in enumerate(names)}


def fit_drive(data: FitData, params: ValveParameters, *, effort: int = 120,
              noise_a: float | None = None, inflation: float = 1.0) -> DriveReport:
    """Identify the electronics constants with the valve parameters held at ``params``.

    Parameters
    ----------
    data : FitData
        Fit data with at least one record through the electronics.
    params : ValveParameters
        The valve parameters (held).
    effort : int
        Nelder-Mead iterations of the search.
    noise_a : float, optional
        Noise of the current [A] for the intervals (default: from the residual).
    inflation : float
        Factor on the standard errors for a correlated/structured residual (the valve
        parameters' factor, :func:`.sensitivity.analyse_sensitivity`).
    """
    carried = _carried(data)
    names = [n for n in DRIVE_BOUNDS if carried[n]]
    notes = []
    base = data.electronics
    hold, n_hold = estimate_hold_current(data)
    if hold is not None:
        lo, hi = DRIVE_BOUNDS['holding_current_a']
        base = base.replace(holding_current_a=min(max(hold, lo), hi))
        notes.append(f'hold current first read from the data: median {hold:.4g} A over '
                     f'{n_hold} hold-phase samples')
    missing = [n for n in DRIVE_BOUNDS if not carried[n]]
    if missing:
        notes.append('not carried by these records (held at their nominal values): '
                     + ', '.join(missing))
    bounds = [ParameterBound(n, *DRIVE_BOUNDS[n]) for n in names]
    best = _search_drive(data, params, base, bounds, effort)
    values = {n: float(getattr(best.electronics, n)) for n in DRIVE_BOUNDS}
    ci: dict[str, float | None] = {n: None for n in DRIVE_BOUNDS}
    at_bound = []
    for b in bounds:
        u = b.to_unit(values[b.name])
        if u <= AT_BOUND_FRACTION or u >= 1.0 - AT_BOUND_FRACTION:
            at_bound.append(b.name)
    if names:
        ci.update(_intervals(data, params, best.electronics, names, noise_a, inflation))
    pinned = [n for n in names
              if ci[n] is not None and ci[n] < _PINNED_CI95_PCT and n not in at_bound]
    if at_bound:
        notes.append('at a search bound (a sign of misfit, never reported pinned down): '
                     + ', '.join(at_bound))
    return DriveReport(electronics=best.electronics, values=values,
                       bounds={n: DRIVE_BOUNDS[n] for n in DRIVE_BOUNDS}, ci95_pct=ci,
                       pinned=pinned, at_bound=at_bound, carried=carried, notes=notes,
                       cost=best.cost)
