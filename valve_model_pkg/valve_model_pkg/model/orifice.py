"""Orifice mass flow, eq. (12): choked and subsonic branches.

Pressures at the interface are gauge (the shared data format); eq. (12) needs absolute
pressures, so ``atmospheric_pressure_pa`` is added.
"""
from __future__ import annotations

import math

import numpy as np
from .scalars import kernel_scalar

from .constants import ATMOSPHERIC_PRESSURE_PA
from .parameters import ValveParameters

__all__ = ['ATMOSPHERIC_PRESSURE_PA', 'critical_pressure_ratio', 'mass_flow_absolute',
           'orifice_mass_flow', 'orifice_mass_flow_scalar']


def critical_pressure_ratio(gamma: float = 1.4) -> float:
    """(2 / (gamma + 1))^(gamma / (gamma - 1)); 0.528 for air."""
    return (2.0 / (gamma + 1.0)) ** (gamma / (gamma - 1.0))


@kernel_scalar
def _mass_flow(x: float, p_up: float, p_down: float, c_d: float, c_a: float,
               temp: float, r_gas: float, gamma: float) -> float:
    """eq. (12) for absolute pressures p_up >= p_down > 0; returns kg/s."""
    if p_up <= 0.0 or x <= 0.0:
        return 0.0
    ratio = p_down / p_up
    crit = (2.0 / (gamma + 1.0)) ** (gamma / (gamma - 1.0))
    base = c_d * c_a * x * p_up / math.sqrt(temp)
    if ratio <= crit:
        # choked: 0.0405 for air = sqrt(gamma/R (2/(gamma+1))^((gamma+1)/(gamma-1)))
        c_chk = math.sqrt(gamma / r_gas
                          * (2.0 / (gamma + 1.0)) ** ((gamma + 1.0) / (gamma - 1.0)))
        return c_chk * base
    # subsonic: exponent 2/gamma (the paper prints gamma/gamma, a typo)
    term = ratio ** (2.0 / gamma) - ratio ** ((gamma + 1.0) / gamma)
    return base * math.sqrt(max(0.0, 2.0 * gamma / (r_gas * (gamma - 1.0)) * term))


#: eq. (12) for one point with absolute pressures p_up >= p_down and explicit coefficients:
#: ``mass_flow_absolute(x, p_up_pa, p_down_pa, c_d, c_a_m, temperature_k,
#: gas_constant_j_per_kg_k, heat_capacity_ratio) -> kg/s`` (0 for x <= 0). For other
#: orifices of the same law (the cylinder's bleed); plain Python (model/scalars.py).
mass_flow_absolute = _mass_flow


def orifice_mass_flow_scalar(position_m: float, supply_pressure_pa: float,
                             output_pressure_pa: float, params: ValveParameters) -> float:
    """:func:`orifice_mass_flow` for one point without numpy broadcasting, kg/s.

    Gauge pressures in Pa (reversed flow negative), as :func:`orifice_mass_flow`; the
    simulator node calls this at 1 kHz.
    """
    up = supply_pressure_pa + ATMOSPHERIC_PRESSURE_PA
    down = output_pressure_pa + ATMOSPHERIC_PRESSURE_PA
    sign = 1.0
    if down > up:
        up, down, sign = down, up, -1.0
    return sign * float(_mass_flow(position_m, up, down, params.discharge_coefficient,
                                   params.orifice_area_gradient_m, params.supply_temperature_k,
                                   params.gas_constant_j_per_kg_k, params.heat_capacity_ratio))


def orifice_mass_flow(position_m: float | np.ndarray,
                      supply_pressure_pa: float | np.ndarray,
                      output_pressure_pa: float | np.ndarray = 0.0,
                      params: ValveParameters | None = None,
                      atmospheric_pressure_pa: float = ATMOSPHERIC_PRESSURE_PA
                      ) -> np.ndarray:
    """Air mass flow through the valve orifice, eq. (12).

    dm/dt = 0.0405 C_d C_A x P_sup / sqrt(T)                         if P_out/P_sup <= 0.528
    dm/dt = C_d C_A x P_sup / sqrt(T) * sqrt(2 gamma / (R (gamma - 1))
            * ((P_out/P_sup)^(2/gamma) - (P_out/P_sup)^((gamma+1)/gamma)))   otherwise.

    The paper prints the first subsonic exponent as gamma/gamma; that is a typo for
    2/gamma (the standard orifice equation; with gamma/gamma = 1 the two branches would not
    meet at the critical ratio). 0.0405 is the choked constant for air,
    sqrt(gamma/R (2/(gamma+1))^((gamma+1)/(gamma-1))) with R = 287 J/(kg K), gamma = 1.4;
    it is computed from the parameters (0.04042 for air), so the branches join
    continuously at the critical ratio (2/(gamma+1))^(gamma/(gamma-1)) = 0.528.

    Parameters
    ----------
    position_m : array_like
        Spool position in m; the paper uses the PWM-period average x_bar. Negative values
        are treated as closed.
    supply_pressure_pa, output_pressure_pa : array_like
        Gauge pressures in Pa. If the output pressure exceeds the supply pressure the flow
        reverses and is returned negative (same equation, roles swapped).
    params : ValveParameters, optional
        C_d, C_A, T, R, gamma (default: the packaged parameter set).
    atmospheric_pressure_pa : float
        Added to the gauge pressures, Pa.

    Returns
    -------
    numpy.ndarray
        Mass flow in kg/s, broadcast shape of the inputs (0-d array for scalars).
    """
    if params is None:
        params = ValveParameters()
    x, p_s, p_o = np.broadcast_arrays(np.asarray(position_m, float),
                                      np.asarray(supply_pressure_pa, float)
                                      + atmospheric_pressure_pa,
                                      np.asarray(output_pressure_pa, float)
                                      + atmospheric_pressure_pa)
    out = np.empty(x.shape)
    flat_out = out.reshape(-1)
    for n, (xi, ps, po) in enumerate(zip(x.reshape(-1), p_s.reshape(-1), p_o.reshape(-1))):
        sign = 1.0
        if po > ps:
            ps, po, sign = po, ps, -1.0
        flat_out[n] = sign * _mass_flow(float(xi), float(ps), float(po),
                                        params.discharge_coefficient,
                                        params.orifice_area_gradient_m,
                                        params.supply_temperature_k,
                                        params.gas_constant_j_per_kg_k,
                                        params.heat_capacity_ratio)
    return out
