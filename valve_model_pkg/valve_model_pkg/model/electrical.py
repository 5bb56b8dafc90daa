"""Coil electrical state equation: eqs. (5) and (7), with the optional electrical effects.

Circuit (terminal voltage V, terminal current i)::

    V --[ R(T) ]--+--[ L_leak ]--[ L(x), saturating ]--+
                  |                                    |
                  +------------[ R_e = 1/G_e ]---------+

The inductive branch carries the magnetising current i_m, the state of the model; the
eddy-loss resistor R_e shunts the whole inductive branch (this keeps the model at three
mechanical/electrical states, with no stiff extra state). With G_e = 0, L_leak = 0 and no
saturation the equation is the paper's eq. (7) exactly:

    di/dt = (V - R i) / L - 2 mu_r L x_dot i / (N^2 A_e mu_c).

``coil_heating`` raises R = R_0 (1 + alpha dT) with copper alpha = 0.00393 1/K, and dT
obeys tau_th d(dT)/dt = R_th P - dT with the copper loss P = R i^2.

Emulator form ``eddy_ladder`` (``EMULATOR_EFFECTS``; not an identification candidate,
written independently of the eddy resistor above). Eddy currents in a solid core delay
part of the flux (diffusion); a one-rung Foster ladder models it with two time
constants. The magnetising inductance is split into a fast part a L(x), a = 1/(1 + r),
carrying i_m, in series with a slow part b L(x), b = r/(1 + r), carrying i_b and shunted
by the eddy path R_b (which carries i_m - i_b)::

    V --[ R(T) ]--+--[ L_leak ]--[ a L(x) ]--+--[ b L(x) ]--+
                  |                          +--[  R_b   ]--+
                  +------------[ R_e = 1/G_e ]--------------+

    v_br = (V - R i_m) / (1 + R G_e),     e_b = R_b (i_m - i_b),
    (L_leak + a dlambda/di(i_m)) di_m/dt = v_br - e_b - a dlambda/dx(i_m) x_dot,
    b dlambda/di(i_b) di_b/dt = e_b - b dlambda/dx(i_b) x_dot,
    F = a F_law(i_m) + b F_law(i_b)     (co-energy of both parts).

Its impedance at rest, s a L + s b L R_b / (R_b + s b L), has no resistive path at high
frequency (the candidate's s L R_e / (R_e + s L) tends to R_e): a voltage step makes the
current start at slope V / (a L) with no jump, then follow two time constants. The
candidate is the limit of a fully shunted inductance (a = 0), which the ladder excludes
(r finite). r = 0 means off (i_b stays 0).
"""
from __future__ import annotations

from .scalars import kernel_scalar

from .magnetics import (
    _coefficients, _flux_partials, _inductance, _inductance_slope, _law_partials,
)
from .parameters import ValveParameters

__all__ = ['COPPER_ALPHA_PER_K', 'coil_resistance', 'current_derivative']

#: Temperature coefficient of copper resistance, 1/K.
COPPER_ALPHA_PER_K = 0.00393


@kernel_scalar
def _resistance(r_0: float, d_temp: float) -> float:
    if d_temp == 0.0:
        return r_0  # r_0 (1 + alpha 0) exactly
    return r_0 * (1.0 + COPPER_ALPHA_PER_K * d_temp)


@kernel_scalar
def _current_derivative(v: float, i_m: float, x_dot: float, ind: float, slope: float,
                        r: float, g_e: float, l_leak: float, beta: float
                        ) -> tuple[float, float]:
    """Return (di_m/dt, terminal current) for terminal voltage ``v``.

    An effect at its neutral value (G_e = 0, L_leak = 0) and a held spool (x_dot = 0) skip
    operations that are exact identities (division by 1 + R 0, adding 0, subtracting
    0 x_dot), so the result is the full expression's to the last bit, without its cost.
    """
    # KVL, eq. (5): V = R i + d lambda_total / dt, with i = i_m + G_e v_branch
    if g_e == 0.0:
        v_branch = v - r * i_m
    else:
        v_branch = (v - r * i_m) / (1.0 + r * g_e)
    dl_di, dl_dx = _flux_partials(i_m, ind, slope, beta)
    # eq. (7) generalised: the motional EMF dl_dx * x_dot is eq. (6)'s i dL/dt
    emf = v_branch if x_dot == 0.0 else v_branch - dl_dx * x_dot
    di = emf / (dl_di if l_leak == 0.0 else l_leak + dl_di)
    if g_e == 0.0:
        return di, i_m
    return di, i_m + g_e * v_branch


