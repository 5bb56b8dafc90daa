"""Magnetic circuit: equivalent length, inductance L(x), its slope, flux and force.

Paper eqs. (1)-(4), (6) and (8). The compiled kernel uses the scalar ``_...`` functions
(plain Python, compiled into the kernel: model/scalars.py); the public functions take a
:class:`ValveParameters` and numpy arrays.

With the ``magnetic_saturation`` effect (beta = 1/i_sat > 0) the flux linkage is
lambda(x, i) = L(x) i / (1 + beta |i|) and the force is the co-energy derivative
F = dL/dx * (u - ln(1 + u)) / beta^2 with u = beta |i|, which tends to eq. (8),
F = (1/2) dL/dx i^2 = L^2 i^2 / (N^2 A_e mu_0), as beta -> 0 (beta = 0 is eq. (8) exactly).

Emulator form ``saturation_tanh`` (``EMULATOR_EFFECTS``; not an identification candidate,
written independently of the law above so that an emulated saturation is not the
candidate's own equation). A fixed saturation flux linkage lambda_s = N B_sat A_e::

    lambda(x, i) = lambda_s tanh(u),   u = L(x) i / lambda_s,
    d lambda / d i = L(x) sech^2(u),   d lambda / d x = dL/dx i sech^2(u),
    F = dL/dx (lambda_s / L)^2 (u tanh u - ln cosh u)    (co-energy derivative).

It differs from the candidate in shape and in its x dependence: the incremental
inductance falls quadratically (sech^2(u) = 1 - u^2 + ...) instead of linearly
(1/(1 + beta i)^2 = 1 - 2 beta i + ...), and the knee current lambda_s / L(x) falls as the
gap closes, where the candidate's 1/beta is the same at every x. As lambda_s -> inf it
tends to eq. (5)/(8); lambda_s = 0 means off.
"""
from __future__ import annotations

import math

import numpy as np
from .scalars import kernel_scalar

from .parameters import ValveParameters

__all__ = [
    'MU_0',
    'equivalent_length',
    'inductance',
    'inductance_slope',
    'flux_linkage',
    'magnetic_force',
]

#: Permeability of free space, H/m.
MU_0 = 4.0e-7 * math.pi


def _coefficients(params: ValveParameters) -> tuple[float, float, float]:
    """Return (K_L, l_0, b_2) with L(x) = K_L / (l_0 - b_2 x)."""
    mu_c = params.relative_permeability * MU_0
    k_l = params.coil_turns ** 2 * params.core_area_m2 * mu_c  # N^2 A_e mu_c, eq. (4)
    l_0 = params.core_length_m + 2.0 * params.relative_permeability * params.total_air_gap_m
    b_2 = 2.0 * params.relative_permeability
    return k_l, l_0, b_2


@kernel_scalar
def _inductance(x: float, k_l: float, l_0: float, b_2: float) -> float:
    # eq. (4): L = N^2 A_e mu_c / (l_c + 2 mu_r (x_t - x))
    return k_l / (l_0 - b_2 * x)


@kernel_scalar
def _inductance_slope(ind: float, k_l: float, b_2: float) -> float:
    # eq. (6) divided by x_dot: dL/dx = 2 mu_r L^2 / (N^2 A_e mu_c)
    return ind * ind * b_2 / k_l


@kernel_scalar
def _flux_partials(i: float, ind: float, slope: float, beta: float) -> tuple[float, float]:
    """Return (d lambda / d i, d lambda / d x) of the magnetising flux linkage."""
    if beta == 0.0:
        return ind, slope * i  # eq. (5): lambda = L(x) i
    s = 1.0 / (1.0 + beta * abs(i))
    return ind * s * s, slope * i * s


@kernel_scalar
def _force(i: float, slope: float, beta: float) -> float:
    if beta == 0.0:
        return 0.5 * slope * i * i  # eq. (8), = L^2 i^2 / (N^2 A_e mu_0)
    u = beta * abs(i)
    if u < 1e-3:
        # series of u - ln(1 + u): avoids the cancellation at small currents
        g = u * u * (0.5 - u * (1.0 / 3.0 - 0.25 * u))
    else:
        g = u - math.log1p(u)
    return slope * g / (beta * beta)


@kernel_scalar
def _tanh_flux_partials(i: float, ind: float, slope: float, lam_s: float
                        ) -> tuple[float, float]:
    """(d lambda / d i, d lambda / d x) of the emulator's tanh law (``lam_s`` > 0, Wb)."""
    th = math.tanh(ind * i / lam_s)
    sech2 = 1.0 - th * th
    return ind * sech2, slope * i * sech2


