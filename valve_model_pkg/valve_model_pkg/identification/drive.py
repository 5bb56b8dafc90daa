"""The drive electronics' constants that show in the current, identified within bounds.

Operation and ``pwm`` records run the model's drive electronics
(:class:`~valve_model_pkg.model.ElectronicsConfig`): a form for each phase (how the peak
phase ends, how the current is held, how the valve is released) and its constants. The
form is given (``--electronics``) or chosen by the data (:mod:`.electronics_family`); the
constants of that form that leave their mark in a 1 kHz interval-mean current are
identified here (:data:`FORM_CONSTANTS`):

* the peak end: the dip (``dip_threshold_a``), dip and rise (and ``rise_threshold_a``), a
  current threshold (``peak_current_a``) or a timer (``max_boost_time_s``): the width of
  the current peak;
* the hold: the set point of a PI chopper or hysteresis band (``holding_current_a``, and
  ``hysteresis_band_a``), or the fixed duty of an open-loop PWM hold (``hold_duty``): the
  hold phase's mean current;
* the release: a capacitor (``capacitor_voltage_v``, ``capacitor_discharge_time_s``) or a
  Zener clamp (``zener_voltage_v``): how fast the current falls after the main PWM's
  falling edge (a freewheel diode has no constant that shows).

They are identified with the valve's parameters held (the model's batch entry point takes
one electronics setting per batch, so each electronics candidate is its own run; runs go
to a thread pool), alternating with the valve fit: the hold first from the data directly
(a closed-loop hold regulates the mean current of the hold phase to its set point; an
open-loop hold's duty is R I_hold / V_supply), then a bounded direct search over all of
them. Each is reported with its bounds, an interval from the local sensitivity (widened
for a structured residual as the valve parameters' are), whether it is pinned down and
whether it sits at a bound (a sign of misfit). ``fixed`` (a user's description file taken
as it is) skips the search and reports the intervals only.
"""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..model import ElectronicsConfig
from ..model.parameters import ValveParameters
from .problem import FitData, ParameterBound, remembered
from .search import SearchSettings, direct_search

__all__ = ['DRIVE_BOUNDS', 'FORM_CONSTANTS', 'DriveReport', 'estimate_hold_current',
           'fit_drive', 'form_constants', 'hold_start', 'search_constants',
           'DriveFit', 'COMPARATOR_CLOCKS_HZ', 'form_choices']

#: Search ranges of the electronics constants (SI). Wide: a driver's hold current is set
#: between a few hundred mA and an ampere or two, its release pulse by a capacitor or a
#: Zener diode of a few to a hundred volts.
DRIVE_BOUNDS: dict[str, tuple[float, float]] = {
    'holding_current_a': (0.1, 2.0),
    'hysteresis_band_a': (0.005, 0.3),
    'hold_duty': (0.02, 1.0),
    'dip_threshold_a': (0.002, 0.1),
    'rise_threshold_a': (0.0005, 0.1),
    'peak_current_a': (0.1, 3.0),
    'max_boost_time_s': (0.5e-3, 20e-3),
    'capacitor_voltage_v': (1.0, 60.0),
    'capacitor_discharge_time_s': (0.05e-3, 5e-3),
    'zener_voltage_v': (3.0, 100.0),
}
#: The constants of each form (by part and form name) that show in the current.
FORM_CONSTANTS: dict[tuple[str, str], tuple[str, ...]] = {
    ('peak_end', 'dip'): ('dip_threshold_a',),
    ('peak_end', 'dip_rise'): ('dip_threshold_a', 'rise_threshold_a'),
    ('peak_end', 'threshold'): ('peak_current_a',),
    ('peak_end', 'timer'): ('max_boost_time_s',),
    ('hold', 'pi'): ('holding_current_a',),
    ('hold', 'hysteresis'): ('holding_current_a', 'hysteresis_band_a'),
    ('hold', 'pwm'): ('hold_duty',),
    ('release', 'capacitor'): ('capacitor_voltage_v', 'capacitor_discharge_time_s'),
    ('release', 'capacitor_peak'): ('capacitor_voltage_v', 'capacitor_discharge_time_s'),
    ('release', 'zener'): ('zener_voltage_v',),
    ('release', 'diode'): (),
}
#: Clocks a hysteresis hold's comparator is tried at [Hz]. The clock shows in the
#: interval-mean current through the phase of the ripple at each falling edge (the current
#: the release starts from), but not smoothly: the cost jumps between neighbouring clocks,
#: so the clock is chosen among these (and the start value), not searched.
COMPARATOR_CLOCKS_HZ = (10e3, 20e3, 25e3, 40e3, 50e3, 100e3)
#: Bands of the grid of :func:`hysteresis_grid` (about 11 % apart) [A].
HYSTERESIS_BANDS_A = tuple(float(b) for b in np.geomspace(0.01, 0.05, 16))
#: Offsets of the grid's set points from the hold read off the data [A].
HYSTERESIS_HOLD_OFFSETS_A = tuple(float(x) for x in np.arange(-8e-3, 8.1e-3, 2e-3))
#: Clock x band pairs of the grid whose every set point is tried (:func:`hysteresis_grid`):
#: a quarter of them, which held the whole grid's best in all but one of 26 grids of two
#: records (that one 2.4 % above it, before the local search that follows).
GRID_FINE_PAIRS = 32
#: Which phase of the record shows each constant: the hold phase (peak end and hold) or
#: the fall after the main PWM's falling edge (release).
_SHOWN_BY = {'peak_end': 'hold', 'hold': 'hold', 'release': 'falls'}


