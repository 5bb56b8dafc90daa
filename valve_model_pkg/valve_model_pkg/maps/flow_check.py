"""Fig. 10: measured steady flow against the map's average spool position.

The paper validates the static map by measuring the steady output flow of the valve at
50 Hz and 4 bar, exhausting to atmosphere, for duties from 0 to 100 %. With the pressures
fixed, eq. (12) makes the flow proportional to the averaged opening x_avg in either regime
(choked: 0.0405 C_d C_A x P_sup / sqrt(T); subsonic: the same times a function of the
pressure ratio only), so the *flow percentage* (flow over the flow at 100 % duty) equals
the map's x_avg / x_max divided by its value at 100 % duty (1 whenever the valve opens at
all). This module reads a measured ``flow_map`` file of the measured-data format
(read by :mod:`valve_model_pkg.dataformat`) and compares it with the map, point by point
and overall. The flow percentage does not depend on the orifice constant; a ``mass_flow``
file also gives the absolute scale, from which
:func:`valve_model_pkg.maps.flow_identification.identify_from_flow_map` identifies
C_d C_A (``valve_flow_check --out DIR``).

A ``flow_map`` file (the measured-data format, ``shared/measured-data-format.md`` of the
steering repository)::

    # experiment: flow_map
    # supply_pressure_pa: 400000          (gauge)
    # output_pressure_pa: 0               (gauge, optional, default 0)
    # pwm_frequency_hz: 50
    # supply_temperature_k: 293.15        (optional)
    duty,mass_flow                         (or duty,flow_fraction)
    0.0,0.0
    0.05,0.0
    ...
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import dataformat
from .dutymap import DutyMap
from ..errors import FlowMapFormatError
from .inversion import OrificeConstants, flow_per_opening

__all__ = ['FlowMap', 'FlowComparison', 'read_flow_map', 'write_flow_map', 'compare_flow_map',
           'map_flow_fraction', 'map_flow_position']


@dataclass(frozen=True)
class FlowMap:
    """A measured steady flow against duty.

    Attributes
    ----------
    path : str
    duty : numpy.ndarray, shape (n,)
        Duties [1], ascending.
    mass_flow_kg_s : numpy.ndarray, shape (n,) or None
        Measured mass flow [kg/s] (None for a ``flow_fraction`` file).
    flow_fraction : numpy.ndarray, shape (n,)
        Flow over the flow at 100 % duty [1] (given, or computed from ``mass_flow``).
    supply_pressure_pa, output_pressure_pa : float
        Gauge [Pa].
    pwm_frequency_hz : float
    supply_temperature_k : float or None
    metadata : dict
        All ``# key: value`` lines (unknown keys kept).
    """

    path: str
    duty: np.ndarray
    mass_flow_kg_s: np.ndarray | None
    flow_fraction: np.ndarray
    supply_pressure_pa: float
    output_pressure_pa: float
    pwm_frequency_hz: float
    supply_temperature_k: float | None
    metadata: dict[str, str] = field(default_factory=dict)


def read_flow_map(path: str | os.PathLike[str], *,
                  pwm_frequency_hz: float | None = None,
                  supply_pressure_pa: float | None = None) -> FlowMap:
    """Read a measured ``flow_map`` file, refusing anything malformed.

    The file is read by :func:`valve_model_pkg.dataformat.read_flow_map` (the rules of the
    measured-data format); this function adds what the comparison needs: the PWM
    frequency and supply pressure (from the file or the caller) and, for ``mass_flow``
    files, a row at duty 1 to scale by.

    Parameters
    ----------
    path : path-like
    pwm_frequency_hz, supply_pressure_pa : float, optional
        Used when the file does not state them (a value in the file must agree).

    Raises
    ------
    FlowMapFormatError
        Naming the file, the line and the problem. No row is ever dropped silently.
    """
    spath = str(path)
    try:
        record = dataformat.read_flow_map(path)
    except dataformat.DataFormatError as err:
        raise FlowMapFormatError(err.path, err.line, err.reason) from err
    numeric = {'pwm_frequency_hz': record.pwm_frequency_hz,
               'supply_pressure_pa': record.supply_pressure_pa}
    for key, given in (('pwm_frequency_hz', pwm_frequency_hz),
                       ('supply_pressure_pa', supply_pressure_pa)):
        if numeric[key] is None:
            if given is None:
                raise FlowMapFormatError(spath, None, f'metadata {key} missing (and not '
                                                      'given on the command line)')
            numeric[key] = float(given)
        elif given is not None and not math.isclose(numeric[key], given, rel_tol=1e-9,
                                                    abs_tol=1e-9):
            raise FlowMapFormatError(spath, None, f'{key} is {numeric[key]:g} in the file but '
                                                  f'{given:g} was given')
    if numeric['pwm_frequency_hz'] <= 0.0:
        raise FlowMapFormatError(spath, None, 'pwm_frequency_hz must be positive')
    d = record.duty
    if record.mass_flow_kg_s is not None:
        v = record.mass_flow_kg_s
        if d[-1] != 1.0:
            raise FlowMapFormatError(spath, None, 'mass_flow file needs a row at duty 1 (the '
                                                  'flow percentage is relative to 100 % duty)')
        if v[-1] <= 0.0:
            raise FlowMapFormatError(spath, int(record.line_numbers[-1]),
                                     'flow at 100 % duty is not positive')
        fraction, mass = v / v[-1], v
    else:
        fraction, mass = record.flow_fraction, None
    return FlowMap(spath, d, mass, fraction, numeric['supply_pressure_pa'],
                   record.output_pressure_pa, numeric['pwm_frequency_hz'],
                   record.supply_temperature_k, record.metadata)


def write_flow_map(path: str | os.PathLike[str], duty: np.ndarray, *,
                   supply_pressure_pa: float, pwm_frequency_hz: float,
                   mass_flow_kg_s: np.ndarray | None = None,
                   flow_fraction: np.ndarray | None = None, output_pressure_pa: float = 0.0,
                   supply_temperature_k: float | None = None,
                   metadata: dict[str, str] | None = None) -> Path:
    """Write a ``flow_map`` file (exactly one of the value columns) in the measured-data
    format, through :func:`valve_model_pkg.dataformat.write_table`."""
    if (mass_flow_kg_s is None) == (flow_fraction is None):
        raise ValueError('give exactly one of mass_flow_kg_s and flow_fraction')
    col, values = ('mass_flow', mass_flow_kg_s) if mass_flow_kg_s is not None \
        else ('flow_fraction', flow_fraction)
    meta: dict[str, object] = {'experiment': 'flow_map', **(metadata or {}),
                               'supply_pressure_pa': float(supply_pressure_pa),
                               'output_pressure_pa': float(output_pressure_pa),
                               'pwm_frequency_hz': float(pwm_frequency_hz)}
    if supply_temperature_k is not None:
        meta['supply_temperature_k'] = float(supply_temperature_k)
    return dataformat.write_table(path, meta, {'duty': duty, col: values})


def map_flow_position(duty_map: DutyMap, duty: float, pwm_frequency_hz: float,
                      supply_pressure_pa: float) -> float:
    """x_avg / x_max of the map at one duty (pressures between the grid interpolated)."""
    i_f = duty_map.frequency_index(pwm_frequency_hz)
    try:
        d, x = duty_map.curve_points(i_f, duty_map.pressure_index(supply_pressure_pa))
        return float(np.interp(duty, d, x))
    except KeyError:
        from .inversion import FlowToDutyInverter
        inv = FlowToDutyInverter(duty_map, pwm_frequency_hz)
        return inv.duty_to_position(float(duty), supply_pressure_pa)


def map_flow_fraction(duty_map: DutyMap, duty: np.ndarray, pwm_frequency_hz: float,
                      supply_pressure_pa: float) -> np.ndarray:
    """Flow percentage (as a fraction) the map predicts: x_avg(d) / x_avg(100 %).

    Between grid pressures the curves are interpolated along the duty axis, as the
    flow-to-duty inversion does; the frequency must be on the grid.
    """
    i_f = duty_map.frequency_index(pwm_frequency_hz)
    duty = np.asarray(duty, dtype=float)
    try:
        d, curve = duty_map.curve_points(i_f, duty_map.pressure_index(supply_pressure_pa))
        x = np.interp(duty, d, curve)
        full = float(curve[-1])
    except KeyError:
        from .inversion import FlowToDutyInverter
        inv = FlowToDutyInverter(duty_map, pwm_frequency_hz)
        x = np.array([inv.duty_to_position(float(d), supply_pressure_pa) for d in duty])
        full = inv.duty_to_position(1.0, supply_pressure_pa)
    return x / full if full > 0.0 else np.zeros_like(x)


@dataclass(frozen=True)
class FlowComparison:
    """Measured against predicted flow, per duty and overall.

    Attributes
    ----------
    duty : numpy.ndarray, shape (n,)
    measured_fraction, predicted_fraction : numpy.ndarray, shape (n,)
        Flow over the flow at 100 % duty [1].
    error_fraction : numpy.ndarray, shape (n,)
        measured - predicted [1] (percentage points / 100 of the full flow).
    rms_error, max_abs_error, mean_error : float
        Over all points [1].
    choked : bool
        Regime of eq. (12) at the file's pressures.
    measured_full_flow_kg_s : float or None
        Measured flow at 100 % duty.
    predicted_full_flow_kg_s : float
        eq. (12) with the map's parameters at x_avg(100 %).
    """

    duty: np.ndarray
    measured_fraction: np.ndarray
    predicted_fraction: np.ndarray
    error_fraction: np.ndarray
    rms_error: float
    max_abs_error: float
    mean_error: float
    choked: bool
    measured_full_flow_kg_s: float | None
    predicted_full_flow_kg_s: float

    def table(self) -> str:
        """Plain-text report: one row per duty, then the overall figures."""
        lines = [' duty %   measured %   map %    error %',
                 ' ------   ----------   -----    -------']
        for d, m, p, e in zip(self.duty, self.measured_fraction, self.predicted_fraction,
                              self.error_fraction):
            lines.append(f'{d * 100:7.2f}   {m * 100:10.2f}   {p * 100:5.2f}   {e * 100:+8.2f}')
        lines.append(f'overall: rms {self.rms_error * 100:.2f} %, max |error| '
                     f'{self.max_abs_error * 100:.2f} %, mean {self.mean_error * 100:+.2f} % '
                     'of the flow at 100 % duty')
        regime = 'choked' if self.choked else 'subsonic'
        full = f'predicted full flow {self.predicted_full_flow_kg_s:.6g} kg/s ({regime})'
        if self.measured_full_flow_kg_s is not None:
            full += f', measured {self.measured_full_flow_kg_s:.6g} kg/s ' \
                    f'({self.measured_full_flow_kg_s / self.predicted_full_flow_kg_s - 1:+.1%})'
        lines.append(full)
        return '\n'.join(lines)

    def as_dict(self) -> dict:
        """JSON-ready dict."""
        return {
            'points': [{'duty': float(d), 'measured_fraction': float(m),
                        'predicted_fraction': float(p), 'error_fraction': float(e)}
                       for d, m, p, e in zip(self.duty, self.measured_fraction,
                                             self.predicted_fraction, self.error_fraction)],
            'rms_error': self.rms_error, 'max_abs_error': self.max_abs_error,
            'mean_error': self.mean_error, 'choked': self.choked,
            'measured_full_flow_kg_s': self.measured_full_flow_kg_s,
            'predicted_full_flow_kg_s': self.predicted_full_flow_kg_s,
        }


def compare_flow_map(duty_map: DutyMap, measured: FlowMap) -> FlowComparison:
    """Compare a measured flow map with the duty map (Fig. 10).

    Raises
    ------
    KeyError
        If the file's PWM frequency is not in the map.
    """
    predicted = map_flow_fraction(duty_map, measured.duty, measured.pwm_frequency_hz,
                                  measured.supply_pressure_pa)
    err = measured.flow_fraction - predicted
    consts = OrificeConstants.from_parameters(duty_map.parameters)
    k_flow, choked = flow_per_opening(measured.supply_pressure_pa, measured.output_pressure_pa,
                                      consts, measured.supply_temperature_k)
    full_x = float(map_flow_position(duty_map, 1.0, measured.pwm_frequency_hz,
                                     measured.supply_pressure_pa))
    return FlowComparison(
        duty=measured.duty, measured_fraction=measured.flow_fraction,
        predicted_fraction=predicted, error_fraction=err,
        rms_error=float(np.sqrt(np.mean(err ** 2))), max_abs_error=float(np.max(np.abs(err))),
        mean_error=float(np.mean(err)), choked=choked,
        measured_full_flow_kg_s=None if measured.mass_flow_kg_s is None
        else float(measured.mass_flow_kg_s[-1]),
        predicted_full_flow_kg_s=float(k_flow * consts.stroke_m * full_x))
