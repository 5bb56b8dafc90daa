"""Figures of the static map: Fig. 8 (pressures), Fig. 9 (frequencies), Fig. 10 (flow).

matplotlib is imported inside the functions (Agg backend, no display needed), so the rest
of the package does not pay for it.
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from .dutymap import DutyMap

__all__ = ['plot_pressures', 'plot_frequencies', 'plot_flow_comparison']


def _pyplot():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def _curves(ax, duty_map: DutyMap, pairs: list[tuple[int, int]], labels: list[str]) -> None:
    for (i, j), label in zip(pairs, labels):
        feat = duty_map.features(i, j)
        width = '' if math.isnan(feat.effective_width) else \
            f' (range {feat.dead_band_duty:.0%}-{feat.saturation_duty:.0%})'
        d, x = duty_map.curve_points(i, j)     # grid plus refined points
        ax.plot(d * 100.0, x * 100.0, label=label + width)
    ax.set_xlabel('duty cycle [%]')
    ax.set_ylabel(r'average spool position $\bar{x}/x_{max}$ [%]')
    ax.set_xlim(0, 100)
    ax.set_ylim(-2, 102)
    ax.grid(True, alpha=0.3)
    ax.legend(loc='lower right', fontsize=8)


def plot_pressures(duty_map: DutyMap, path: str | os.PathLike[str],
                   pwm_frequency_hz: float = 50.0) -> Path:
    """Fig. 8: x_avg/x_max against duty at one frequency, one curve per supply pressure."""
    plt = _pyplot()
    i = duty_map.frequency_index(pwm_frequency_hz)
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    n_p = duty_map.supply_pressures_pa.size
    _curves(ax, duty_map, [(i, j) for j in range(n_p)],
            [f'{p / 1e5:g} bar' for p in duty_map.supply_pressures_pa])
    ax.set_title(f'Average spool position vs duty, f_PWM = {pwm_frequency_hz:g} Hz (Fig. 8)')
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_frequencies(duty_map: DutyMap, path: str | os.PathLike[str],
                     supply_pressure_pa: float = 4.0e5) -> Path:
    """Fig. 9: x_avg/x_max against duty at one pressure, one curve per PWM frequency."""
    plt = _pyplot()
    j = duty_map.pressure_index(supply_pressure_pa)
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    n_f = duty_map.pwm_frequencies_hz.size
    _curves(ax, duty_map, [(i, j) for i in range(n_f)],
            [f'{f:g} Hz' for f in duty_map.pwm_frequencies_hz])
    ax.set_title(f'Average spool position vs duty, P_s = {supply_pressure_pa / 1e5:g} bar '
                 '(Fig. 9)')
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_flow_comparison(duty: np.ndarray, measured_fraction: np.ndarray,
                         map_duty: np.ndarray, map_fraction: np.ndarray,
                         path: str | os.PathLike[str], title: str = '') -> Path:
    """Fig. 10: measured flow percentage and the map's average position percentage."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    ax.plot(np.asarray(map_duty) * 100.0, np.asarray(map_fraction) * 100.0,
            label=r'simulated $\bar{x}/x_{max}$ (map)')
    ax.plot(np.asarray(duty) * 100.0, np.asarray(measured_fraction) * 100.0, 'o', ms=4,
            label='measured flow / flow at 100 %')
    ax.set_xlabel('duty cycle [%]')
    ax.set_ylabel('[%]')
    ax.set_xlim(0, 100)
    ax.grid(True, alpha=0.3)
    ax.legend(loc='lower right', fontsize=8)
    ax.set_title(title or 'Measured flow and simulated average position (Fig. 10)')
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