def form_constants(cfg: ElectronicsConfig, part: str | None = None) -> list[str]:
    """The constants of ``cfg``'s form (of one ``part``: peak_end, hold or release; default
    all three) that show in the current (:data:`FORM_CONSTANTS`)."""
    parts = (part,) if part else ('peak_end', 'hold', 'release')
    out: list[str] = []
    for p in parts:
        if p == 'release' and not cfg.negative_voltage:
            continue
        out += [n for n in FORM_CONSTANTS[(p, getattr(cfg, p))] if n not in out]
    return out


def form_choices(cfg: ElectronicsConfig) -> list[str]:
    """The settings of ``cfg``'s form chosen from a few values rather than searched (the
    hysteresis comparator's clock, :data:`COMPARATOR_CLOCKS_HZ`)."""
    return ['comparator_frequency_hz'] if cfg.current_control and cfg.hold == 'hysteresis' \
        else []


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
                'form': {p: getattr(self.electronics, p)
                         for p in ('peak_end', 'hold', 'hold_decay', 'release')},
                'electronics': self.electronics.to_dict(),
                'nominal': {k: getattr(ElectronicsConfig(), k) for k in self.values}}


@dataclass(frozen=True)
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


def _carried(data: FitData, cfg: ElectronicsConfig) -> dict[str, bool]:
    """Which constants of ``cfg``'s form the records can show at all."""
    hold = sum(int(s.sum()) for _, s in _hold_samples(data)) >= 5
    falls = False
    for m in data.measurements:
        d = m.drive
        if d is not None and np.any((d.high_until_s > d.period_starts_s)
                                    & (d.high_until_s < m.t_s[-1] - 2e-3)):
            falls = True
    shown = {'hold': hold, 'falls': falls}
    return {n: shown[_SHOWN_BY[p]] for p in _SHOWN_BY for n in form_constants(cfg, p)}


def hold_start(data: FitData, params: ValveParameters, cfg: ElectronicsConfig
               ) -> tuple[ElectronicsConfig, str | None]:
    """``cfg`` with its hold constant read from the data (set point of a closed-loop hold:
    the median hold-phase current; duty of an open-loop hold: R I_hold / V_supply) and a
    note in words (None when the records have no hold phase)."""
    hold, n_hold = estimate_hold_current(data)
    if hold is None:
        return cfg, None
    if cfg.hold == 'pwm':
        supply = [float(np.median(m.drive.supply_voltage_v)) for m in data.measurements
                  if m.drive is not None]
        lo, hi = DRIVE_BOUNDS['hold_duty']
        duty = params.coil_resistance_ohm * hold / max(float(np.median(supply)), 1e-3)
        return (cfg.replace(hold_duty=min(max(duty, lo), hi)),
                f'hold duty first read from the data: R I_hold / V_supply = {duty:.4g} '
                f'(median hold current {hold:.4g} A over {n_hold} hold-phase samples)')
    lo, hi = DRIVE_BOUNDS['holding_current_a']
    return (cfg.replace(holding_current_a=min(max(hold, lo), hi)),
            f'hold current first read from the data: median {hold:.4g} A over {n_hold} '
            'hold-phase samples')


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


def search_constants(data: FitData, params: ValveParameters, base: ElectronicsConfig,
                     effort: int, grid: bool = False, read_hold: bool = True) -> DriveFit:
    """The constants of ``base``'s form that the records carry, from the hold read off the
    data (``read_hold``; else ``base``'s hold) and ``base``'s other values, searched with
    the valve held at ``params`` (``effort`` Nelder-Mead iterations; no intervals); with
    ``grid`` a hysteresis hold's clock, band and set point first on a grid
    (:func:`hysteresis_grid`)."""
    if read_hold:
        base, _ = hold_start(data, params, base)
    carried = _carried(data, base)
    bounds = [ParameterBound(n, *DRIVE_BOUNDS[n]) for n in carried if carried[n]]
    return _search_clocked(data, params, base, bounds, effort, grid)


#: Searches kept per data set (:attr:`~.problem.FitData.drive_cache`).
DRIVE_CACHE = 256


