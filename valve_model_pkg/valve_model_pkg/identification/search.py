"""Derivative-free, population-based direct search inside box bounds.

The identification's cost (integral of the absolute current error) is not smooth: the
spool's end stops switch the dynamics and the absolute value has kinks. The paper used a
direct search; so does this module, in a form that suits the batch simulation API: every
step asks for a whole batch of candidate points at once, which the model evaluates in
parallel (numba ``prange``).

1. A global stage samples the unit box (scrambled Sobol points plus the start point) and
   keeps the best few, spread apart.
2. Nelder-Mead simplices run from those points *in lock step*: each iteration gathers the
   reflection points of all simplices into one batch, then the expansion or contraction
   points, then any shrink points. Bounds are handled by clipping to the unit box.
3. The best simplex is restarted once it has converged, with a fresh simplex around its
   best vertex, because Nelder-Mead can stall on a collapsed simplex.

Everything works in normalised coordinates ``u`` in ``[0, 1]^n``; the caller maps them to
physical parameters (log-scaled between the bounds).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.stats import qmc

__all__ = ['SearchResult', 'SearchSettings', 'direct_search']

_LOG = logging.getLogger(__name__)

#: Batch objective: (m, n) points in the unit box -> (m,) costs (``inf`` = infeasible).
BatchObjective = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class SearchSettings:
    """Effort of :func:`direct_search`.

    Attributes
    ----------
    global_samples : int
        Sobol points of the global stage (0 skips it: local search from the start only).
    starts : int
        Number of Nelder-Mead simplices run in lock step.
    max_iterations : int
        Nelder-Mead iterations (each evaluates one batch, or two, or a shrink).
    initial_step : float
        Edge of the initial simplex in unit-box coordinates.
    restarts : int
        Fresh simplices around the best point after convergence (stops early when a
        restart brings no improvement).
    stall_iterations : int
        A simplex whose best cost has not improved (relatively, by ``tolerance``) for this
        many iterations is stopped: on the kinks of an absolute-error cost Nelder-Mead can
        crawl for hundreds of iterations, and a fresh simplex gets out faster.
    tolerance : float
        Converged when a simplex's cost spread is below ``tolerance`` times its best cost
        and its diameter is below ``10 * tolerance`` (unit-box units).
    seed : int
        Seed of the Sobol scrambling.
    """

    global_samples: int = 256
    starts: int = 6
    max_iterations: int = 400
    initial_step: float = 0.12
    restarts: int = 3
    stall_iterations: int = 60
    tolerance: float = 1e-4
    seed: int = 0


@dataclass
class SearchResult:
    """Outcome of :func:`direct_search`."""

    u: np.ndarray
    cost: float
    evaluations: int
    iterations: int
    history: list[float] = field(default_factory=list)
    starts_u: np.ndarray | None = None
    starts_cost: np.ndarray | None = None


class _Counter:
    """Wraps the objective: counts evaluations, clips to the box, reports progress."""

    def __init__(self, fun: BatchObjective, progress: Callable[[str], None] | None) -> None:
        self.fun = fun
        self.n = 0
        self.progress = progress
        self.best = math.inf

    def __call__(self, u: np.ndarray) -> np.ndarray:
        u = np.clip(np.atleast_2d(u), 0.0, 1.0)
        cost = np.asarray(self.fun(u), dtype=float)
        cost = np.where(np.isfinite(cost), cost, np.inf)
        self.n += u.shape[0]
        self.best = min(self.best, float(cost.min()) if cost.size else math.inf)
        return cost


def _initial_simplex(center: np.ndarray, step: float, free: np.ndarray) -> np.ndarray:
    """Simplex around ``center`` stepping along the ``free`` dimensions (inwards at bounds).

    Coordinates not in ``free`` are the same in every vertex, and Nelder-Mead's moves
    (affine combinations of vertices) keep them so: that is how a profile search holds a
    parameter fixed per simplex.
    """
    simplex = np.repeat(center[None, :], free.size + 1, axis=0)
    for k, j in enumerate(free):
        s = step if center[j] + step <= 1.0 else -step
        simplex[k + 1, j] = center[j] + s
    return simplex


def _nelder_mead_lockstep(fun: _Counter, starts: np.ndarray, settings: SearchSettings,
                          progress: Callable[[str], None] | None, label: str,
                          free: np.ndarray | None = None
                          ) -> tuple[np.ndarray, np.ndarray, int]:
    """Run one Nelder-Mead per start in lock step; return (vertices, costs, iterations)."""
    k, dim = starts.shape
    free = np.arange(dim) if free is None else np.asarray(free)
    n = free.size
    # Adaptive coefficients (Gao & Han 2012) behave better than the classic ones in 8+ dims.
    alpha, gamma = 1.0, 1.0 + 2.0 / n
    rho, sigma = 0.75 - 1.0 / (2.0 * n), 1.0 - 1.0 / n
    simp = np.stack([_initial_simplex(s, settings.initial_step, free) for s in starts])
    cost = fun(simp.reshape(-1, dim)).reshape(k, n + 1)
    active = np.ones(k, dtype=bool)
    best_seen = cost.min(axis=1)
    last_gain = np.zeros(k, dtype=int)
    it = 0
    for it in range(1, settings.max_iterations + 1):
        order = np.argsort(cost, axis=1)
        simp = np.take_along_axis(simp, order[:, :, None], axis=1)
        cost = np.take_along_axis(cost, order, axis=1)
        spread = cost[:, -1] - cost[:, 0]
        diam = np.max(np.abs(simp - simp[:, :1, :]), axis=(1, 2))
        done = (spread <= settings.tolerance * np.maximum(np.abs(cost[:, 0]), 1e-300)) & \
            (diam <= 10.0 * settings.tolerance)
        improved = cost[:, 0] < best_seen * (1.0 - settings.tolerance)
        last_gain[improved] = it
        best_seen = np.minimum(best_seen, cost[:, 0])
        done |= it - last_gain > settings.stall_iterations
        active &= ~done
        if progress and (it % 50 == 0 or not active.any()):
            progress(f'{label}: iteration {it}, best cost {cost[:, 0].min():.6g}, '
                     f'{int(active.sum())}/{k} simplices active, {fun.n} simulations')
        if not active.any():
            break
        idx = np.flatnonzero(active)
        centroid = simp[idx, :-1, :].mean(axis=1)
        worst = simp[idx, -1, :]
        xr = np.clip(centroid + alpha * (centroid - worst), 0.0, 1.0)
        fr = fun(xr)
        best_c, second_worst, worst_c = cost[idx, 0], cost[idx, -2], cost[idx, -1]

        expand = fr < best_c
        outside = (fr >= second_worst) & (fr < worst_c)
        inside = fr >= worst_c
        accept_r = (fr < second_worst) & ~expand
        # Second batch: expansions and contractions together.
        xe = np.clip(centroid + gamma * (xr - centroid), 0.0, 1.0)
        xoc = np.clip(centroid + rho * (xr - centroid), 0.0, 1.0)
        xic = np.clip(centroid - rho * (centroid - worst), 0.0, 1.0)
        second = np.where(expand[:, None], xe, np.where(outside[:, None], xoc, xic))
        need2 = expand | outside | inside
        f2 = np.full(idx.size, np.inf)
        if need2.any():
            f2[need2] = fun(second[need2])
        shrink = np.zeros(idx.size, dtype=bool)
        for j, s in enumerate(idx):
            if accept_r[j]:
                simp[s, -1], cost[s, -1] = xr[j], fr[j]
            elif expand[j]:
                if f2[j] < fr[j]:
                    simp[s, -1], cost[s, -1] = second[j], f2[j]
                else:
                    simp[s, -1], cost[s, -1] = xr[j], fr[j]
            elif outside[j]:
                if f2[j] <= fr[j]:
                    simp[s, -1], cost[s, -1] = second[j], f2[j]
                else:
                    shrink[j] = True
            else:
                if f2[j] < worst_c[j]:
                    simp[s, -1], cost[s, -1] = second[j], f2[j]
                else:
                    shrink[j] = True
        if shrink.any():
            sidx = idx[shrink]
            pts = simp[sidx, :1, :] + sigma * (simp[sidx, 1:, :] - simp[sidx, :1, :])
            fs = fun(pts.reshape(-1, dim)).reshape(sidx.size, n)
            simp[sidx, 1:, :] = pts
            cost[sidx, 1:] = fs
    order = np.argsort(cost, axis=1)
    simp = np.take_along_axis(simp, order[:, :, None], axis=1)
    cost = np.take_along_axis(cost, order, axis=1)
    return simp, cost, it


def _pick_starts(u: np.ndarray, cost: np.ndarray, k: int, min_distance: float) -> np.ndarray:
    """Best ``k`` points at least ``min_distance`` apart (fills up with the next best)."""
    order = np.argsort(cost)
    chosen: list[int] = []
    for i in order:
        if not np.isfinite(cost[i]):
            break
        if all(np.max(np.abs(u[i] - u[j])) >= min_distance for j in chosen):
            chosen.append(int(i))
        if len(chosen) == k:
            break
    for i in order:
        if len(chosen) == k or not np.isfinite(cost[i]):
            break
        if int(i) not in chosen:
            chosen.append(int(i))
    return u[chosen]


def direct_search(fun: BatchObjective, u0: np.ndarray, settings: SearchSettings = SearchSettings(),
                  *, progress: Callable[[str], None] | None = None,
                  label: str = 'search', fixed: np.ndarray | None = None) -> SearchResult:
    """Minimise a batch objective over the unit box.

    Parameters
    ----------
    fun : callable
        ``fun(U) -> costs`` for ``U`` of shape (m, n) in ``[0, 1]^n``; returns shape (m,),
        ``inf`` for infeasible points.
    u0 : numpy.ndarray, shape (n,) or (k, n)
        Start point(s) (e.g. the measured values); always among the candidates. Without
        a global stage, one simplex runs from each.
    settings : SearchSettings
        Effort.
    progress : callable, optional
        Receives one-line progress messages.
    label : str
        Prefix of the progress messages.
    fixed : numpy.ndarray of int, optional
        Dimensions held at their start values in the first (lock-step) stage: a profile
        search, e.g. one simplex per trial value of an effect parameter. The restarts
        then free every dimension.

    Returns
    -------
    SearchResult
        Best point, its cost, the number of evaluations.
    """
    u_starts = np.clip(np.atleast_2d(np.asarray(u0, dtype=float)), 0.0, 1.0)
    u0 = u_starts[0]
    n = u0.size
    counter = _Counter(fun, progress)
    history: list[float] = []
    if settings.global_samples > 0:
        m = 2 ** int(math.ceil(math.log2(max(settings.global_samples, 2))))
        sob = qmc.Sobol(n, scramble=True, seed=settings.seed).random(m)
        cand = np.vstack([u_starts, sob])
        ccost = counter(cand)
        if progress:
            progress(f'{label}: global stage, {cand.shape[0]} points, best cost '
                     f'{np.min(ccost):.6g}')
        starts = _pick_starts(cand, ccost, settings.starts, min_distance=0.15)
        history.append(float(np.min(ccost)))
    else:
        starts = u_starts
        ccost = None
    free = None if fixed is None else np.setdiff1d(np.arange(n), np.asarray(fixed))
    simp, cost, iters = _nelder_mead_lockstep(counter, starts, settings, progress, label,
                                              free)
    best_s = int(np.argmin(cost[:, 0]))
    best_u, best_c = simp[best_s, 0].copy(), float(cost[best_s, 0])
    history.append(best_c)
    total_iters = iters
    for r in range(settings.restarts):
        # Each restart is a fresh, smaller simplex around the best point so far.
        step = max(settings.initial_step / 2.0 ** (r + 1), 20 * settings.tolerance)
        rs = SearchSettings(global_samples=0, starts=1, max_iterations=settings.max_iterations,
                            initial_step=step, restarts=0, tolerance=settings.tolerance,
                            stall_iterations=settings.stall_iterations, seed=settings.seed)
        simp_r, cost_r, it_r = _nelder_mead_lockstep(counter, best_u[None, :], rs, progress,
                                                     f'{label} (restart {r + 1})')
        total_iters += it_r
        gain = best_c - float(cost_r[0, 0])
        if gain > 0.0:
            best_u, best_c = simp_r[0, 0].copy(), float(cost_r[0, 0])
        history.append(best_c)
        if gain <= settings.tolerance * abs(best_c):
            break
    _LOG.debug('%s: cost %.6g after %d evaluations', label, best_c, counter.n)
    return SearchResult(u=best_u, cost=best_c, evaluations=counter.n, iterations=total_iters,
                        history=history, starts_u=starts,
                        starts_cost=None if ccost is None else np.sort(ccost)[:len(starts)])
