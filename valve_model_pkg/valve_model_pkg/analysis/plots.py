"""Figures of a run report: stacked panels over time, lost samples drawn as gaps.

Matplotlib's object API (``Figure``), no pyplot: no global state and no GUI backend, so
reports can be written from any thread or process.
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np
from matplotlib.figure import Figure

__all__ = ['Line', 'Panel', 'Span', 'plot_panels', 'with_gaps', 'moving_mean']

#: A sample further from the one before than this many median periods is lost.
_GAP_PERIODS = 2.5


class Line(NamedTuple):
    """One line of a panel: times [s], values, legend label, matplotlib format."""

    t_s: np.ndarray
    values: np.ndarray
    label: str
    style: str


class Panel(NamedTuple):
    """One panel: its y label and lines."""

    ylabel: str
    lines: list[Line]


class Span(NamedTuple):
    """A shaded time span in every panel: from, to [s] and its legend label."""

    start_s: float
    end_s: float
    label: str


def with_gaps(t: np.ndarray, y: np.ndarray, sequence: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
    """Insert NaN where samples are missing, so a plot draws them as gaps.

    Parameters
    ----------
    t, y : numpy.ndarray, shape (n,)
        Times [s] and values.
    sequence : numpy.ndarray, shape (n,), optional
        A per-message counter: a step other than one is a gap too.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        Times and values with a NaN inserted before each sample after a gap (a sequence
        gap, or more than 2.5 median periods).
    """
    if t.size < 3:
        return t, y
    dt = float(np.median(np.diff(t)))
    broken = np.diff(t) > _GAP_PERIODS * dt
    if sequence is not None and sequence.size == t.size:
        broken |= np.diff(sequence.astype(np.int64)) != 1
    idx = np.flatnonzero(broken) + 1
    if idx.size == 0:
        return t, y
    return (np.insert(t.astype(float), idx, np.nan),
            np.insert(np.asarray(y, dtype=float), idx, np.nan))


def moving_mean(t: np.ndarray, y: np.ndarray, window_s: float) -> np.ndarray:
    """Centred moving mean over ``window_s`` [s] (samples at the median period).

    Parameters
    ----------
    t, y : numpy.ndarray, shape (n,)
        Times [s] and values.
    window_s : float
        Window [s].

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    if t.size < 2:
        return y
    dt = float(np.median(np.diff(t)))
    n = max(1, int(round(window_s / dt)))
    kernel = np.ones(n) / n
    return np.convolve(y, kernel, mode='same')


def plot_panels(path: Path, t0_s: float, panels: Sequence[Panel], title: str,
                span: Span | None = None) -> None:
    """Write stacked panels sharing the time axis (time from ``t0_s`` [s]) as a PNG."""
    fig = Figure(figsize=(11, 2.3 * len(panels)))
    axes = np.atleast_1d(fig.subplots(len(panels), 1, sharex=True))
    for ax, (ylabel, lines) in zip(axes, panels):
        for t, y, label, style in lines:
            ax.plot(t - t0_s, y, style, label=label, linewidth=1.0)
        if span is not None:  # where the close-up is, in every panel of the overview
            ax.axvspan(span.start_s - t0_s, span.end_s - t0_s, color='tab:orange', alpha=0.25,
                       label=span.label)
        ax.set_ylabel(ylabel)
        ax.grid(True, alpha=0.3)
        if len(lines) > 1 or span is not None:
            ax.legend(loc='upper right', fontsize=8)
    axes[-1].set_xlabel('time [s]')
    axes[0].set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
