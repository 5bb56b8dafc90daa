"""Spool mechanics: eqs. (9)-(11), end stops, Coulomb friction.

eq. (9):  m_s x'' + b x' + k (x + delta) = F_m + F_prs
eq. (10): F_prs = (A_1 - A_2) P_sup + (A_3 - A_4) P_out   (gauge pressures)
eq. (11): the same as two first-order state equations.

End stops at x = 0 (closed) and x = x_max (open): the spool rests against a stop while the
net force without damping ("active force" F_m - k (x + delta) + F_prs) pushes it into the
stop, or pulls away by no more than the Coulomb friction F_c (stiction), and leaves it when
the force reverses. An impact is plastic (the paper) or, with ``end_stop_bounce``, reverses
the velocity with the coefficient of restitution e.
"""
from __future__ import annotations

import numpy as np
from .scalars import kernel_scalar

from .parameters import ValveParameters

__all__ = [
    'MODE_FREE', 'MODE_CLOSED', 'MODE_OPEN', 'MODE_STUCK',
    'pressure_force', 'active_force',
]

#: Mechanical modes of the kernel.
MODE_FREE = 0
MODE_CLOSED = 1
MODE_OPEN = 2
MODE_STUCK = 3  # held mid-stroke by static friction

#: Impact speed below which a bouncing spool is taken to have settled, m/s.
SETTLE_SPEED_M_S = 1e-3


@kernel_scalar
def _pressure_force(a_1: float, a_2: float, a_3: float, a_4: float,
                    p_sup: float, p_out: float) -> float:
    return (a_1 - a_2) * p_sup + (a_3 - a_4) * p_out  # eq. (10)


@kernel_scalar
def _active_force(f_m: float, k: float, x: float, delta: float, f_prs: float) -> float:
    # eq. (9) right-hand side minus damping: magnetic + pressure - spring (with pre-tension)
    return f_m - k * (x + delta) + f_prs


@kernel_scalar
def _acceleration(f_active: float, v: float, b: float, f_c: float, m: float) -> float:
    """eq. (11) with Coulomb friction; stiction when v == 0 and |F| <= F_c."""
    if f_c > 0.0:
        if v > 0.0:
            f_active -= f_c
        elif v < 0.0:
            f_active += f_c
        elif abs(f_active) <= f_c:
            return 0.0
        elif f_active > 0.0:
            f_active -= f_c
        else:
            f_active += f_c
    return (f_active - b * v) / m


@kernel_scalar
def _leave_margin(mode: int, f_active: float, f_c: float) -> float:
    """Positive when a held spool starts to move (mode is the current, held mode)."""
    if mode == MODE_CLOSED:
        return f_active - f_c
    if mode == MODE_OPEN:
        return -f_active - f_c
    return abs(f_active) - f_c  # MODE_STUCK


def pressure_force(params: ValveParameters, supply_pressure_pa: float | np.ndarray,
                   output_pressure_pa: float | np.ndarray = 0.0) -> np.ndarray:
    """Pressure force on the spool in N, eq. (10) (gauge pressures in Pa).

    Positive opens the valve. With the paper's areas A_1 < A_2, so the supply pressure
    pushes the valve closed; A_3 = A_4 cancels the output pressure.
    """
    return ((params.area_a1_m2 - params.area_a2_m2) * np.asarray(supply_pressure_pa, float)
            + (params.area_a3_m2 - params.area_a4_m2) * np.asarray(output_pressure_pa, float))


def active_force(params: ValveParameters, magnetic_force_n: float | np.ndarray,
                 position_m: float | np.ndarray,
                 supply_pressure_pa: float = 0.0, output_pressure_pa: float = 0.0
                 ) -> np.ndarray:
    """Net force on the spool without damping and friction in N (eq. (9) rearranged)."""
    return (np.asarray(magnetic_force_n, float)
            - params.spring_stiffness_n_per_m * (np.asarray(position_m, float)
                                                 + params.spring_pretension_m)
            + pressure_force(params, supply_pressure_pa, output_pressure_pa))
