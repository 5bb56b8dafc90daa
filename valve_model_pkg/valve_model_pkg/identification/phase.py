"""The main PWM period grid's phase: a nuisance parameter, placed for each model.

An operational record's telemetry bounds its main PWM period starts only through its
command changes: the grid may sit anywhere in a range of about one sample interval
(:attr:`~.measurement.DriveInput.phase_range_s`, 1 ms at 1 kHz). Where in that range the
model's interval-mean current fits best depends on the model: an effect that changes the
timing of the response to an edge moves the best phase by a good part of the range (the
eddy path's immediate current step at each edge shifts it by about 0.3 ms at 4 mS, a
leakage inductance's delay the other way). A grid placed once with one model and kept for
another charges the other for the first model's timing, and an effect's true amount can
then fit worse than none at all.

So the phase is a parameter of each model, profiled out: placed at the model's own
parameters (:func:`place`) for the baseline at its search optimum, and for an effect's
refit at each trial amount (:class:`AmountPhases`) and at the refit's optimum. Every model
compared gets the same freedom, so the criteria stay fair.
"""
from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import replace
from typing import Sequence

import numpy as np

from ..model import ElectronicsConfig
from ..model.parameters import ValveParameters
from .measurement import Measurement, window
from .model_adapter import FIELD_INDEX
from .problem import FitData, ParameterSpace, _pool, remembered, unit_objective

__all__ = ['AmountPhases', 'PHASE_RESOLUTION_S', 'PHASE_TRIAL_WINDOW_S', 'best_phase',
           'phase_free', 'phase_shifts', 'place', 'placed', 'shift_measurement',
           'shiftable']

#: Span of the record each trial phase is judged on [s] (from the start of its compared
#: part): a placement costs one round of :data:`PHASE_TRIALS` runs of this span around
#: the expected phase, three when the best lies beyond that round (:func:`best_phase`).
PHASE_TRIAL_WINDOW_S = 0.4
#: Trial shifts per round of :func:`best_phase`.
PHASE_TRIALS = 11
#: Shifts closer than this are one placement [s] (the model latches commands 1 us ahead).
PHASE_RESOLUTION_S = 1e-6
#: Placements of parameter sets kept per data set (:func:`phase_shifts`), and data sets kept
#: per shift by an :class:`AmountPhases`.
PLACEMENT_CACHE = 64


def phase_free(m: Measurement) -> bool:
    """True when ``m``'s main PWM grid may move (a drive with a phase range)."""
    if m.drive is None:
        return False
    lo, hi = m.drive.phase_range_s
    return hi - lo > PHASE_RESOLUTION_S


def shiftable(data: FitData) -> bool:
    """True when any file of ``data`` has a main PWM grid that may move."""
    return any(phase_free(m) for m in data.full)


def shift_measurement(m: Measurement, delta_s: float) -> Measurement:
    """``m`` with its main PWM period grid moved by ``delta_s`` [s]; the main PWM level
    (its voltage column) follows."""
    new = m.drive.shifted(delta_s)
    return replace(m, drive=new, voltage_v=new.main_pwm_level(m.t_s))


def best_phase(m: Measurement, params: ValveParameters,
               electronics: ElectronicsConfig | None = None, parallel: bool = False,
               around_s: float | None = None) -> float:
    """The shift [s] of ``m``'s main PWM grid, within the range its command changes allow,
    whose simulated current on the first :data:`PHASE_TRIAL_WINDOW_S` of its compared part
    is closest to the measured one (mean absolute error).

    The search: :data:`PHASE_TRIALS` trial shifts over the range, then as many over a
    tenth of it around the best. With ``around_s`` (a shift expected near the best: the
    grid placed for a model close to this one) the fine round comes first, around it, and
    stands when its best lies inside its bracket (or on the range's end); a best on the
    bracket's edge means the minimum lies beyond it, and the whole search runs.
    ``parallel`` runs each round's trials on the identification's threads."""
    d = m.drive
    lo, hi = d.phase_range_s
    head = window(m, PHASE_TRIAL_WINDOW_S)
    raw = params.to_vector()[None, :]

    def cost(delta: float) -> float:
        data = FitData([replace(head, drive=d.shifted(delta))])
        data.parallel = False
        if electronics is not None:
            data.electronics = electronics
        return float(data.cost(raw)[0])

    def trial_round(centre: float, width: float) -> tuple[float, float, list[float]]:
        trials = [float(x) for x in np.linspace(max(lo, centre - width / 2),
                                                min(hi, centre + width / 2), PHASE_TRIALS)]
        costs = list(_pool().map(cost, trials)) if parallel else [cost(x) for x in trials]
        k = int(np.argmin(np.nan_to_num(costs, nan=np.inf)))   # the first of equal ones
        return trials[k], costs[k], trials

    fine = (hi - lo) / 10.0
    if around_s is not None:
        best, best_cost, trials = trial_round(min(max(around_s, lo), hi), fine)
        inner = trials[0] < best < trials[-1]
        at_end = best <= lo + PHASE_RESOLUTION_S or best >= hi - PHASE_RESOLUTION_S
        if np.isfinite(best_cost) and (inner or at_end):
            return best
    best, best_cost = 0.0, np.inf
    for width in (hi - lo, fine):
        centre = best if np.isfinite(best_cost) else 0.5 * (lo + hi)
        delta, c, _ = trial_round(centre, width)
        if c < best_cost:
            best, best_cost = delta, c
    return best