def _search_clocked(data: FitData, params: ValveParameters, base: ElectronicsConfig,
                    bounds: list[ParameterBound], effort: int, grid: bool) -> DriveFit:
    """The bounded search of :func:`_search_drive`; for a hysteresis hold with ``grid``
    first its comparator's clock and band (:func:`hysteresis_grid`), the search then starting
    from the best point of the grid."""
    def search() -> DriveFit:
        start = base
        if grid and form_choices(base) and effort > 0:
            start = hysteresis_grid(data, params, base).electronics
        return _search_drive(data, params, start, bounds, effort)
    key = ('search', params.to_vector().tobytes(), base,
           tuple((b.name, b.low, b.high, b.log) for b in bounds), effort, grid)
    return remembered(data.drive_cache, key, search, DRIVE_CACHE)


def hysteresis_grid(data: FitData, params: ValveParameters, base: ElectronicsConfig
                    ) -> DriveFit:
    """A clocked hysteresis hold's comparator clock, band and set point on a grid, the valve
    held at ``params``: clocks :data:`COMPARATOR_CLOCKS_HZ` and ``base``'s, bands
    :data:`HYSTERESIS_BANDS_A`, set points ``base``'s +- :data:`HYSTERESIS_HOLD_OFFSETS_A`;
    coarse to fine: every clock x band at ``base``'s set point, then every set point of the
    :data:`GRID_FINE_PAIRS` best of those pairs.

    The current at each falling edge (where the release starts) is the phase of the
    sampled limit cycle there, which jumps with these three: the cost has narrow valleys a
    local search from a default value does not reach, but a grid of this spacing does.
    The clock and the band set the ripple's period and its phase at the edge together, the
    set point moves the hold's mean; so the pairs of the lowest cost at one set point hold
    the valleys the other set points deepen.
    """
    def search() -> DriveFit:
        clocks = sorted(set(COMPARATOR_CLOCKS_HZ) | {base.comparator_frequency_hz})
        lo, hi = DRIVE_BOUNDS['holding_current_a']

        def cfg(f: float, b: float, dh: float) -> ElectronicsConfig:
            return base.replace(comparator_frequency_hz=f, hysteresis_band_a=b,
                                holding_current_a=min(max(base.holding_current_a + dh, lo), hi))
        pairs = [(f, b) for f in clocks for b in HYSTERESIS_BANDS_A]
        coarse = [base] + [cfg(f, b, 0.0) for f, b in pairs]
        costs = _costs(data, params.to_vector(), coarse)
        best = np.argsort(costs[1:], kind='stable')[:GRID_FINE_PAIRS]
        fine = [cfg(*pairs[k], dh) for k in sorted(best) for dh in HYSTERESIS_HOLD_OFFSETS_A
                if abs(dh) > 1e-12]
        tried = coarse + fine
        costs = np.concatenate([costs, _costs(data, params.to_vector(), fine)])
        k = int(np.argmin(costs))
        return DriveFit(tried[k], float(costs[k]))
    return remembered(data.drive_cache, ('grid', params.to_vector().tobytes(), base),
                      search, DRIVE_CACHE)


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
    if bounds and effort > 0:
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
              noise_a: float | None = None, inflation: float = 1.0,
              fixed: bool = False) -> DriveReport:
    """Identify the constants of the electronics' form with the valve held at ``params``.

    The form and the start values are ``data.electronics``.

    Parameters
    ----------
    data : FitData
        Fit data with at least one record through the electronics.
    params : ValveParameters
        The valve parameters (held).
    effort : int
        Nelder-Mead iterations of the search (0: the intervals only).
    noise_a : float, optional
        Noise of the current [A] for the intervals (default: from the residual).
    inflation : float
        Factor on the standard errors for a correlated/structured residual (the valve
        parameters' factor, :func:`.sensitivity.analyse_sensitivity`).
    fixed : bool
        Take ``data.electronics`` as it is (a user's description file): no hold estimate,
        no search; the intervals say how well the data confirm it.
    """
    base = data.electronics
    carried = _carried(data, base)
    names = [n for n in carried if carried[n]]
    notes = []
    if fixed:
        notes.append('form and constants as given (--electronics): not searched')
    elif effort > 0:
        base, note = hold_start(data, params, base)
        if note:
            notes.append(note)
    missing = [n for n in carried if not carried[n]]
    if missing:
        notes.append('not carried by these records (held at their given values): '
                     + ', '.join(missing))
    bounds = [ParameterBound(n, *DRIVE_BOUNDS[n]) for n in names]
    best = _search_drive(data, params, base, [], 0) if fixed else \
        _search_clocked(data, params, base, bounds, effort, True)
    values = {n: float(getattr(best.electronics, n)) for n in carried}
    ci: dict[str, float | None] = {n: None for n in carried}
    at_bound = []
    for b in ([] if fixed else bounds):
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
                       bounds={n: DRIVE_BOUNDS[n] for n in carried}, ci95_pct=ci,
                       pinned=pinned, at_bound=at_bound, carried=carried, notes=notes,
                       cost=best.cost)
