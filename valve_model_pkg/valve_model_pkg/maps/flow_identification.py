"""The flow side identified: the orifice constant C_d C_A of eq. (12) from measurements.

eq. (12) gives the mass flow through the valve as

    dm/dt = C_d C_A x_avg p_sup / sqrt(T) * psi(p_out / p_sup)                       (12)

with psi the choked constant 0.0405 or the subsonic root. C_d (discharge coefficient) and
C_A (orifice area per metre of opening) appear only as their product, and the spool
dynamics (hence the static duty map x_avg(d)) do not depend on either: **only the product
C_d C_A is identifiable from flow**, and strictly only C_d C_A / sqrt(T) (T is taken as
known: the file's ``supply_temperature_k`` or the parameter set's). The convention of this
module: C_d keeps its value from the parameter set (a loss coefficient that the flow data
cannot separate from the area) and C_A is scaled, C_A = (C_d C_A)_identified / C_d. The
map x_avg(d) therefore stays valid; only the flow scale changes, which is what
``flow_to_duty`` needs.

Two sources are handled, both ROS-free:

1. A steady ``flow_map`` record (Fig. 10, :mod:`.flow_check`) with ``mass_flow`` in kg/s:
   :func:`identify_from_flow_map`. At fixed pressures the flow is linear in the product,
   q_i = (C_d C_A) g_i with g_i = eq. (12) at C_d C_A = 1 and x_avg = x_max r(d_i), r the
   map's x_avg / x_max; least squares through the origin over the duties at which the map
   has the valve open, with a Student-t interval. The dead band (duty where the flow
   starts) and the saturation (duty where it reaches full flow) of the map are checked
   against the measured curve.
2. A record of the cylinder's chamber (time, chamber pressure, chamber volume, valve
   opening, supply pressure): :func:`identify_from_chamber`. The chamber energy balance
   of the suite's plant (:mod:`valve_model_pkg.pneumatics.cylinder`, eq. C2),

       R T (m_in - m_bleed) = V dp/dt / n + p dV/dt                                 (C2)

   (n = 1: isothermal, d(pV)/dt = R T dm/dt with m = p V / (R T); n = gamma: adiabatic;
   the plant uses n = 1.2), is integrated over short windows so that the pressure is never
   differentiated (Stieltjes sums of V dp and p dV), and m_in = (C_d C_A) phi_valve,
   m_bleed = (C_d A)_bleed phi_bleed are fitted by linear least squares (the bleed either
   given or identified with the valve). :func:`chamber_record_from_bag` builds that record
   from a suite bag, given the cylinder geometry (which the bag does not carry).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..model.constants import ATMOSPHERIC_PRESSURE_PA
from ..model.orifice import mass_flow_absolute
from ..model.parameters import ValveParameters, implausible_values
from .dutymap import DutyMap
from .flow_check import FlowMap, map_flow_fraction, map_flow_position
from .inversion import OrificeConstants, flow_per_opening
from ..errors import FlowIdentificationError

__all__ = ['FlowIdentificationError', 'OrificeEstimate', 'EdgeCheck', 'FlowIdentification',
           'ChamberRecord', 'ChamberEstimate', 'identify_from_flow_map',
           'identify_from_chamber', 'chamber_record_from_bag', 'chamber_volume_m3',
           'opening_from_duty', 'flow_edges', 'with_orifice_product', 'write_parameters',
           'recalibrated_map', 'chamber_valve_flow',
           'START_THRESHOLD', 'SATURATION_THRESHOLD']

#: Flow fraction [1] above which the flow has "started" (end of the dead band).
START_THRESHOLD = 0.02
#: Flow fraction [1] at and above which the flow counts as saturated (full opening).
SATURATION_THRESHOLD = 0.98


@dataclass(frozen=True)
class OrificeEstimate:
    """The identified orifice constant and its interval.

    Attributes
    ----------
    product_m : float
        C_d C_A [m^2/m] (orifice area per metre of opening times the discharge coefficient).
    interval_m : tuple of float
        Two-sided confidence interval of ``product_m`` [m^2/m].
    confidence : float
        Level of the interval [1] (0.95).
    prior_product_m : float
        C_d C_A of the parameter set started from [m^2/m].
    discharge_coefficient : float
        C_d [1], kept from the parameter set.
    orifice_area_gradient_m : float
        C_A = product / C_d [m^2/m].
    temperature_k : float
        T used in eq. (12) [K] (only C_d C_A / sqrt(T) is identified).
    n_points : int
        Points (or windows) used in the fit.
    """

    product_m: float
    interval_m: tuple[float, float]
    confidence: float
    prior_product_m: float
    discharge_coefficient: float
    orifice_area_gradient_m: float
    temperature_k: float
    n_points: int

    @property
    def ratio_to_prior(self) -> float:
        """Identified over prior product [1]."""
        return self.product_m / self.prior_product_m

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return {'discharge_coefficient': self.discharge_coefficient,
                'orifice_area_gradient_m': self.orifice_area_gradient_m,
                'product_m': self.product_m, 'interval_m': list(self.interval_m),
                'confidence': self.confidence, 'prior_product_m': self.prior_product_m,
                'ratio_to_prior': self.ratio_to_prior, 'temperature_k': self.temperature_k,
                'n_points': self.n_points,
                'note': 'only C_d*C_A (strictly C_d*C_A/sqrt(T)) is identifiable from flow; '
                        'C_d is kept from the parameter set and C_A = product / C_d'}


@dataclass(frozen=True)
class EdgeCheck:
    """One edge of the flow curve, measured against the map.

    Attributes
    ----------
    name : str
        ``dead_band`` (duty where the flow starts, fraction > :data:`START_THRESHOLD`) or
        ``saturation`` (duty where it reaches :data:`SATURATION_THRESHOLD`).
    threshold : float
        The flow fraction defining the edge [1].
    measured_duty : float or None
        From the measured points, linear interpolation between neighbours [1]; None if the
        measured curve never crosses the threshold.
    model_duty : float or None
        From the map sampled at the measured duties, same rule [1].
    model_duty_fine : float or None
        From the map on a 0.001 duty grid [1] (what a finer measurement would show).
    tolerance : float
        The measured duty spacing at the edge [1]: the file cannot locate it better.
    agrees : bool
        |measured - model| <= tolerance (both found, or both absent).
    """

    name: str
    threshold: float
    measured_duty: float | None
    model_duty: float | None
    model_duty_fine: float | None
    tolerance: float
    agrees: bool

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        diff = None if self.measured_duty is None or self.model_duty is None \
            else self.measured_duty - self.model_duty
        return {'threshold_fraction': self.threshold, 'measured_duty': self.measured_duty,
                'model_duty': self.model_duty, 'model_duty_fine': self.model_duty_fine,
                'difference': diff, 'tolerance': self.tolerance, 'agrees': self.agrees}


@dataclass(frozen=True)
class FlowIdentification:
    """Result of :func:`identify_from_flow_map`.

    Attributes
    ----------
    estimate : OrificeEstimate
    saturated_product_m : float or None
        C_d C_A from the saturated points alone [m^2/m] (x_avg = x_max there, so it does not
        depend on the map's shape); a cross-check of ``estimate``.
    dead_band, saturation : EdgeCheck
    error_before_pct, error_after_pct : float
        Rms of (measured - predicted mass flow) over all points, in % of the measured flow
        at 100 % duty, with the prior and the identified product.
    max_error_before_pct, max_error_after_pct : float
        Largest |error| in the same unit.
    params : ValveParameters
        The parameter set started from, with the identified C_A.
    choked : bool
        Regime of eq. (12) at the record's pressures.
    """

    estimate: OrificeEstimate
    saturated_product_m: float | None
    dead_band: EdgeCheck
    saturation: EdgeCheck
    error_before_pct: float
    error_after_pct: float
    max_error_before_pct: float
    max_error_after_pct: float
    params: ValveParameters
    choked: bool
    notes: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dict (the content of ``flow_identified.json``)."""
        return {'source': 'flow_map', **self.estimate.as_dict(),
                'saturated_product_m': self.saturated_product_m, 'choked': self.choked,
                'dead_band': self.dead_band.as_dict(),
                'saturation': self.saturation.as_dict(),
                'flow_error_pct_of_full_flow': {
                    'before': {'rms': self.error_before_pct, 'max': self.max_error_before_pct},
                    'after': {'rms': self.error_after_pct, 'max': self.max_error_after_pct}},
                'notes': list(self.notes)}

    def summary(self) -> str:
        """A few lines for a person."""
        e = self.estimate
        lo, hi = e.interval_m
        lines = [f'C_d*C_A = {e.product_m:.6g} m^2/m ({e.confidence:.0%} interval '
                 f'{lo:.6g} .. {hi:.6g}; prior {e.prior_product_m:.6g}, ratio '
                 f'{e.ratio_to_prior:.4f}); C_d kept {e.discharge_coefficient:g}, '
                 f'C_A = {e.orifice_area_gradient_m:.6g} m^2/m',
                 f'flow error (rms, % of full flow): before {self.error_before_pct:.2f} %, '
                 f'after {self.error_after_pct:.2f} %']
        for edge in (self.dead_band, self.saturation):
            lines.append(f'{edge.name}: measured duty {_fmt(edge.measured_duty)}, map '
                         f'{_fmt(edge.model_duty)} (fine grid {_fmt(edge.model_duty_fine)}), '
                         f'tolerance {edge.tolerance:.3f}: '
                         f'{"agrees" if edge.agrees else "DISAGREES"}')
        lines += self.notes
        return '\n'.join(lines)


def _fmt(value: float | None) -> str:
    return '-' if value is None else f'{value:.3f}'


def _t_quantile(confidence: float, dof: int) -> float:
    from scipy.stats import t as student_t
    return float(student_t.ppf(0.5 + confidence / 2.0, dof))


def _unit_constants(params: ValveParameters, temperature_k: float | None) -> OrificeConstants:
    """OrificeConstants with C_d = C_A = 1, so eq. (12) returns the flow per unit product."""
    c = OrificeConstants.from_parameters(params)
    return OrificeConstants(1.0, 1.0, c.supply_temperature_k if temperature_k is None
                            else float(temperature_k), c.gas_constant_j_per_kg_k,
                            c.heat_capacity_ratio, c.stroke_m)


def _through_origin(y: np.ndarray, g: np.ndarray, confidence: float
                    ) -> tuple[float, tuple[float, float]]:
    """Least squares y = P g through the origin; P and its Student-t interval."""
    sgg = float(g @ g)
    if g.size < 2 or sgg <= 0.0:
        raise FlowIdentificationError('fewer than 2 usable points to fit C_d*C_A')
    p = float(y @ g) / sgg
    res = y - p * g
    s2 = float(res @ res) / (g.size - 1)
    half = _t_quantile(confidence, g.size - 1) * math.sqrt(s2 / sgg)
    return p, (p - half, p + half)


def with_orifice_product(params: ValveParameters, product_m: float) -> ValveParameters:
    """The parameter set with C_A = ``product_m`` / C_d (C_d kept).

    Raises
    ------
    FlowIdentificationError
        If the product is not positive and finite or C_A leaves its plausible range.
    """
    if not (math.isfinite(product_m) and product_m > 0.0):
        raise FlowIdentificationError(f'identified C_d*C_A = {product_m!r} is not positive')
    new = params.replace(orifice_area_gradient_m=float(product_m / params.discharge_coefficient))
    for name, value, (lo, hi) in implausible_values(new):
        if name == 'orifice_area_gradient_m':
            raise FlowIdentificationError(
                f'identified orifice_area_gradient_m = {value:.6g} is outside its plausible '
                f'range [{lo:g}, {hi:g}] (check the units of mass_flow: kg/s)')
    return new


def flow_edges(duty: np.ndarray, fraction: np.ndarray, *,
               start_threshold: float = START_THRESHOLD,
               saturation_threshold: float = SATURATION_THRESHOLD
               ) -> tuple[float | None, float | None]:
    """Duty where a flow curve starts and where it saturates [1].

    Start: the first crossing above ``start_threshold``; saturation: the first duty from
    which the fraction stays at or above ``saturation_threshold``. Both are linearly
    interpolated between the neighbouring points; None if the curve never gets there.

    Parameters
    ----------
    duty : numpy.ndarray, shape (n,)
        Ascending duties [1].
    fraction : numpy.ndarray, shape (n,)
        Flow over the flow at 100 % duty [1].
    """
    d = np.asarray(duty, dtype=float)
    f = np.asarray(fraction, dtype=float)

    def crossing(i: int, level: float) -> float:
        if i == 0 or f[i] == f[i - 1]:
            return float(d[i])
        return float(d[i - 1] + (level - f[i - 1]) / (f[i] - f[i - 1]) * (d[i] - d[i - 1]))

    above = np.nonzero(f > start_threshold)[0]
    start = crossing(int(above[0]), start_threshold) if above.size else None
    below = np.nonzero(f < saturation_threshold)[0]
    if below.size == 0:
        sat: float | None = float(d[0])
    elif below[-1] == f.size - 1:
        sat = None
    else:
        sat = crossing(int(below[-1]) + 1, saturation_threshold)
    return start, sat


def _edge(name: str, threshold: float, measured: float | None, model: float | None,
          fine: float | None, duty: np.ndarray) -> EdgeCheck:
    where = model if model is not None else measured
    if where is None:
        tol = float(np.max(np.diff(duty))) if duty.size > 1 else 1.0
    else:
        j = int(np.clip(np.searchsorted(duty, where), 1, duty.size - 1))
        tol = float(duty[j] - duty[j - 1])
    if measured is None or model is None:
        agrees = measured is None and model is None
    else:
        agrees = abs(measured - model) <= tol + 1e-12
    return EdgeCheck(name, threshold, measured, model, fine, tol, agrees)


def identify_from_flow_map(duty_map: DutyMap, measured: FlowMap,
                           params: ValveParameters | None = None, *,
                           confidence: float = 0.95) -> FlowIdentification:
    """Identify C_d C_A from a measured ``flow_map`` record with mass flow (Fig. 10).

    Model: q(d) = (C_d C_A) g(d), g(d) = eq. (12) at C_d C_A = 1 and x_avg = x_max r(d),
    r = the map's x_avg / x_max at the record's frequency and supply pressure, T the
    record's ``supply_temperature_k`` (else the parameter set's). The fit is least
    squares through the origin over the duties where the map has the valve open (r > 0);
    the interval is the Student-t interval with n - 1 degrees of freedom (it covers the
    measurement scatter, not a bias of the map's shape, of T or of the pressure sensor).

    Parameters
    ----------
    duty_map : DutyMap
        The static map (its x_avg / x_max does not depend on C_d or C_A).
    measured : FlowMap
        A record read by :func:`.flow_check.read_flow_map`; must carry ``mass_flow``.
    params : ValveParameters, optional
        The parameter set to start from (default: the map's own).
    confidence : float
        Level of the interval [1].

    Raises
    ------
    FlowIdentificationError
        No ``mass_flow`` column, fewer than 2 open points, or an implausible result.
    KeyError
        If the record's PWM frequency is not in the map.
    """
    if measured.mass_flow_kg_s is None:
        raise FlowIdentificationError(
            f'{measured.path}: has flow_fraction only; identifying C_d*C_A needs the '
            'absolute flow (a "mass_flow" column in kg/s)')
    if params is None:
        params = ValveParameters.from_dict(duty_map.parameters)
    q = np.asarray(measured.mass_flow_kg_s, dtype=float)
    d = np.asarray(measured.duty, dtype=float)
    unit = _unit_constants(params, measured.supply_temperature_k)
    k1, choked = flow_per_opening(measured.supply_pressure_pa, measured.output_pressure_pa,
                                  unit)
    if k1 <= 0.0:
        raise FlowIdentificationError(
            f'{measured.path}: no forward pressure difference (supply '
            f'{measured.supply_pressure_pa:g} Pa, output {measured.output_pressure_pa:g} Pa '
            'gauge): the flow says nothing about the orifice')
    r = np.array([map_flow_position(duty_map, float(x), measured.pwm_frequency_hz,
                                    measured.supply_pressure_pa) for x in d])
    g = k1 * unit.stroke_m * r                 # flow per unit C_d*C_A [kg/s / (m^2/m)]
    open_ = r > 0.0
    product, interval = _through_origin(q[open_], g[open_], confidence)
    notes: list[str] = []
    sat = r >= SATURATION_THRESHOLD
    sat_product = None
    if np.count_nonzero(sat) >= 1:
        sat_product = float(q[sat] @ g[sat]) / float(g[sat] @ g[sat])
    new_params = with_orifice_product(params, product)
    prior = params.discharge_coefficient * params.orifice_area_gradient_m
    full = float(q[-1])
    err_before = (q - prior * g) / full * 100.0
    err_after = (q - product * g) / full * 100.0
    # Edges: the map sampled like the measurement (comparable) and on a fine grid.
    model_frac = map_flow_fraction(duty_map, d, measured.pwm_frequency_hz,
                                   measured.supply_pressure_pa)
    fine_d = np.linspace(0.0, 1.0, 1001)
    fine_frac = map_flow_fraction(duty_map, fine_d, measured.pwm_frequency_hz,
                                  measured.supply_pressure_pa)
    m_start, m_sat = flow_edges(d, measured.flow_fraction)
    p_start, p_sat = flow_edges(d, model_frac)
    f_start, f_sat = flow_edges(fine_d, fine_frac)
    dead = _edge('dead_band', START_THRESHOLD, m_start, p_start, f_start, d)
    satur = _edge('saturation', SATURATION_THRESHOLD, m_sat, p_sat, f_sat, d)
    if sat_product is not None and abs(sat_product / product - 1.0) > 0.03:
        notes.append(f'note: the saturated points alone give C_d*C_A = {sat_product:.6g} '
                     f'({sat_product / product - 1.0:+.1%}): the map\'s shape between dead band '
                     'and saturation does not match the measured curve')
    for edge in (dead, satur):
        if not edge.agrees:
            notes.append(f'note: the map\'s {edge.name.replace("_", " ")} is off the '
                         'measurement: re-identify the valve\'s dynamic parameters '
                         '(valve_identify) and rebuild the map')
    est = OrificeEstimate(product, interval, confidence, prior, params.discharge_coefficient,
                          new_params.orifice_area_gradient_m, unit.supply_temperature_k,
                          int(np.count_nonzero(open_)))
    return FlowIdentification(
        est, sat_product, dead, satur,
        float(np.sqrt(np.mean(err_before ** 2))), float(np.sqrt(np.mean(err_after ** 2))),
        float(np.max(np.abs(err_before))), float(np.max(np.abs(err_after))),
        new_params, choked, notes)


# --- the chamber mass balance -------------------------------------------------------------


@dataclass(frozen=True)
class ChamberRecord:
    """A record of the cylinder chamber, on one time base (arrays of shape (n,)).

    Attributes
    ----------
    t_s : numpy.ndarray
        Time [s], ascending.
    chamber_pressure_pa : numpy.ndarray
        Chamber pressure, gauge [Pa].
    volume_m3 : numpy.ndarray
        Chamber volume [m^3] (:func:`chamber_volume_m3` from the piston position).
    opening_m : numpy.ndarray
        The opening the orifice sees [m]: the spool position (instantaneous; with windows
        much longer than a PWM period the period average x_avg gives the same integral).
    supply_pressure_pa : numpy.ndarray
        Supply pressure, gauge [Pa].
    """

    t_s: np.ndarray
    chamber_pressure_pa: np.ndarray
    volume_m3: np.ndarray
    opening_m: np.ndarray
    supply_pressure_pa: np.ndarray


@dataclass(frozen=True)
class ChamberEstimate:
    """Result of :func:`identify_from_chamber`.

    Attributes
    ----------
    estimate : OrificeEstimate
    bleed_discharge_area_m2 : float
        C_d A of the bleed to atmosphere [m^2] (identified, or as given).
    bleed_identified : bool
    polytropic_exponent : float
        n used in (C2) [1].
    window_s : float
        Length of the integration windows [s].
    error_before_pct, error_after_pct : float
        Rms of the windowed mass balance residual with the prior and the identified
        product, in % of the largest windowed valve flow (with the same bleed).
    params : ValveParameters
        The parameter set with the identified C_A.
    """

    estimate: OrificeEstimate
    bleed_discharge_area_m2: float
    bleed_identified: bool
    polytropic_exponent: float
    window_s: float
    error_before_pct: float
    error_after_pct: float
    params: ValveParameters

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return {'source': 'chamber', **self.estimate.as_dict(),
                'bleed_discharge_area_m2': self.bleed_discharge_area_m2,
                'bleed_identified': self.bleed_identified,
                'polytropic_exponent': self.polytropic_exponent, 'window_s': self.window_s,
                'flow_error_pct_of_full_flow': {'before': {'rms': self.error_before_pct},
                                                'after': {'rms': self.error_after_pct}}}


def chamber_volume_m3(position_m: np.ndarray, bore_diameter_m: float,
                      dead_volume_m3: float) -> np.ndarray:
    """Chamber volume V = V_0 + A_p y [m^3] (C1), A_p = pi D^2 / 4."""
    area = math.pi * bore_diameter_m ** 2 / 4.0
    return dead_volume_m3 + area * np.asarray(position_m, dtype=float)


def opening_from_duty(duty_map: DutyMap, duty: np.ndarray, pwm_frequency_hz: float,
                      supply_pressure_pa: float) -> np.ndarray:
    """x_avg [m] the map gives for each duty, when a record has the duty but no spool
    position (then the windows must be long against the PWM period and the valve's step
    response)."""
    stroke = float(ValveParameters.from_dict(duty_map.parameters).stroke_m)
    return stroke * np.array([map_flow_position(duty_map, float(x), pwm_frequency_hz,
                                                supply_pressure_pa) for x in duty])


def _orifice_unit(p_up: np.ndarray, p_down: np.ndarray, temp: float, r_gas: float,
                  gamma: float) -> np.ndarray:
    """eq. (12) per unit C_d C_A and unit opening, flow from the higher pressure to the
    lower, signed positive from ``p_up`` to ``p_down`` (absolute pressures)."""
    out = np.empty(p_up.shape)
    for i, (a, b) in enumerate(zip(p_up.tolist(), p_down.tolist())):
        out[i] = mass_flow_absolute(1.0, a, b, 1.0, 1.0, temp, r_gas, gamma) if a >= b \
            else -mass_flow_absolute(1.0, b, a, 1.0, 1.0, temp, r_gas, gamma)
    return out


def _window_sums(record: ChamberRecord, params: ValveParameters, temp: float,
                 polytropic_exponent: float, window_s: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Window sums of the mass balance (C2): the stored mass change 1/(R T) sum(V dp / n +
    p dV) [kg], the valve's sum(x phi_v dt) per unit C_d C_A and the bleed's sum(phi_b dt)
    per unit C_d A, with midpoint values on each sample interval; and each window's length
    [s]. Checks the record (FlowIdentificationError)."""
    arrays = [np.asarray(a, dtype=float) for a in (
        record.t_s, record.chamber_pressure_pa, record.volume_m3, record.opening_m,
        record.supply_pressure_pa)]
    names = ('t_s', 'chamber_pressure_pa', 'volume_m3', 'opening_m', 'supply_pressure_pa')
    n = arrays[0].size
    for name, a in zip(names, arrays):
        if a.shape != (n,):
            raise FlowIdentificationError(f'{name} has shape {a.shape}, expected ({n},)')
        if not np.all(np.isfinite(a)):
            raise FlowIdentificationError(f'{name} has non-finite values')
    t, pg, vol, x, psg = arrays
    if n < 3 or np.any(np.diff(t) <= 0.0):
        raise FlowIdentificationError('t_s must hold at least 3 strictly ascending times')
    r_gas, gamma = params.gas_constant_j_per_kg_k, params.heat_capacity_ratio
    p = pg + ATMOSPHERIC_PRESSURE_PA
    ps = psg + ATMOSPHERIC_PRESSURE_PA
    # midpoint values on each sample interval
    pm, vm = 0.5 * (p[1:] + p[:-1]), 0.5 * (vol[1:] + vol[:-1])
    xm, psm = 0.5 * (x[1:] + x[:-1]), 0.5 * (ps[1:] + ps[:-1])
    dt = np.diff(t)
    lhs = (vm * np.diff(p) / polytropic_exponent + pm * np.diff(vol)) / (r_gas * temp)
    phi_v = np.maximum(xm, 0.0) * _orifice_unit(psm, pm, temp, r_gas, gamma) * dt
    phi_b = np.maximum(_orifice_unit(pm, np.full_like(pm, ATMOSPHERIC_PRESSURE_PA), temp,
                                     r_gas, gamma), 0.0) * dt
    # sum over windows
    edges = np.floor((0.5 * (t[1:] + t[:-1]) - t[0]) / window_s).astype(int)
    n_win = int(edges[-1]) + 1
    y_w = np.bincount(edges, lhs, n_win)
    v_w = np.bincount(edges, phi_v, n_win)
    b_w = np.bincount(edges, phi_b, n_win)
    return y_w, v_w, b_w, np.bincount(edges, dt, n_win)


def chamber_valve_flow(record: ChamberRecord, params: ValveParameters, *,
                       bleed_discharge_area_m2: float, temperature_k: float | None = None,
                       polytropic_exponent: float = 1.0, window_s: float = 0.05
                       ) -> tuple[np.ndarray, np.ndarray]:
    """The mass flow the valve delivered into the chamber, window by window [kg/s].

    The chamber as a flow meter: the stored mass change plus what the bleed let out (C2,
    C3), over each window, divided by its length::

        m_valve = (1/(R T) sum(V dp / n + p dV) + B sum(phi_b dt)) / window

    (the same sums :func:`identify_from_chamber` fits; ``record.opening_m`` is not used).
    ``params`` gives R, T (default) and gamma.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        Start time of each window [s] and the window's mean valve flow [kg/s].

    Raises
    ------
    FlowIdentificationError
        Arrays of unequal length, non-finite values or fewer than 3 ascending times.
    """
    temp = float(params.supply_temperature_k if temperature_k is None else temperature_k)
    y_w, _, b_w, length = _window_sums(record, params, temp, polytropic_exponent, window_s)
    t0 = float(np.asarray(record.t_s, dtype=float)[0])
    starts = t0 + window_s * np.arange(y_w.size)
    with np.errstate(invalid='ignore', divide='ignore'):
        flow = (y_w + float(bleed_discharge_area_m2) * b_w) / length
    keep = length > 0.0
    return starts[keep], flow[keep]


def identify_from_chamber(record: ChamberRecord, params: ValveParameters, *,
                          temperature_k: float | None = None,
                          polytropic_exponent: float = 1.0,
                          bleed_discharge_area_m2: float | None = None,
                          window_s: float = 0.05, confidence: float = 0.95
                          ) -> ChamberEstimate:
    """Identify C_d C_A from the chamber's mass balance (C2).

    Over each window [t_a, t_b] of length ``window_s``::

        1/(R T) sum(V dp / n + p dV) = P sum(x phi_v dt) - B sum(phi_b dt)

    with midpoint values on each sample interval, phi_v = eq. (12) per unit C_d C_A from
    supply to chamber (negative if the chamber is above the supply), phi_b = eq. (12) per
    unit C_d A from the chamber to atmosphere. P = C_d C_A and (unless given) B = (C_d A) of
    the bleed come from linear least squares over the windows; the pressure enters as its
    increments only, so its noise averages out instead of being differentiated.

    Parameters
    ----------
    record : ChamberRecord
    params : ValveParameters
        Start set (C_d kept, T, R, gamma).
    temperature_k : float, optional
        Gas temperature T [K] (default: the set's supply temperature; the chamber gas is
        taken at the supply temperature).
    polytropic_exponent : float
        n of (C2) [1]: 1 isothermal (slow motions, long records), 1.4 adiabatic; the
        suite's plant uses its ``polytropic_exponent`` (1.2 by default).
    bleed_discharge_area_m2 : float, optional
        C_d A of a bleed to atmosphere [m^2]; None identifies it with the valve (it needs
        windows with the valve closed and the chamber above atmosphere); 0 for none.
    window_s : float
        Window length [s]; a few PWM periods.
    confidence : float

    Raises
    ------
    FlowIdentificationError
        Arrays of unequal length, non-finite values, too few windows or no valve flow.
    """
    temp = float(params.supply_temperature_k if temperature_k is None else temperature_k)
    y_w, v_w, b_w, _ = _window_sums(record, params, temp, polytropic_exponent, window_s)
    n_win = y_w.size
    if not np.any(v_w != 0.0):
        raise FlowIdentificationError('the valve never opens against a pressure difference '
                                      'in the record: nothing to identify')
    if bleed_discharge_area_m2 is None:
        a = np.column_stack([v_w, -b_w])
        if n_win < 3:
            raise FlowIdentificationError(f'{n_win} windows of {window_s:g} s: too few')
        coef, *_ = np.linalg.lstsq(a, y_w, rcond=None)
        res = y_w - a @ coef
        dof = n_win - 2
        cov = float(res @ res) / dof * np.linalg.inv(a.T @ a)
        product, bleed = float(coef[0]), float(coef[1])
        half = _t_quantile(confidence, dof) * math.sqrt(max(cov[0, 0], 0.0))
        interval = (product - half, product + half)
    else:
        bleed = float(bleed_discharge_area_m2)
        product, interval = _through_origin(y_w + bleed * b_w, v_w, confidence)
    new_params = with_orifice_product(params, product)
    prior = params.discharge_coefficient * params.orifice_area_gradient_m
    scale = float(np.max(np.abs(v_w))) * product
    before = (y_w - prior * v_w + bleed * b_w) / scale * 100.0
    after = (y_w - product * v_w + bleed * b_w) / scale * 100.0
    est = OrificeEstimate(product, interval, confidence, prior, params.discharge_coefficient,
                          new_params.orifice_area_gradient_m, temp, n_win)
    return ChamberEstimate(est, bleed, bleed_discharge_area_m2 is None, polytropic_exponent,
                           window_s, float(np.sqrt(np.mean(before ** 2))),
                           float(np.sqrt(np.mean(after ** 2))), new_params)


def _find_topic(data: dict[str, Any], suffix: str, path: str) -> Any:
    hits = [k for k in data if k == '/' + suffix or k.endswith('/' + suffix)]
    if len(hits) != 1:
        raise FlowIdentificationError(
            f'{path}: needs exactly one topic ending in {suffix!r}, found {hits or "none"}')
    return data[hits[0]]


def chamber_record_from_bag(path: str | os.PathLike[str], *, bore_diameter_m: float,
                            dead_volume_m3: float) -> ChamberRecord:
    """The chamber record of a suite bag (``valve_recorder`` or ``ros2 bag record``).

    Reads ``valve/state`` (spool position and supply pressure, 1 kHz: the opening the
    cylinder node feeds to its plant), ``valve/output_pressure`` (the chamber pressure,
    absolute, from the cylinder node, 200 Hz) and ``cylinder/joint_states`` (piston
    position, 200 Hz), all on their header stamps. The time base is the valve state's
    (the opening switches within a PWM period; pressure and position are smooth and are
    interpolated linearly onto it), within the span all three topics cover. A namespaced
    bag (``/left/valve/state``) is read when it holds one valve.

    The bag does not carry the cylinder's geometry: the bore and the dead volume (the
    cylinder node's ``bore_diameter_m`` and ``dead_volume_m3``) are arguments; the
    polytropic exponent and the bleed are arguments of :func:`identify_from_chamber`.

    Raises
    ------
    FlowIdentificationError
        A topic missing or ambiguous, or the topics not overlapping in time.
    """
    from ..recording import load_bag
    spath = str(path)
    data = load_bag(path)
    from ..interface import TOPIC_JOINT_STATES, TOPIC_OUTPUT_PRESSURE, TOPIC_STATE
    pres = _find_topic(data, TOPIC_OUTPUT_PRESSURE, spath)
    joint = _find_topic(data, TOPIC_JOINT_STATES, spath)
    state = _find_topic(data, TOPIC_STATE, spath)
    # seconds from the first valve state, formed from integer ns (epoch seconds in
    # float64 resolve only 0.24 us)
    origin = int(state.stamp_ns[0]) if len(state) else 0
    tp, tj, ts = ((topic.stamp_ns - origin) * 1e-9 for topic in (pres, joint, state))
    raw_pos = joint['position']
    if raw_pos.dtype == object:   # ragged float64[]: one array per message
        pos = np.array([float(v[0]) if len(v) else math.nan for v in raw_pos])
    else:
        pos = np.asarray(raw_pos, float).reshape(raw_pos.shape[0], -1)[:, 0]
    good = np.isfinite(pos)
    tj, pos = tj[good], pos[good]
    if min(tp.size, tj.size, ts.size) < 2:
        raise FlowIdentificationError(f'{spath}: fewer than 2 messages on a needed topic')
    lo, hi = max(tp[0], tj[0], ts[0]), min(tp[-1], tj[-1], ts[-1])
    keep = (ts >= lo) & (ts <= hi)
    if np.count_nonzero(keep) < 3:
        raise FlowIdentificationError(f'{spath}: pressure, joint states and valve state do '
                                      'not overlap in time')
    t = ts[keep]
    p_gauge = np.interp(t, tp, np.asarray(pres['fluid_pressure'], float)) \
        - ATMOSPHERIC_PRESSURE_PA
    y = np.interp(t, tj, pos)
    x = np.asarray(state['spool_position'], float)[keep]
    sup = np.asarray(state['supply_pressure'], float)[keep]
    volume = chamber_volume_m3(y, bore_diameter_m, dead_volume_m3)
    return ChamberRecord(t - t[0], p_gauge, volume, x, sup)


def recalibrated_map(duty_map: DutyMap, params: ValveParameters, source: str) -> DutyMap:
    """The map with the orifice constants of ``params`` and its curves unchanged.

    x_avg(d) is a property of the spool dynamics, which do not depend on C_d or C_A (eq. 12
    is downstream of the spool: no flow force in the model), so a map whose parameters
    differ only in C_d, C_A is the same map; this saves a rebuild (minutes) and lets
    ``flow_to_duty`` restart at once with the calibrated flow scale.

    Raises
    ------
    FlowIdentificationError
        If ``params`` differs from the map's parameters in anything but C_d and C_A.
    """
    import dataclasses
    old = ValveParameters.from_dict(duty_map.parameters)
    same = params.replace(discharge_coefficient=old.discharge_coefficient,
                          orifice_area_gradient_m=old.orifice_area_gradient_m)
    if same != old:
        raise FlowIdentificationError('the parameter set differs from the map\'s beyond '
                                      'C_d and C_A: rebuild the map with valve_map')
    note = (f'orifice constants from {source} (valve_flow_check): C_d = '
            f'{params.discharge_coefficient:g}, C_A = {params.orifice_area_gradient_m:.6g}; '
            'curves copied (independent of C_d, C_A)')
    return dataclasses.replace(duty_map, parameters=params.to_dict(),
                               notes=[*duty_map.notes, note])


def write_parameters(params: ValveParameters, path: str | os.PathLike[str],
                     header: str = '') -> Path:
    """Write a parameter YAML that :func:`valve_model_pkg.model.load_parameters` reads.

    The same layout as ``valve_identify``'s ``params.yaml`` (``ValveParameters.to_dict``
    through ``yaml.safe_dump``), with ``header`` as leading comment lines.
    """
    def clean(v: Any) -> Any:
        if isinstance(v, dict):
            return {k: clean(w) for k, w in v.items()}
        if isinstance(v, (np.floating, np.integer)):
            return v.item()
        return v
    body = yaml.safe_dump(clean(params.to_dict()), sort_keys=False)
    lines = ''.join(f'# {line}\n' for line in header.splitlines())
    out = Path(path)
    out.write_text(lines + body, encoding='utf-8')
    return out