@kernel_scalar
def _log_cosh(u: float) -> float:
    a = abs(u)
    # ln cosh u = a - ln 2 + ln(1 + e^-2a): no overflow of cosh at large a
    return a - math.log(2.0) + math.log1p(math.exp(-2.0 * a))


@kernel_scalar
def _tanh_force(i: float, ind: float, slope: float, lam_s: float) -> float:
    """Co-energy force of the tanh law, N: dL/dx (lambda_s/L)^2 (u tanh u - ln cosh u)."""
    u = ind * i / lam_s
    if abs(u) < 1e-3:
        # series (u^2/2 - u^4/4): avoids the cancellation at small currents
        u2 = u * u
        g = u2 * (0.5 - 0.25 * u2)
    else:
        g = u * math.tanh(u) - _log_cosh(u)
    k = lam_s / ind
    return slope * k * k * g


@kernel_scalar
def _law_partials(i: float, ind: float, slope: float, beta: float, lam_s: float
                  ) -> tuple[float, float]:
    """Flux partials of the law in force: the emulator's tanh law if set, else the candidate's."""
    if lam_s > 0.0:
        return _tanh_flux_partials(i, ind, slope, lam_s)
    return _flux_partials(i, ind, slope, beta)


@kernel_scalar
def _law_force(i: float, ind: float, slope: float, beta: float, lam_s: float) -> float:
    """Co-energy force of the law in force (see :func:`_law_partials`), N."""
    if lam_s > 0.0:
        return _tanh_force(i, ind, slope, lam_s)
    return _force(i, slope, beta)


def equivalent_length(params: ValveParameters, position_m: np.ndarray | float) -> np.ndarray:
    """Equivalent magnetic path length l_eq, eq. (2).

    Parameters
    ----------
    params : ValveParameters
    position_m : array_like
        Spool position x in m (0 = closed).

    Returns
    -------
    numpy.ndarray
        l_eq = l_c + 2 mu_r (x_t - x) in m, same shape as ``position_m``.
    """
    x = np.asarray(position_m, dtype=float)
    return params.core_length_m + 2.0 * params.relative_permeability * (
        params.total_air_gap_m - x)


def inductance(params: ValveParameters, position_m: np.ndarray | float) -> np.ndarray:
    """Coil inductance L(x) in H, eq. (4)."""
    k_l, _, _ = _coefficients(params)
    return k_l / equivalent_length(params, position_m)


def inductance_slope(params: ValveParameters, position_m: np.ndarray | float) -> np.ndarray:
    """dL/dx in H/m, eq. (6) divided by the spool velocity."""
    k_l, _, b_2 = _coefficients(params)
    ind = inductance(params, position_m)
    return ind * ind * b_2 / k_l


def flux_linkage(params: ValveParameters, current_a: np.ndarray | float,
                 position_m: np.ndarray | float) -> np.ndarray:
    """Magnetising flux linkage lambda(x, i) in Wb (eq. (3): L i = N phi; with saturation).

    The emulator's ``saturation_tanh`` form, when set, replaces the candidate's law.
    """
    i = np.asarray(current_a, dtype=float)
    lam_s = params.saturation_tanh_flux_linkage_wb
    if lam_s > 0.0:
        return lam_s * np.tanh(inductance(params, position_m) * i / lam_s)
    return inductance(params, position_m) * i / (
        1.0 + params.saturation_coefficient_per_a * np.abs(i))


def magnetic_force(params: ValveParameters, current_a: np.ndarray | float,
                   position_m: np.ndarray | float) -> np.ndarray:
    """Magnetic attraction force in N, eq. (8) (co-energy form with saturation).

    Parameters
    ----------
    params : ValveParameters
    current_a : array_like
        Magnetising current i in A.
    position_m : array_like
        Spool position x in m.

    Returns
    -------
    numpy.ndarray
        F_m = L(x)^2 i^2 / (N^2 A_e mu_0) when saturation is off; broadcast shape. The
        emulator's ``saturation_tanh`` form, when set, replaces the candidate's law.
    """
    i = np.asarray(current_a, dtype=float)
    slope = inductance_slope(params, position_m)
    lam_s = params.saturation_tanh_flux_linkage_wb
    if lam_s > 0.0:
        ind = inductance(params, position_m)
        u = ind * i / lam_s
        log_cosh = np.abs(u) - math.log(2.0) + np.log1p(np.exp(-2.0 * np.abs(u)))
        return slope * (lam_s / ind) ** 2 * (u * np.tanh(u) - log_cosh)
    beta = params.saturation_coefficient_per_a
    if beta == 0.0:
        return 0.5 * slope * i * i
    u = beta * np.abs(i)
    return slope * (u - np.log1p(u)) / (beta * beta)
