"""Periodic steady state of a PWM-driven valve, detected from its period averages.

A PWM run reaches a *periodic steady state* when every PWM period repeats the previous
one. The map generator only sees the average spool position of each period,
``a_0, a_1, ...`` (fractions of x_max, from the model's batch API), so the criterion is
stated on those:

* **Cycle of one period** (the normal case): the last ``window`` period-to-period changes
  ``|a_k - a_(k-1)|`` are all at most ``tolerance``, and the remaining drift, estimated by a
  geometric extrapolation of the last two changes (``|d_k| rho / (1 - rho)`` with
  ``rho = |d_k| / |d_(k-1)|``), is at most ``tolerance`` too. This refuses a slow creep that
  changes little per period but a lot in total. The steady value is ``a_k``.
* **Cycle of m periods** (m = 2 .. ``max_cycle``: a sub-harmonic limit cycle, e.g. a spool
  that does not quite close every other period at a high PWM frequency): the last
  ``max(window, 2 m)`` lag-m changes ``|a_k - a_(k-m)|`` are at most ``tolerance``. The steady
  value is the mean of the last m period averages (the average over the whole cycle, which
  is what the orifice sees at steady state).
* At least ``min_periods`` periods are always simulated (the first period starts from a
  closed valve with an empty capacitor and is never representative).

A sub-harmonic cycle is only looked for when the period-to-period changes exceed the
tolerance (a slow creep with small changes is never mistaken for a long cycle).

A run that meets neither within ``max_periods`` (a quasi-periodic or chaotic response, seen
near the edges of the effective range at 100 and 200 Hz) is reported as not converged; its
value is the mean over the second half of its periods (the long-run average the orifice
sees) and the map records the grid point as unconverged.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

__all__ = ['SteadyStateCriterion', 'SteadyState', 'detect_steady_state', 'steady_at',
           'not_converged']


@dataclass(frozen=True)
class SteadyStateCriterion:
    """Settings of the periodic-steady-state test (see the module docstring).

    Attributes
    ----------
    tolerance : float
        Largest period-to-period change of the average position that counts as repeated,
        fraction of x_max (default 1e-4 = 0.01 % of the stroke).
    window : int
        Number of consecutive changes that must be within tolerance.
    min_periods : int
        Periods always simulated.
    max_periods : int
        Periods after which a run is given up as not converged.
    max_cycle : int
        Longest sub-harmonic cycle (in PWM periods) accepted as periodic.
    """

    tolerance: float = 1e-4
    window: int = 3
    min_periods: int = 4
    max_periods: int = 400
    max_cycle: int = 16

    def __post_init__(self) -> None:
        if not (math.isfinite(self.tolerance) and self.tolerance > 0.0):
            raise ValueError(f'tolerance must be positive, got {self.tolerance!r}')
        if self.window < 1 or self.max_cycle < 1:
            raise ValueError('window and max_cycle must be at least 1')
        if not 2 <= self.min_periods <= self.max_periods:
            raise ValueError(f'need 2 <= min_periods <= max_periods, got {self.min_periods}, '
                             f'{self.max_periods}')

    @classmethod
    def from_dict(cls, data: dict) -> SteadyStateCriterion:
        """Inverse of :meth:`as_dict` (the description is ignored)."""
        return cls(**{k: v for k, v in data.items() if k != 'method'})

    def as_dict(self) -> dict:
        """Settings plus a one-line description of the method, for the map file."""
        d = asdict(self)
        d['method'] = ('period averages a_k: steady when the last `window` changes '
                       '|a_k - a_(k-m)| (m = 1, or a sub-harmonic cycle of m <= max_cycle '
                       'periods with max(window, 2m) changes) are <= tolerance (fraction of '
                       'x_max) and, for m = 1, the geometric extrapolation of the remaining '
                       'drift is <= tolerance; value = a_k (m = 1) or the mean of the last m '
                       'periods')
        return d


@dataclass(frozen=True)
class SteadyState:
    """Result of the steady-state test of one run.

    Attributes
    ----------
    converged : bool
    periods : int
        Periods needed (index of the last period used, plus one).
    cycle : int
        Periods per cycle (1 = period-periodic; 0 if not converged).
    value : float
        Steady average position, fraction of x_max.
    """

    converged: bool
    periods: int
    cycle: int
    value: float


def steady_at(a: np.ndarray, k: int, crit: SteadyStateCriterion) -> SteadyState | None:
    """The steady state if the criterion holds at period ``k`` of ``a`` (else None).

    Only ``a[: k + 1]`` is used, so a simulation can call this after every period.
    """
    tol = crit.tolerance
    w1 = crit.window
    if k < max(crit.min_periods - 1, w1):
        return None
    if np.max(np.abs(np.diff(a[k - w1:k + 1]))) <= tol:
        # changes per period are small: steady unless it is a slow creep
        d1, d0 = abs(a[k] - a[k - 1]), abs(a[k - 1] - a[k - 2]) if k >= 2 else 0.0
        if d1 > 1e-12 and d0 > 0.0:
            rho = d1 / d0
            if rho >= 1.0 or d1 * rho / (1.0 - rho) > tol:
                return None
        return SteadyState(True, k + 1, 1, float(a[k]))
    # a real sub-harmonic cycle changes by more than tol from period to period
    for m in range(2, crit.max_cycle + 1):
        w = max(w1, 2 * m)
        if k - w - m + 1 < 0:
            break
        seg = a[k - w - m + 1:k + 1]
        if np.max(np.abs(seg[m:] - seg[:-m])) <= tol:
            return SteadyState(True, k + 1, m, float(np.mean(a[k - m + 1:k + 1])))
    return None


def not_converged(a: np.ndarray) -> SteadyState:
    """The result for a run that never met the criterion: mean of its second half."""
    return SteadyState(False, int(a.size), 0, float(np.mean(a[a.size // 2:])))


def _first_steady(a: np.ndarray, crit: SteadyStateCriterion) -> SteadyState | None:
    for k in range(a.size):
        s = steady_at(a, k, crit)
        if s is not None:
            return s
    return None


def detect_steady_state(averages: np.ndarray, criterion: SteadyStateCriterion,
                        final: bool = False) -> list[SteadyState | None]:
    """Find the first period at which each run is in periodic steady state.

    Parameters
    ----------
    averages : numpy.ndarray, shape (n_runs, n_periods)
        Average position of each PWM period, fraction of x_max.
    criterion : SteadyStateCriterion
    final : bool
        True when no longer run will follow: an unsettled run then gets a not-converged
        :class:`SteadyState` (mean over the second half of its periods) instead of None.

    Returns
    -------
    list
        Per run a :class:`SteadyState`, or None if it has not settled (and not ``final``).
    """
    a = np.atleast_2d(np.asarray(averages, dtype=float))
    out: list[SteadyState | None] = []
    for row in a:
        s = _first_steady(row, criterion)
        if s is None and final:
            s = not_converged(row)
        out.append(s)
    return out