@kernel_scalar
def _ladder_derivatives(v: float, i_m: float, i_b: float, x_dot: float, ind: float,
                        slope: float, r: float, g_e: float, l_leak: float, beta: float,
                        lam_s: float, ratio: float, r_b: float
                        ) -> tuple[float, float, float]:
    """(di_m/dt, di_b/dt, terminal current) with the emulator forms (module docstring).

    ``ratio`` = r of ``eddy_ladder`` (0: no slow part, i_b ignored), ``r_b`` its shunt
    resistance (ohm), ``lam_s`` the ``saturation_tanh`` flux linkage (0: the candidate's
    law with ``beta``), the rest as :func:`_current_derivative`.
    """
    v_branch = (v - r * i_m) / (1.0 + r * g_e)
    a = 1.0 / (1.0 + ratio)
    dl_di, dl_dx = _law_partials(i_m, ind, slope, beta, lam_s)
    if ratio == 0.0:
        di = (v_branch - dl_dx * x_dot) / (l_leak + dl_di)
        return di, 0.0, i_m + g_e * v_branch
    b = ratio * a
    e_b = r_b * (i_m - i_b)
    di = (v_branch - e_b - a * dl_dx * x_dot) / (l_leak + a * dl_di)
    db_di, db_dx = _law_partials(i_b, ind, slope, beta, lam_s)
    dib = (e_b - b * db_dx * x_dot) / (b * db_di)
    return di, dib, i_m + g_e * v_branch


@kernel_scalar
def _temperature_derivative(d_temp: float, i_t: float, r: float, r_th: float,
                            tau_th: float) -> float:
    if r_th == 0.0 and d_temp == 0.0:
        return 0.0  # (0 - 0) / tau_th exactly: no heating, nothing to cool
    return (r_th * r * i_t * i_t - d_temp) / tau_th


def coil_resistance(params: ValveParameters, temperature_rise_k: float = 0.0) -> float:
    """Coil resistance in ohm at ``temperature_rise_k`` above the reference temperature."""
    return float(params.coil_resistance_ohm * (1.0 + COPPER_ALPHA_PER_K * temperature_rise_k))


def current_derivative(params: ValveParameters, voltage_v: float, current_a: float,
                       position_m: float, velocity_m_s: float,
                       temperature_rise_k: float = 0.0) -> tuple[float, float]:
    """Time derivative of the magnetising current, eq. (7) (with the enabled effects).

    Parameters
    ----------
    params : ValveParameters
    voltage_v : float
        Terminal voltage V in V.
    current_a : float
        Magnetising current i_m in A (equals the terminal current without eddy currents).
    position_m, velocity_m_s : float
        Spool position x (m) and velocity x_dot (m/s).
    temperature_rise_k : float
        Coil temperature above the reference, K (coil_heating).

    Returns
    -------
    tuple of float
        (di_m/dt in A/s, terminal current in A).
    """
    k_l, l_0, b_2 = _coefficients(params)
    ind = _inductance(position_m, k_l, l_0, b_2)
    slope = _inductance_slope(ind, k_l, b_2)
    r = _resistance(params.coil_resistance_ohm, temperature_rise_k)
    di, i_t = _current_derivative(voltage_v, current_a, velocity_m_s, ind, slope, r,
                                  params.eddy_conductance_s, params.leakage_inductance_h,
                                  params.saturation_coefficient_per_a)
    return float(di), float(i_t)