def placed(data: FitData, shifts: Sequence[float]) -> FitData:
    """``data`` with each file's grid moved by its shift [s] (``data`` itself when no shift
    reaches :data:`PHASE_RESOLUTION_S`); the same threads and electronics."""
    if all(abs(s) < PHASE_RESOLUTION_S for s in shifts):
        return data
    files = [shift_measurement(m, s) if abs(s) >= PHASE_RESOLUTION_S else m
             for m, s in zip(data.full, shifts)]
    out = FitData(files, max_rate_hz=data.max_rate_hz)
    out.parallel, out.workers, out.electronics = data.parallel, data.workers, data.electronics
    return out


def phase_shifts(data: FitData, params: ValveParameters,
                 around_s: Sequence[float] | None = None) -> tuple[float, ...]:
    """Each file's best grid shift at ``params`` [s] (:func:`best_phase`; 0 for a file
    whose grid may not move), searched first around ``around_s`` (per file; default 0:
    ``data``'s grids were placed for a model close to ``params``). The last
    :data:`PLACEMENT_CACHE` placements (under the electronics in force) are kept on
    ``data`` and its serial views."""
    around = tuple(around_s) if around_s is not None else (0.0,) * len(data.full)

    def search() -> tuple[float, ...]:
        return tuple(best_phase(m, params, data.electronics, data.parallel, a)
                     if phase_free(m) else 0.0 for m, a in zip(data.full, around))
    return remembered(data.phase_cache, (params.to_vector().tobytes(), data.electronics),
                      search, PLACEMENT_CACHE)


def place(data: FitData, params: ValveParameters) -> FitData:
    """``data`` with every main PWM grid placed where ``params``' current fits best
    (``data`` itself when no grid may move or none moves)."""
    if not shiftable(data):
        return data
    return placed(data, phase_shifts(data, params))


def _rounded(shift_s: float) -> float:
    """``shift_s`` on the grid of :data:`PHASE_RESOLUTION_S` [s] (one data set per step)."""
    return PHASE_RESOLUTION_S * round(shift_s / PHASE_RESOLUTION_S)


class AmountPhases:
    """The phases of an effect's refit: the grids placed per amount of the effect.

    :meth:`anchor` places the grids exactly at a parameter set (a trial amount with the
    other parameters where a profile starts it); any other amount of ``field`` gets each
    file's shift interpolated linearly between the anchors' amounts (the nearest anchor's
    beyond them), all rounded to :data:`PHASE_RESOLUTION_S`: the best phase moves smoothly
    with the amount, and the simplices that adapt the other parameters at an amount
    would otherwise pay for the grid of another. Without an anchor every amount runs on
    ``data`` as it is.

    Parameters
    ----------
    data : FitData
        The data searched (its grids as placed before the refit).
    field : str
        The effect's amount (its first field, a :class:`ValveParameters` field).
    """

    def __init__(self, data: FitData, field: str) -> None:
        self.data = data
        self.field = field
        self._anchors: dict[float, tuple[float, ...]] = {}
        self._placed: OrderedDict[tuple[float, ...], FitData] = OrderedDict()
        self._lock = threading.Lock()

    def anchor(self, params: ValveParameters) -> None:
        """Place the grids exactly at ``params`` for its amount."""
        amount = float(getattr(params, self.field))
        if amount not in self._anchors:
            near = self.shifts_at(amount)   # interpolated from the anchors so far
            self._anchors[amount] = tuple(_rounded(s) for s in phase_shifts(self.data, params,
                                                                            near))

    def shifts_at(self, amount: float) -> tuple[float, ...]:
        """Each file's shift at ``amount`` of the effect [s]."""
        if not self._anchors:
            return tuple(0.0 for _ in self.data.full)
        hit = self._anchors.get(amount)
        if hit is not None:
            return hit
        xs = sorted(self._anchors)
        cols = np.array([self._anchors[x] for x in xs])
        return tuple(_rounded(float(np.interp(amount, xs, cols[:, k])))
                     for k in range(cols.shape[1]))

    def data_at(self, amount: float) -> FitData:
        """The data with the grids placed for ``amount`` of the effect."""
        shifts = self.shifts_at(amount)
        with self._lock:
            hit = self._placed.get(shifts)
            if hit is not None:
                self._placed.move_to_end(shifts)
                return hit
        out = placed(self.data, shifts)
        with self._lock:
            self._placed[shifts] = out
            while len(self._placed) > PLACEMENT_CACHE:
                self._placed.popitem(last=False)
        return out

    def objective(self, space: ParameterSpace):
        """Batch objective over ``space``'s unit coordinates (as
        :func:`~.problem.unit_objective`), each row on the grids of its amount."""
        col = FIELD_INDEX[self.field]

        def fun(u: np.ndarray) -> np.ndarray:
            u = np.atleast_2d(u)
            raw = space.raw_matrix(u)
            out = np.full(raw.shape[0], np.inf)
            groups: dict[int, tuple[FitData, list[int]]] = {}
            for r in range(raw.shape[0]):
                amount = float(raw[r, col])
                # a row unit_objective refuses needs no grid of its own
                d = self.data_at(amount) if np.isfinite(amount) else self.data
                groups.setdefault(id(d), (d, []))[1].append(r)
            for d, idx in groups.values():
                out[idx] = unit_objective(space, d)(u[idx])
            return out
        return fun
