"""Synthetic duty maps with known answers, for tests, benchmarks and examples.

:func:`linear_map` builds a :class:`DutyMap` whose curves are straight ramps from a dead
band edge to a saturation edge (a clipped linear function of duty); the edge moves linearly
with the supply pressure (the paper's "shift without changing the width") and the width
shrinks with frequency. Inverting it has exact answers, which the tests use.
"""
from __future__ import annotations

import numpy as np

from .dutymap import DutyMap

__all__ = ['linear_map', 'linear_position']


def linear_position(duty: float | np.ndarray, pwm_frequency_hz: float,
                    supply_pressure_pa: float, *, dead_band: float = 0.10,
                    shift_per_bar: float = 0.01, width_at_20_hz: float = 0.8,
                    width_per_hz: float = 0.002) -> np.ndarray:
    """x_avg / x_max of the synthetic valve (see :func:`linear_map`)."""
    start = dead_band + shift_per_bar * supply_pressure_pa / 1e5
    width = width_at_20_hz - width_per_hz * (pwm_frequency_hz - 20.0)
    return np.clip((np.asarray(duty, dtype=float) - start) / width, 0.0, 1.0)


def linear_map(params=None, *, duty_step: float = 0.01,
               supply_pressures_pa=(0.0, 2e5, 4e5, 6e5),
               pwm_frequencies_hz=(20.0, 50.0), **shape: float) -> DutyMap:
    """A map of clipped linear ramps (exact on its grid).

    Parameters
    ----------
    params : ValveParameters, optional
        Recorded parameter set (default: the packaged paper parameters).
    duty_step : float
    supply_pressures_pa, pwm_frequencies_hz : sequence of float
    **shape
        ``dead_band``, ``shift_per_bar``, ``width_at_20_hz``, ``width_per_hz`` of
        :func:`linear_position`.
    """
    from valve_model_pkg.model import ElectronicsConfig, load_parameters
    params = load_parameters() if params is None else params
    n = round(1.0 / duty_step)
    duty = np.round(np.linspace(0.0, 1.0, n + 1), 12)
    x = np.array([[linear_position(duty, f, p, **shape) for p in supply_pressures_pa]
                  for f in pwm_frequencies_hz])
    return DutyMap(duty=duty, supply_pressures_pa=np.asarray(supply_pressures_pa, float),
                   pwm_frequencies_hz=np.asarray(pwm_frequencies_hz, float),
                   position_fraction=x, parameters=params.to_dict(),
                   electronics=ElectronicsConfig().to_dict(),
                   generator={'program': 'valve_model_pkg.maps.synthetic.linear_map'},
                   notes=['synthetic map of clipped linear ramps (not a simulation)'])
