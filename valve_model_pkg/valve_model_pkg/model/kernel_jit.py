"""The valve model's integrator, compiled by numba (``cache=True``).

Method
------
Classical fixed-step Runge-Kutta 4 on the hybrid system, with every discontinuity handled
exactly instead of being smeared by a step:

* **Scheduled edges** (main PWM rising/falling edges and period starts, chopper switch-off,
  controller and comparator ticks, the peak timer, output sample times) are known in
  advance, so every step is shortened to land exactly on the next one; the interval up to
  it is split into equal steps no longer than ``h_free`` (spool moving) or ``h_stop``
  (spool held). Between edges the right-hand side is smooth, so RK4 keeps its 4th order.
* **Level events**: the current reaching a level at an instant no schedule knows (the
  ``threshold`` peak end; the zero that ends a Zener, diode or blocked fast-decay phase)
  is located by regula falsi (Illinois) on redone steps; the step ends there and the
  drive switches (``_locate_level``). Only electronics with such a form look for them.
* **End-stop impacts** (x reaches 0 or x_max) are located inside the step on the cubic
  Hermite interpolant of x (x and x_dot at both ends are known), the step is redone up to
  the impact, x is set onto the stop and the velocity to 0 (plastic, the paper) or to
  -e x_dot (``end_stop_bounce``).
* **Leaving a stop** (the net force changes sign) and, with Coulomb friction, velocity
  reversals are located by regula falsi (Illinois) on redone steps. If a spool released
  from rest on a stop is back on that stop at the very start of its first free step (the
  margin was barely positive and falls at once, e.g. under the capacitor pulse at a falling
  edge: the lift is far below what the interpolant resolves), it stays on the stop for that
  step instead of being released again at the same instant.
* **Time always advances.** A pass of the main loop that does not advance time counts as
  a stall; after ``_STALL_LIMIT`` of them in a row the next step is forced (no release
  check, the mechanics frozen for one step if needed, pending events stepped past) and
  counted in ``d[D_N_FORCED]``. A correct kernel never gets there (the tests check 0); the
  guard exists so the real-time simulator node and the CAN emulator can never hang.
* While the spool rests on a stop, x and x_dot are frozen and only the coil (and
  temperature) states are integrated: L is constant there, the dynamics are a slow RL
  circuit (tau = L/R ~ 7-11 ms), so steps of ``h_stop`` = 100 us are ~1e-8 accurate and
  the chopper edges, not accuracy, set the step.

Why not an adaptive solver: the drive is a train of scheduled discontinuities (20 kHz
chopper), which make adaptive controllers reject and shrink steps at every edge; landing
on them with a fixed-step RK4 is cheaper and has no tolerance tuning. The convergence test
(halving both step sizes) checks the result.

Compilation: every function is ``njit(cache=True)``; the machine code is cached in
``__pycache__`` next to this file, so only the first process on a machine compiles; later
processes load it. Numba checks only this file's time stamp, so a change of a kernel source
elsewhere (the layout constants in kernel.py, the physics in electrical.py, ...) would keep
a stale cache: importing this module compares :func:`~valve_model_pkg.model.aot.kernel_key`
with the key the cache was built for and drops the cache when they differ. Functions that
allocate nothing are compiled without numba's reference counting (``_nrt=False``): they
only borrow the arrays of the entry point that calls them, which holds them for the whole
call, so counting references on every inner call (two atomic operations per array
argument) would buy nothing. The scalar physics functions of magnetics.py, electrical.py,
mechanics.py and orifice.py are plain Python (model/scalars.py) and registered with numba
here, before anything is compiled. The same functions are compiled ahead of time into an
extension module (model/aot_build.py), which serves every entry point of kernel.py without
numba; this module is imported only when that module is missing or stale (model/aot.py).
The layouts (``D_*``, ``P_*``, ``O_*``, ...) and the Python entry points are kernel.py's.

Reading order of the main loop (``_advance``): process the events due now, release a
held spool if its force margin is positive, take one RK4 step up to the next event, then
locate what happened inside it with the two compiled root finders: ``_free_step_events``
(end-stop impact on the Hermite interpolant, ``_impact``; velocity reversal under
friction, ``_reversal``) for a moving spool and ``_release`` (Illinois on the held force
margin) for a held one.

Data layout (all float64 arrays, which the cached and the ahead-of-time code take alike):
``p`` derived parameters (``_derive``), ``e`` electronics (``electronics.E_*``), ``y``
the continuous state ``[i_m, x, x_dot, dT, q]`` (q = integral of x, for period averages;
the integrals of the terminal current and voltage, for interval means, are integrated
with it but kept in ``d[D_QI]``, ``d[D_QV]``; no integral feeds back into the dynamics),
``d`` the discrete drive/mode state (``D_*``).

Emulator effect forms (``parameters.EMULATOR_EFFECTS``: ``saturation_tanh``,
``eddy_ladder``; equations in magnetics.py and electrical.py, docs/effects.md) are written
independently of the identification's candidates, so a valve emulated with them is not
the candidate's own equation. Their slow ladder current i_b is integrated with y like
the integrals (the 8th component of the step tuple) and kept in ``d[D_IB]``. With both
off (``p[P_EMU] == 0``) no function evaluates any of their terms (``_rk4_emulated`` is a
separate path), so they cost nothing and change no number
(tests/unit/test_can_emulator_effect_forms.py).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit
from numba.extending import register_jitable

from . import electronics as _el
from .electrical import (
    _current_derivative, _ladder_derivatives, _resistance, _temperature_derivative,
)
from .kernel import (
    D_AVG_IDX, D_BOOST, D_BOOST_END, D_CHOP_DUTY, D_CHOP_OFF, D_DIPPED, D_DUTY, D_IB,
    D_IMAX, D_IMIN, D_IPREV, D_MAIN_ON, D_MODE, D_N_FORCED, D_N_STEPS, D_NEXT_BOUNDARY,
    D_NEXT_FALL, D_NEXT_SAMPLE, D_NEXT_TICK, D_PEND_DUTY, D_PEND_PERIOD, D_PER_RUNNING,
    D_PER_START, D_PERIOD, D_PHASE, D_PI_INT, D_POUT, D_PREV_PERIOD, D_PSUP, D_Q_START,
    D_QI, D_QV, D_SAMPLE_DT, D_SAMPLE_IDX, D_SAMPLE_T0, D_T, D_T_OFF, D_T_ON, D_VC_OFF,
    D_VC_ON, D_VNEG, D_VS, D_XAVG, IV_DONE, IV_I, IV_QI0, IV_QV0, IV_T0, IV_V, N_D, N_OUT,
    N_P, N_Y, O_DT, O_I, O_MODE, O_QI, O_QV, O_QX, O_V, O_X, O_XDOT, P_A1, P_A2, P_A3, P_A4,
    P_B, P_B2, P_BETA, P_DELTA, P_E, P_EMU, P_FC, P_GE, P_K, P_KL, P_L0, P_LADR, P_LADRB,
    P_LAMS, P_LLEAK, P_M, P_R, P_RTH, P_TAUTH, P_XMAX, PH_CLAMP, PH_FAST, PH_FREEWHEEL,
    PH_OFF, PH_SUPPLY, S_DT, S_DUTY, S_FLOW, S_FREQ, S_I, S_I_MEAN, S_POUT, S_PSUP, S_T,
    S_V, S_V_MEAN, S_X, S_XAVG, S_XDOT, Y_DT, Y_I, Y_Q, Y_V, Y_X,
)
from .magnetics import MU_0, _force, _inductance, _inductance_slope, _law_force
from .mechanics import (
    MODE_CLOSED, MODE_FREE, MODE_OPEN, MODE_STUCK, SETTLE_SPEED_M_S,
    _acceleration, _active_force, _leave_margin, _pressure_force,
)
from .orifice import _mass_flow
from .parameters import PARAMETER_FIELDS
from .scalars import kernel_scalars

# the scalar functions of the physics modules imported above, compiled into the kernel
for _fn in kernel_scalars():
    register_jitable(_fn)

_F = {name: n for n, name in enumerate(PARAMETER_FIELDS)}
_R_MASS = _F['spool_mass_kg']
_R_K = _F['spring_stiffness_n_per_m']
_R_N = _F['coil_turns']
_R_A1 = _F['area_a1_m2']
_R_A2 = _F['area_a2_m2']
_R_A3 = _F['area_a3_m2']
_R_A4 = _F['area_a4_m2']
_R_LC = _F['core_length_m']
_R_R = _F['coil_resistance_ohm']
_R_XMAX = _F['stroke_m']
_R_AE = _F['core_area_m2']
_R_DELTA = _F['spring_pretension_m']
_R_XT = _F['total_air_gap_m']
_R_B = _F['damping_n_s_per_m']
_R_MUR = _F['relative_permeability']
_R_BETA = _F['saturation_coefficient_per_a']
_R_GE = _F['eddy_conductance_s']
_R_FC = _F['coulomb_friction_n']
_R_RTH = _F['thermal_resistance_k_per_w']
_R_TAUTH = _F['thermal_time_constant_s']
_R_LLEAK = _F['leakage_inductance_h']
_R_E = _F['restitution_coefficient']
_R_LAMS = _F['saturation_tanh_flux_linkage_wb']
_R_LADR = _F['eddy_ladder_inductance_ratio']
_R_LADRB = _F['eddy_ladder_resistance_ohm']
N_RAW = len(PARAMETER_FIELDS)

_EPS_T = 1e-12  # events closer than 1 ps count as simultaneous
#: A step shorter than this is no progress (an impact found at the step start).
_H_MIN = 1e-11
#: Loop passes without advancing time after which the guard forces a step. A correct
#: pass sequence at one instant needs a handful (events, a release, an impact).
_STALL_LIMIT = 100
#: Take a held step when a spool released from rest on a stop is back on it at once
#: (otherwise release and impact would alternate at one instant forever). Only tests
#: switch it off, to check the no-progress guard on that loop; numba freezes it at
#: compile time.
_HOLD_ON_RECROSS = True
_INF = np.inf


@njit(cache=True)
def _derive(raw: np.ndarray) -> np.ndarray:
    """Derived parameter vector ``P_*`` from a raw vector in PARAMETER_FIELDS order."""
    p = np.empty(N_P)
    mu_r = raw[_R_MUR]
    p[P_M] = raw[_R_MASS]
    p[P_K] = raw[_R_K]
    p[P_KL] = raw[_R_N] ** 2 * raw[_R_AE] * mu_r * MU_0
    p[P_L0] = raw[_R_LC] + 2.0 * mu_r * raw[_R_XT]
    p[P_B2] = 2.0 * mu_r
    p[P_R] = raw[_R_R]
    p[P_XMAX] = raw[_R_XMAX]
    p[P_DELTA] = raw[_R_DELTA]
    p[P_B] = raw[_R_B]
    p[P_A1] = raw[_R_A1]
    p[P_A2] = raw[_R_A2]
    p[P_A3] = raw[_R_A3]
    p[P_A4] = raw[_R_A4]
    p[P_BETA] = raw[_R_BETA]
    p[P_GE] = raw[_R_GE]
    p[P_FC] = raw[_R_FC]
    p[P_RTH] = raw[_R_RTH]
    p[P_TAUTH] = raw[_R_TAUTH]
    p[P_LLEAK] = raw[_R_LLEAK]
    p[P_E] = raw[_R_E]
    p[P_LAMS] = raw[_R_LAMS]
    p[P_LADR] = raw[_R_LADR]
    p[P_LADRB] = raw[_R_LADRB]
    p[P_EMU] = 1.0 if (raw[_R_LAMS] != 0.0 or raw[_R_LADR] != 0.0) else 0.0
    return p


# --------------------------------------------------------------------------------------
# Right-hand side
# --------------------------------------------------------------------------------------
@njit(cache=True, _nrt=False)
def _voltage(t: float, phase: int, d: np.ndarray, e: np.ndarray) -> float:
    """Coil terminal voltage applied by the driver at time t (phase fixed between edges)."""
    if phase == PH_SUPPLY:
        return d[D_VS]
    if phase == PH_FREEWHEEL:
        return 0.0
    if phase > PH_FREEWHEEL:
        # a clamp (Zener, free-wheel diode) or fast decay, until the current reaches zero
        return -d[D_VNEG] if phase == PH_CLAMP else -d[D_VS]
    vc = d[D_VC_OFF]
    if vc == 0.0:
        return 0.0
    arg = (t - d[D_T_OFF]) / e[_el.E_CAP_DISCHARGE_S]
    if arg > 50.0:
        return 0.0  # pulse over (below 2e-22 of its start); skips the exp
    # capacitor as a first-order low-pass with initial value (Section 4)
    return -vc * math.exp(-arg)


@njit(cache=True, _nrt=False, inline='always')
def _opens(volt: float, i_m: float, phase: int, p: np.ndarray, e: np.ndarray) -> bool:
    """Whether the coil's terminal is open: the eddy path is on, the driver's path in
    ``phase`` conducts forward current only (a clamp always; the capacitor pulse and fast
    decay when the driver blocks reverse current) and its voltage ``volt`` would drive the
    terminal current i_t = (i_m + G_e volt) / (1 + R G_e) below zero. The diodes block the
    terminal current, not the magnetising current: the terminal opens at i_t = 0 while i_m
    still flows, and i_m then decays through the eddy path."""
    if p[P_GE] == 0.0 or i_m + p[P_GE] * volt >= 0.0:
        return False
    if phase == PH_CLAMP:
        return True
    return (phase == PH_OFF or phase == PH_FAST) and e[_el.E_BLOCK_REVERSE] != 0.0


@njit(cache=True, _nrt=False, inline='always')
def _open_voltage(i_m: float, g_open: float) -> float:
    """Terminal voltage of the open coil, V: the one that keeps i_t at zero, -i_m / G_e
    (the eddy path carries i_m). ``g_open`` is G_e, or in :func:`_rhs` at least half a step
    over L: below that the decay's time constant L G_e is shorter than the step can follow
    (RK4 is stable to h / tau = 2.8), and the magnetising current falls within a step
    either way."""
    return -i_m / g_open


@njit(cache=True, _nrt=False, inline='always')
def _stage_voltage(volt: float, i_m: float, phase: int, h: float, ind: float, p: np.ndarray,
                   e: np.ndarray) -> tuple[float, bool]:
    """The terminal voltage at an RK4 stage of step ``h`` under the driver's ``volt`` and
    whether the terminal is open (:func:`_opens`; L(x) = ``ind`` sets the floor of the
    open terminal's conductance, :func:`_open_voltage`)."""
    if _opens(volt, i_m, phase, p, e):
        return _open_voltage(i_m, max(p[P_GE], 0.5 * h / ind)), True
    return volt, False


@njit(cache=True, _nrt=False, inline='always')
def _rhs(volt: float, i_m: float, x: float, v: float, d_temp: float, moving: bool,
         phase: int, f_prs: float, ind: float, slope: float, h: float, p: np.ndarray,
         e: np.ndarray) -> tuple[float, float, float, float, float, float]:
    """Derivatives (di_m/dt, dx/dt, dx_dot/dt, dT/dt), the terminal current and voltage:
    eqs. (7), (11).

    ``volt`` is the driver's terminal voltage at the stage time, ``ind``, ``slope`` are
    L(x) and dL/dx at the stage position (eqs. 4, 6), ``h`` the step (an open terminal,
    :func:`_opens`).
    """
    r = _resistance(p[P_R], d_temp)
    x_dot = v if moving else 0.0
    volt, is_open = _stage_voltage(volt, i_m, phase, h, ind, p, e)
    di, i_t = _current_derivative(volt, i_m, x_dot, ind, slope, r, p[P_GE], p[P_LLEAK],
                                  p[P_BETA])
    if is_open:
        i_t = 0.0
    if phase == PH_OFF and i_m <= 0.0 and di < 0.0 and e[_el.E_BLOCK_REVERSE] != 0.0:
        di = 0.0  # the driver's diode blocks reverse current
    ddt = _temperature_derivative(d_temp, i_t, r, p[P_RTH], p[P_TAUTH])
    if moving:
        f_a = _active_force(_force(i_m, slope, p[P_BETA]), p[P_K], x, p[P_DELTA], f_prs)
        dv = _acceleration(f_a, v, p[P_B], p[P_FC], p[P_M])  # eq. (11)
        return di, v, dv, ddt, i_t, volt
    return di, 0.0, 0.0, ddt, i_t, volt


@njit(cache=True, _nrt=False)
def _rhs_emulated(t: float, i_m: float, x: float, v: float, d_temp: float, i_b: float,
                  mode: int, phase: int, f_prs: float, h: float, p: np.ndarray,
                  d: np.ndarray, e: np.ndarray) -> tuple[float, float, float, float, float,
                                                         float, float, float]:
    """Derivatives of (i_m, x, x_dot, dT, q, q_i, q_v, i_b) with the emulator forms on."""
    ind = _inductance(x, p[P_KL], p[P_L0], p[P_B2])
    slope = _inductance_slope(ind, p[P_KL], p[P_B2])
    r = _resistance(p[P_R], d_temp)
    volt = _voltage(t, phase, d, e)
    volt, is_open = _stage_voltage(volt, i_m, phase, h, ind, p, e)
    moving = mode == MODE_FREE
    x_dot = v if moving else 0.0
    di, dib, i_t = _ladder_derivatives(volt, i_m, i_b, x_dot, ind, slope, r, p[P_GE],
                                       p[P_LLEAK], p[P_BETA], p[P_LAMS], p[P_LADR],
                                       p[P_LADRB])
    if is_open:
        i_t = 0.0
    if phase == PH_OFF and i_m <= 0.0 and di < 0.0 and e[_el.E_BLOCK_REVERSE] != 0.0:
        di = 0.0  # the driver's diode blocks reverse current
    ddt = _temperature_derivative(d_temp, i_t, r, p[P_RTH], p[P_TAUTH])
    if moving:
        f_a = _active_force(_emulated_force(i_m, i_b, ind, slope, p), p[P_K], x,
                            p[P_DELTA], f_prs)
        dv = _acceleration(f_a, v, p[P_B], p[P_FC], p[P_M])  # eq. (11)
        return di, v, dv, ddt, x, i_t, volt, dib
    return di, 0.0, 0.0, ddt, x, i_t, volt, dib


@njit(cache=True, _nrt=False)
def _emulated_force(i_m: float, i_b: float, ind: float, slope: float,
                    p: np.ndarray) -> float:
    """Magnetic force with the emulator forms: a F_law(i_m) + b F_law(i_b), N."""
    ratio = p[P_LADR]
    f_m = _law_force(i_m, ind, slope, p[P_BETA], p[P_LAMS])
    if ratio == 0.0:
        return f_m
    a = 1.0 / (1.0 + ratio)
    return a * f_m + ratio * a * _law_force(i_b, ind, slope, p[P_BETA], p[P_LAMS])


@njit(cache=True, _nrt=False)
def _rk4(t: float, h: float, y: tuple, mode: int, phase: int, f_prs: float, p: np.ndarray,
         d: np.ndarray, e: np.ndarray) -> tuple:
    """One classical RK4 step of length h from the tuple (y[0..4], q_i, q_v, i_b)."""
    ind = _inductance(y[1], p[P_KL], p[P_L0], p[P_B2])
    return _rk4_at(t, h, y, mode, phase, f_prs, ind, _inductance_slope(ind, p[P_KL], p[P_B2]),
                   p, d, e)


@njit(cache=True, _nrt=False)
def _rk4_at(t: float, h: float, y: tuple, mode: int, phase: int, f_prs: float, ind: float,
            slope: float, p: np.ndarray, d: np.ndarray, e: np.ndarray) -> tuple:
    """:func:`_rk4` with L and dL/dx at the start position y[1] given."""
    return _rk4_from(t, h, y, mode, phase, f_prs, ind, slope, _voltage(t, phase, d, e), p, d,
                     e)[0]


@njit(cache=True, _nrt=False)
def _rk4_from(t: float, h: float, y: tuple, mode: int, phase: int, f_prs: float, ind: float,
              slope: float, v_a: float, p: np.ndarray, d: np.ndarray, e: np.ndarray
              ) -> tuple[tuple, float]:
    """:func:`_rk4_at` with the voltage ``v_a`` at t given; returns (z, voltage at t + h).

    The integrals q, q_i, q_v are integrated with the state from the stage values of x,
    the terminal current and the voltage. The driver's voltage is evaluated once per
    stage time (the two midpoint stages share it) and, while the spool is held (x
    frozen), L(x) and dL/dx once per step.
    """
    if p[P_EMU] != 0.0:
        return (_rk4_emulated(t, h, y, mode, phase, f_prs, p, d, e),
                _voltage(t + h, phase, d, e))
    y0, y1, y2, y3, y4, y5, y6, y7 = y
    hh = 0.5 * h
    v_m = _voltage(t + hh, phase, d, e)
    v_g = _voltage(t + h, phase, d, e)
    k_l, l_0, b_2 = p[P_KL], p[P_L0], p[P_B2]
    moving = mode == MODE_FREE
    a0, a1, a2, a3, i_a, u_a = _rhs(v_a, y0, y1, y2, y3, moving, phase, f_prs, ind, slope, h,
                                    p, e)
    x_b = y1 + hh * a1
    if moving:
        ind = _inductance(x_b, k_l, l_0, b_2)
        slope = _inductance_slope(ind, k_l, b_2)
    b0, b1, b2, b3, i_b, u_b = _rhs(v_m, y0 + hh * a0, x_b, y2 + hh * a2, y3 + hh * a3,
                                    moving, phase, f_prs, ind, slope, h, p, e)
    x_c = y1 + hh * b1
    if moving:
        ind = _inductance(x_c, k_l, l_0, b_2)
        slope = _inductance_slope(ind, k_l, b_2)
    c0, c1, c2, c3, i_c, u_c = _rhs(v_m, y0 + hh * b0, x_c, y2 + hh * b2, y3 + hh * b3,
                                    moving, phase, f_prs, ind, slope, h, p, e)
    x_g = y1 + h * c1
    if moving:
        ind = _inductance(x_g, k_l, l_0, b_2)
        slope = _inductance_slope(ind, k_l, b_2)
    g0, g1, g2, g3, i_g, u_g = _rhs(v_g, y0 + h * c0, x_g, y2 + h * c2,
                                    y3 + h * c3, moving, phase, f_prs, ind, slope, h, p, e)
    s = h / 6.0
    return (y0 + s * (a0 + 2.0 * (b0 + c0) + g0),
            y1 + s * (a1 + 2.0 * (b1 + c1) + g1),
            y2 + s * (a2 + 2.0 * (b2 + c2) + g2),
            y3 + s * (a3 + 2.0 * (b3 + c3) + g3),
            y4 + s * (y1 + 2.0 * (x_b + x_c) + x_g),
            y5 + s * (i_a + 2.0 * (i_b + i_c) + i_g),
            y6 + s * (u_a + 2.0 * (u_b + u_c) + u_g),
            y7), v_g


@njit(cache=True, _nrt=False)
def _rk4_emulated(t: float, h: float, y: tuple, mode: int, phase: int, f_prs: float,
                  p: np.ndarray, d: np.ndarray, e: np.ndarray) -> tuple:
    """:func:`_rk4` with the emulator forms on (the slow ladder current i_b is y[7])."""
    y0, y1, y2, y3, y4, y5, y6, y7 = y
    a0, a1, a2, a3, a4, a5, a6, a7 = _rhs_emulated(t, y0, y1, y2, y3, y7, mode, phase,
                                                   f_prs, h, p, d, e)
    hh = 0.5 * h
    b0, b1, b2, b3, b4, b5, b6, b7 = _rhs_emulated(t + hh, y0 + hh * a0, y1 + hh * a1,
                                                   y2 + hh * a2, y3 + hh * a3, y7 + hh * a7,
                                                   mode, phase, f_prs, h, p, d, e)
    c0, c1, c2, c3, c4, c5, c6, c7 = _rhs_emulated(t + hh, y0 + hh * b0, y1 + hh * b1,
                                                   y2 + hh * b2, y3 + hh * b3, y7 + hh * b7,
                                                   mode, phase, f_prs, h, p, d, e)
    g0, g1, g2, g3, g4, g5, g6, g7 = _rhs_emulated(t + h, y0 + h * c0, y1 + h * c1,
                                                   y2 + h * c2, y3 + h * c3, y7 + h * c7,
                                                   mode, phase, f_prs, h, p, d, e)
    s = h / 6.0
    return (y0 + s * (a0 + 2.0 * (b0 + c0) + g0),
            y1 + s * (a1 + 2.0 * (b1 + c1) + g1),
            y2 + s * (a2 + 2.0 * (b2 + c2) + g2),
            y3 + s * (a3 + 2.0 * (b3 + c3) + g3),
            y4 + s * (a4 + 2.0 * (b4 + c4) + g4),
            y5 + s * (a5 + 2.0 * (b5 + c5) + g5),
            y6 + s * (a6 + 2.0 * (b6 + c6) + g6),
            y7 + s * (a7 + 2.0 * (b7 + c7) + g7))


@njit(cache=True, _nrt=False)
def _terminal_current(t: float, y: np.ndarray, phase: int, p: np.ndarray, d: np.ndarray,
                      e: np.ndarray) -> float:
    if p[P_GE] == 0.0:
        return y[Y_I]
    return _terminal_at(_voltage(t, phase, d, e), y, phase, p, e)[1]


@njit(cache=True, _nrt=False)
def _terminal_at(volt: float, y: np.ndarray, phase: int, p: np.ndarray, e: np.ndarray
                 ) -> tuple[float, float]:
    """Terminal voltage [V] and current [A] under the driver's ``volt``: those, or the
    open terminal's (:func:`_opens`), -i_m / G_e and 0."""
    if _opens(volt, y[Y_I], phase, p, e):
        return _open_voltage(y[Y_I], p[P_GE]), 0.0
    return volt, _terminal_current_at(volt, y, p)


@njit(cache=True, _nrt=False)
def _terminal_current_at(volt: float, y: np.ndarray, p: np.ndarray) -> float:
    """Terminal current under the terminal voltage ``volt``: i_m plus the eddy path, A."""
    if p[P_GE] == 0.0:
        return y[Y_I]
    r = _resistance(p[P_R], y[Y_DT])
    return y[Y_I] + p[P_GE] * (volt - r * y[Y_I]) / (1.0 + r * p[P_GE])


@njit(cache=True, _nrt=False)
def _f_active(i_m: float, i_b: float, x: float, f_prs: float, p: np.ndarray) -> float:
    """Net force without damping and friction at (i_m, i_b, x), N (eq. 9 rearranged)."""
    ind = _inductance(x, p[P_KL], p[P_L0], p[P_B2])
    return _f_active_at(i_m, i_b, x, ind, _inductance_slope(ind, p[P_KL], p[P_B2]), f_prs, p)


@njit(cache=True, _nrt=False)
def _f_active_at(i_m: float, i_b: float, x: float, ind: float, slope: float, f_prs: float,
                 p: np.ndarray) -> float:
    """:func:`_f_active` with L(x) and dL/dx given (a held spool keeps them)."""
    if p[P_EMU] != 0.0:
        return _active_force(_emulated_force(i_m, i_b, ind, slope, p), p[P_K], x,
                             p[P_DELTA], f_prs)
    return _active_force(_force(i_m, slope, p[P_BETA]), p[P_K], x, p[P_DELTA], f_prs)


@njit(cache=True, _nrt=False)
def _hermite(s: float, h: float, x0: float, v0: float, x1: float, v1: float) -> float:
    s2 = s * s
    s3 = s2 * s
    return ((2.0 * s3 - 3.0 * s2 + 1.0) * x0 + (s3 - 2.0 * s2 + s) * h * v0
            + (-2.0 * s3 + 3.0 * s2) * x1 + (s3 - s2) * h * v1)


@njit(cache=True, _nrt=False)
def _crossing(h: float, x0: float, v0: float, x1: float, v1: float, xb: float) -> float:
    """Fraction s in (0, 1] of the first crossing of level xb by the Hermite interpolant."""
    sgn1 = 1.0 if x1 - xb > 0.0 else -1.0
    lo = 0.0
    hi = 1.0
    # scan for the first sub-interval whose right end is beyond xb (x0 may sit on xb)
    for k in range(1, 17):
        s = k / 16.0
        if (_hermite(s, h, x0, v0, x1, v1) - xb) * sgn1 > 0.0:
            hi = s
            lo = (k - 1) / 16.0
            break
    for _ in range(48):
        mid = 0.5 * (lo + hi)
        if (_hermite(mid, h, x0, v0, x1, v1) - xb) * sgn1 > 0.0:
            hi = mid
        else:
            lo = mid
    return hi


# --------------------------------------------------------------------------------------
# Discrete events of the drive electronics
# --------------------------------------------------------------------------------------
@njit(cache=True, _nrt=False)
def _rising_edge(t: float, y: np.ndarray, p: np.ndarray, d: np.ndarray,
                 e: np.ndarray) -> None:
    i_t = _terminal_current(t, y, int(d[D_PHASE]), p, d, e)
    d[D_MAIN_ON] = 1.0
    if e[_el.E_CAPACITOR] != 0.0:
        # what is left of the capacitor voltage from the last pulse
        d[D_VC_ON] = d[D_VC_OFF] * math.exp(-(t - d[D_T_OFF]) / e[_el.E_CAP_DISCHARGE_S])
    else:
        d[D_VC_ON] = 0.0
    d[D_T_ON] = t
    d[D_PHASE] = PH_SUPPLY
    d[D_CHOP_OFF] = _INF
    if e[_el.E_CURRENT_CONTROL] != 0.0:
        d[D_BOOST] = 1.0
        d[D_IMAX] = i_t
        d[D_IPREV] = i_t
        d[D_DIPPED] = 0.0
        form = e[_el.E_PEAK_END]
        if form == _el.PEAK_DIP or form == _el.PEAK_DIP_RISE:
            d[D_NEXT_TICK] = t  # controller ticks aligned with the rising edge
        else:
            # the timer (or the threshold form's timeout) is the boost's one tick
            d[D_NEXT_TICK] = t + e[_el.E_BOOST_MAX_S]
    else:
        d[D_BOOST] = 0.0
        d[D_NEXT_TICK] = _INF


@njit(cache=True, _nrt=False)
def _falling_edge(t: float, d: np.ndarray, e: np.ndarray) -> None:
    """End of the main PWM high phase: the release (``ElectronicsConfig.release``)."""
    d[D_MAIN_ON] = 0.0
    d[D_PHASE] = PH_OFF
    if e[_el.E_CAPACITOR] == 0.0:
        d[D_VC_OFF] = 0.0
    elif e[_el.E_RELEASE] == _el.RELEASE_CAPACITOR:
        vcap = e[_el.E_CAP_V]
        d[D_VC_OFF] = vcap + (d[D_VC_ON] - vcap) * math.exp(
            -(t - d[D_T_ON]) / e[_el.E_CAP_CHARGE_S])
    elif e[_el.E_RELEASE] == _el.RELEASE_CAPACITOR_PEAK:
        # charged during the peak phase only (the whole high phase without one)
        t_charged = t
        if d[D_BOOST] == 0.0 and d[D_BOOST_END] >= d[D_T_ON]:
            t_charged = d[D_BOOST_END]
        vcap = e[_el.E_CAP_V]
        d[D_VC_OFF] = vcap + (d[D_VC_ON] - vcap) * math.exp(
            -(t_charged - d[D_T_ON]) / e[_el.E_CAP_CHARGE_S])
    else:
        # Zener clamp or free-wheel diode, until the current reaches zero (a level event)
        d[D_VC_OFF] = 0.0
        d[D_VNEG] = e[_el.E_ZENER_V] if e[_el.E_RELEASE] == _el.RELEASE_ZENER \
            else e[_el.E_DIODE_V]
        d[D_PHASE] = PH_CLAMP
    d[D_T_OFF] = t
    d[D_NEXT_TICK] = _INF
    d[D_CHOP_OFF] = _INF
    d[D_BOOST] = 0.0


@njit(cache=True, _nrt=False)
def _chopper_off(d: np.ndarray, e: np.ndarray) -> None:
    """The hold's chopper switches off: the coil sees ``ElectronicsConfig.hold_decay``."""
    decay = e[_el.E_DECAY]
    if decay == _el.DECAY_FREEWHEEL:
        d[D_PHASE] = PH_FREEWHEEL
    elif decay == _el.DECAY_DIODE:
        d[D_VNEG] = e[_el.E_DIODE_V]
        d[D_PHASE] = PH_CLAMP
    else:
        d[D_PHASE] = PH_FAST


@njit(cache=True, _nrt=False)
def _boost_ends(t: float, i_t: float, d: np.ndarray, e: np.ndarray) -> bool:
    """A controller sample during the boost: True if the peak phase ends now.

    The dip forms sample the current once per chopper period; for the timer and the
    threshold form a boost tick is the timer (the threshold itself is a level event).
    """
    form = e[_el.E_PEAK_END]
    if form != _el.PEAK_DIP and form != _el.PEAK_DIP_RISE:
        return True
    end = t - d[D_T_ON] >= e[_el.E_BOOST_MAX_S] - _EPS_T
    if form == _el.PEAK_DIP:
        if i_t > d[D_IMAX]:
            d[D_IMAX] = i_t
        elif d[D_IMAX] - i_t >= e[_el.E_DIP_A]:
            d[D_DIPPED] = 1.0
        if d[D_DIPPED] != 0.0 and i_t > d[D_IPREV]:
            end = True  # current rises again after the dip: end of stroke
        d[D_IPREV] = i_t
        return end
    if d[D_DIPPED] == 0.0:
        if i_t > d[D_IMAX]:
            d[D_IMAX] = i_t
        elif d[D_IMAX] - i_t >= e[_el.E_DIP_A]:
            d[D_DIPPED] = 1.0
            d[D_IMIN] = i_t
    elif i_t < d[D_IMIN]:
        d[D_IMIN] = i_t
    elif i_t - d[D_IMIN] >= e[_el.E_RISE_A]:
        end = True  # risen a threshold above the minimum after the dip
    return end


@njit(cache=True, _nrt=False)
def _end_boost(t: float, y: np.ndarray, p: np.ndarray, d: np.ndarray,
               e: np.ndarray) -> None:
    """The peak phase ends at t; the PI integrator starts at the feed-forward duty."""
    d[D_BOOST] = 0.0
    d[D_BOOST_END] = t
    ff = e[_el.E_HOLD_A] * _resistance(p[P_R], y[Y_DT]) / d[D_VS] if d[D_VS] > 0 else 1.0
    d[D_PI_INT] = min(1.0, max(0.0, ff))


@njit(cache=True, _nrt=False)
def _hold_tick(t: float, i_t: float, d: np.ndarray, e: np.ndarray) -> None:
    """A tick of the hold (``ElectronicsConfig.hold``): set the chopper from the current."""
    form = e[_el.E_HOLD]
    if form == _el.HOLD_HYSTERESIS:
        half = 0.5 * e[_el.E_BAND_A]
        if i_t < e[_el.E_HOLD_A] - half:
            d[D_PHASE] = PH_SUPPLY
        elif i_t > e[_el.E_HOLD_A] + half and d[D_PHASE] == PH_SUPPLY:
            _chopper_off(d, e)
        d[D_CHOP_DUTY] = 1.0 if d[D_PHASE] == PH_SUPPLY else 0.0
        d[D_CHOP_OFF] = _INF
        d[D_NEXT_TICK] = t + 1.0 / e[_el.E_COMPARATOR_HZ]
        return
    period = 1.0 / e[_el.E_CHOPPER_HZ]
    if form == _el.HOLD_PWM:
        u = e[_el.E_HOLD_DUTY]
    else:
        err = e[_el.E_HOLD_A] - i_t
        integ = d[D_PI_INT] + e[_el.E_KI] * err * period
        integ = min(1.0, max(0.0, integ))  # clamping anti-windup
        d[D_PI_INT] = integ
        u = min(1.0, max(0.0, e[_el.E_KP] * err + integ))
    d[D_CHOP_DUTY] = u
    if u <= 0.0:
        _chopper_off(d, e)
        d[D_CHOP_OFF] = _INF
    elif u >= 1.0:
        d[D_PHASE] = PH_SUPPLY
        d[D_CHOP_OFF] = _INF
    else:
        d[D_PHASE] = PH_SUPPLY
        d[D_CHOP_OFF] = t + u * period
    d[D_NEXT_TICK] = t + period


@njit(cache=True, _nrt=False)
def _controller_tick(t: float, y: np.ndarray, p: np.ndarray, d: np.ndarray,
                     e: np.ndarray) -> None:
    """Sampled current controller: the end of the peak phase, then the hold."""
    i_t = _terminal_current(t, y, int(d[D_PHASE]), p, d, e)
    if d[D_BOOST] != 0.0:
        if not _boost_ends(t, i_t, d, e):
            d[D_NEXT_TICK] = t + 1.0 / e[_el.E_CHOPPER_HZ]
            return
        _end_boost(t, y, p, d, e)
    _hold_tick(t, i_t, d, e)


@njit(cache=True, _nrt=False)
def _period_boundary(t: float, y: np.ndarray, p: np.ndarray, d: np.ndarray,
                     e: np.ndarray, avg_out: np.ndarray) -> None:
    if d[D_PER_RUNNING] != 0.0:
        avg = (y[Y_Q] - d[D_Q_START]) / (t - d[D_PER_START])
        d[D_XAVG] = avg
        k = int(d[D_AVG_IDX])
        if k < avg_out.shape[0]:
            avg_out[k] = avg
        d[D_AVG_IDX] = k + 1.0
    # a pending command takes effect only here: no pulse is ever cut short
    d[D_PREV_PERIOD] = d[D_PERIOD]
    d[D_DUTY] = d[D_PEND_DUTY]
    d[D_PERIOD] = d[D_PEND_PERIOD]
    d[D_PER_START] = t
    d[D_Q_START] = y[Y_Q]
    d[D_PER_RUNNING] = 1.0
    duty = d[D_DUTY]
    if duty > 0.0:
        if d[D_MAIN_ON] == 0.0:
            _rising_edge(t, y, p, d, e)
        d[D_NEXT_FALL] = t + duty * d[D_PERIOD] if duty < 1.0 else _INF
    else:
        if d[D_MAIN_ON] != 0.0:
            _falling_edge(t, d, e)
        d[D_NEXT_FALL] = _INF
    d[D_NEXT_BOUNDARY] = t + d[D_PERIOD]


@njit(cache=True, _nrt=False)
def _command(t_cmd: float, d: np.ndarray, e: np.ndarray, duty: float, period: float) -> None:
    """A main PWM command given at ``t_cmd`` (s): duty 0 switches off at once, others latch.

    The one definition of when a command takes effect (ValveStepper, the CAN emulator and
    the trace runs call it): a non-zero duty and any frequency wait for the next period
    start (glitch-free, like a timer's shadow registers); a duty of 0 while a non-zero duty
    is in force ends the main PWM high phase now (falling edge: chopper off, capacitor
    pulse) and puts duty 0 in force at once. The period grid keeps running, so a later
    non-zero command starts at the next period start of the same grid. A zero command due
    at a period start (within the event tolerance) is left to that period start, so runs
    that never command 0 within a period are unchanged.
    """
    d[D_PEND_DUTY] = duty
    d[D_PEND_PERIOD] = period
    if duty == 0.0 and d[D_DUTY] > 0.0 and d[D_NEXT_BOUNDARY] > t_cmd + _EPS_T:
        d[D_DUTY] = 0.0
        d[D_NEXT_FALL] = _INF
        if d[D_MAIN_ON] != 0.0:
            _falling_edge(d[D_T], d, e)  # at the model time reached (a trace: 3 ps early)


@njit(cache=True, _nrt=False)
def _record(t: float, y: np.ndarray, p: np.ndarray, d: np.ndarray, e: np.ndarray,
            out: np.ndarray) -> None:
    """Write the sample row ``d[D_SAMPLE_IDX]`` at time t and schedule the next sample."""
    volt = _voltage(t, int(d[D_PHASE]), d, e) if d[D_SAMPLE_IDX] < out.shape[0] else 0.0
    _record_at(t, volt, y, p, d, e, out)


@njit(cache=True, _nrt=False)
def _record_at(t: float, volt: float, y: np.ndarray, p: np.ndarray, d: np.ndarray,
               e: np.ndarray, out: np.ndarray) -> None:
    """:func:`_record` with the driver's voltage at t given."""
    k = int(d[D_SAMPLE_IDX])
    if k < out.shape[0]:
        out[k, O_V], out[k, O_I] = _terminal_at(volt, y, int(d[D_PHASE]), p, e)
        out[k, O_X] = y[Y_X]
        out[k, O_XDOT] = y[Y_V]
        out[k, O_DT] = y[Y_DT]
        out[k, O_MODE] = d[D_MODE]
        if out.shape[1] > O_QV:  # (a buffer of the older 6 columns stays valid)
            out[k, O_QX] = y[Y_Q]
            out[k, O_QI] = d[D_QI]
            out[k, O_QV] = d[D_QV]
    d[D_SAMPLE_IDX] = k + 1.0
    if k + 1 >= out.shape[0]:
        d[D_NEXT_SAMPLE] = _INF
    else:
        # from the first sample time, so long runs do not accumulate rounding
        d[D_NEXT_SAMPLE] = d[D_SAMPLE_T0] + (k + 1) * d[D_SAMPLE_DT]


@njit(cache=True, _nrt=False)
def _process_events(t: float, y: np.ndarray, p: np.ndarray, d: np.ndarray, e: np.ndarray,
                    out: np.ndarray, avg_out: np.ndarray) -> None:
    lim = t + _EPS_T
    if d[D_NEXT_BOUNDARY] <= lim:
        _period_boundary(t, y, p, d, e, avg_out)
    if d[D_NEXT_FALL] <= lim:
        d[D_NEXT_FALL] = _INF
        _falling_edge(t, d, e)
    if d[D_CHOP_OFF] <= lim:
        d[D_CHOP_OFF] = _INF
        _chopper_off(d, e)
    if d[D_NEXT_TICK] <= lim:
        _controller_tick(t, y, p, d, e)
    if d[D_NEXT_SAMPLE] <= lim:
        _record(t, y, p, d, e, out)


# --------------------------------------------------------------------------------------
# Root finders inside one RK4 step (the step is redone up to the located instant)
# --------------------------------------------------------------------------------------
@njit(cache=True, _nrt=False)
def _impact(t: float, h: float, t_new: float, s_hit: float, xb: float, y: tuple,
            phase: int, f_prs: float, p: np.ndarray, d: np.ndarray, e: np.ndarray,
            hold_on_recross: bool) -> tuple:
    """End-stop impact at fraction ``s_hit`` of the step (found on the Hermite interpolant).

    Returns (t_new, z): the step is redone up to the impact, x set onto the stop xb and
    the velocity to 0 (plastic, the paper) or -e x_dot (``end_stop_bounce``).
    """
    held = MODE_CLOSED if xb == 0.0 else MODE_OPEN
    if hold_on_recross and s_hit * h <= _H_MIN and y[1] == xb and y[2] == 0.0:
        # Released from rest on this stop and back on it at the step start: the held
        # force margin was positive but falls at once (e.g. the capacitor pulse at a
        # falling edge), so the lift is below what the interpolant resolves (of the order
        # of 1e-19 m). Freeing the spool again would repeat this at the same instant
        # forever; it stays on the stop for the step instead. A margin still positive at
        # the step end releases it.
        z = _rk4(t, h, y, held, phase, f_prs, p, d, e)
        d[D_N_STEPS] += 1.0
        d[D_MODE] = held
        return t_new, (z[0], xb, 0.0, z[3], z[4], z[5], z[6], z[7])
    hs = s_hit * h
    if hs > _H_MIN:
        z = _rk4(t, hs, y, MODE_FREE, phase, f_prs, p, d, e)
        d[D_N_STEPS] += 1.0
    else:
        hs = 0.0
        z = y
    v_imp = z[2]
    v_new = 0.0
    if p[P_E] > 0.0 and abs(v_imp) > SETTLE_SPEED_M_S and hs > 0.0:
        v_new = -p[P_E] * v_imp  # bounce with restitution e
    else:
        d[D_MODE] = held
    return t + hs, (z[0], xb, v_new, z[3], z[4], z[5], z[6], z[7])


@njit(cache=True, _nrt=False)
def _reversal(t: float, h: float, s_rev: float, y: tuple, z: tuple, phase: int,
              f_prs: float, p: np.ndarray, d: np.ndarray, e: np.ndarray) -> tuple:
    """Velocity reversal under Coulomb friction: regula falsi on x_dot(t) = 0."""
    lo = 0.0
    hi = h
    v_lo = y[2]
    v_hi = z[2]
    hs = h * s_rev
    for _ in range(30):
        z = _rk4(t, hs, y, MODE_FREE, phase, f_prs, p, d, e)
        d[D_N_STEPS] += 1.0
        if abs(z[2]) < 1e-9 or hi - lo < 1e-12:
            break
        if (z[2] > 0.0) == (v_lo > 0.0):
            lo = hs
            v_lo = z[2]
        else:
            hi = hs
            v_hi = z[2]
        hs = lo + (hi - lo) * v_lo / (v_lo - v_hi)
    if abs(_f_active(z[0], z[7], z[1], f_prs, p)) <= p[P_FC]:
        d[D_MODE] = MODE_STUCK
    return t + hs, (z[0], z[1], 0.0, z[3], z[4], z[5], z[6], z[7])


@njit(cache=True, _nrt=False)
def _free_step_events(t: float, h: float, t_new: float, y: tuple, z: tuple, phase: int,
                      f_prs: float, p: np.ndarray, d: np.ndarray, e: np.ndarray,
                      hold_on_recross: bool) -> tuple:
    """End-stop impacts and (with friction) velocity reversals inside a free step."""
    s_hit = 2.0
    xb = 0.0
    if z[1] < 0.0:
        s_hit = _crossing(h, y[1], y[2], z[1], z[2], 0.0)
    elif z[1] > p[P_XMAX]:
        xb = p[P_XMAX]
        s_hit = _crossing(h, y[1], y[2], z[1], z[2], xb)
    s_rev = 2.0
    if p[P_FC] > 0.0 and y[2] != 0.0 and (z[2] == 0.0 or (z[2] > 0.0) != (y[2] > 0.0)):
        s_rev = y[2] / (y[2] - z[2])
    if s_hit <= 1.0 and s_hit <= s_rev:
        return _impact(t, h, t_new, s_hit, xb, y, phase, f_prs, p, d, e, hold_on_recross)
    if s_rev <= 1.0:
        return _reversal(t, h, s_rev, y, z, phase, f_prs, p, d, e)
    return t_new, z


@njit(cache=True, _nrt=False)
def _release(t: float, h: float, t_new: float, y: tuple, z: tuple, mode: int, phase: int,
             f_prs: float, ind: float, slope: float, p: np.ndarray, d: np.ndarray,
             e: np.ndarray) -> tuple:
    """Leaving a stop (or static friction): Illinois search for the held force margin = 0.

    ``ind``, ``slope``: L and dL/dx at the held position y[1]. Returns (t_new, z)
    unchanged if the margin stays negative over the step, else the step redone up to the
    release and the mode set to moving.
    """
    f_c = p[P_FC]
    x = y[1]
    g1 = _leave_margin(mode, _f_active_at(z[0], z[7], x, ind, slope, f_prs, p), f_c)
    if g1 <= 0.0:
        return t_new, z
    g0 = _leave_margin(mode, _f_active_at(y[0], y[7], x, ind, slope, f_prs, p), f_c)
    # a margin already positive at the start (a held step after an immediate re-impact,
    # or forced by the guard) brackets no root: release at the end
    lo = 0.0 if g0 <= 0.0 else h
    hi = h
    g_lo = g0
    g_hi = g1
    side = 0
    for _ in range(40):
        if hi - lo < 1e-10:
            break
        hs = (lo * g_hi - hi * g_lo) / (g_hi - g_lo)
        w = _rk4_at(t, hs, y, mode, phase, f_prs, ind, slope, p, d, e)
        d[D_N_STEPS] += 1.0
        g = _leave_margin(mode, _f_active_at(w[0], w[7], x, ind, slope, f_prs, p), f_c)
        if g > 0.0:
            hi = hs
            g_hi = g
            if side == 1:
                g_lo *= 0.5  # Illinois modification
            side = 1
        else:
            lo = hs
            g_lo = g
            if side == -1:
                g_hi *= 0.5
            side = -1
        if abs(g) < 1e-9:
            break
    if hi < h:
        z = _rk4_at(t, hi, y, mode, phase, f_prs, ind, slope, p, d, e)
        d[D_N_STEPS] += 1.0
        t_new = t + hi
    d[D_MODE] = MODE_FREE
    return t_new, z


# --------------------------------------------------------------------------------------
# Level events: the current reaching a level inside a step (the step is redone up to it)
# --------------------------------------------------------------------------------------
_LEVEL_NONE = 0
_LEVEL_PEAK = 1   # 'threshold' peak end: the terminal current rises to peak_current_a
_LEVEL_ZERO = 2   # a clamp or blocked fast decay: the magnetising current falls to zero


@njit(cache=True, _nrt=False)
def _level_kind(phase: int, d: np.ndarray, e: np.ndarray) -> int:
    """The level event armed in ``phase`` (``_LEVEL_*``)."""
    if phase > PH_FREEWHEEL:
        if phase == PH_CLAMP or e[_el.E_BLOCK_REVERSE] != 0.0:
            return _LEVEL_ZERO
        return _LEVEL_NONE
    if phase == PH_SUPPLY and d[D_BOOST] != 0.0 \
            and e[_el.E_PEAK_END] == _el.PEAK_THRESHOLD:
        return _LEVEL_PEAK
    return _LEVEL_NONE


@njit(cache=True, _nrt=False)
def _level_margin(kind: int, i_m: float, d_temp: float, volt: float, p: np.ndarray,
                  e: np.ndarray) -> float:
    """How far the current is past the armed level, A (>= 0: reached)."""
    if kind == _LEVEL_ZERO:
        return -i_m
    i_t = i_m
    if p[P_GE] != 0.0:
        r = _resistance(p[P_R], d_temp)
        i_t = i_m + p[P_GE] * (volt - r * i_m) / (1.0 + r * p[P_GE])
    return i_t - e[_el.E_PEAK_A]


@njit(cache=True, _nrt=False)
def _locate_level(t: float, h: float, t_new: float, y: tuple, z: tuple, v_a: float,
                  v_g: float, g_lo: float, g_hi: float, kind: int, mode: int, phase: int,
                  f_prs: float, ind: float, slope: float, p: np.ndarray, d: np.ndarray,
                  e: np.ndarray) -> tuple:
    """Illinois search for the instant the level is reached inside the step [t, t + h].

    ``g_lo`` < 0 and ``g_hi`` >= 0 are the margins at the step's start and end. Returns
    (t_new, z, voltage at t_new, step length): the step redone up to the first instant
    found with a margin >= 0 (within 1 ps or 1 pA of the crossing).
    """
    lo = 0.0
    hi = h
    side = 0
    for _ in range(60):
        if hi - lo < 1e-12:
            break
        hs = (lo * g_hi - hi * g_lo) / (g_hi - g_lo)
        if not lo < hs < hi:
            hs = 0.5 * (lo + hi)
        w, v_w = _rk4_from(t, hs, y, mode, phase, f_prs, ind, slope, v_a, p, d, e)
        d[D_N_STEPS] += 1.0
        g = _level_margin(kind, w[0], w[3], v_w, p, e)
        if g >= 0.0:
            hi = hs
            g_hi = g
            z = w
            v_g = v_w
            t_new = t + hs
            if side == 1:
                g_lo *= 0.5  # Illinois modification
            side = 1
            if g < 1e-12:
                break
        else:
            lo = hs
            g_lo = g
            if side == -1:
                g_hi *= 0.5
            side = -1
    return t_new, z, v_g, hi


@njit(cache=True, _nrt=False)
def _level_reached(kind: int, t: float, y: np.ndarray, p: np.ndarray, d: np.ndarray,
                   e: np.ndarray) -> None:
    """Apply a reached level: the clamp ends (0 V) or the peak phase ends (the hold)."""
    if kind == _LEVEL_ZERO:
        d[D_PHASE] = PH_FREEWHEEL
        return
    _end_boost(t, y, p, d, e)
    _hold_tick(t, _terminal_current(t, y, PH_SUPPLY, p, d, e), d, e)


@njit(cache=True, _nrt=False)
def _next_event(d: np.ndarray) -> float:
    return min(d[D_NEXT_BOUNDARY], d[D_NEXT_FALL], d[D_NEXT_TICK], d[D_CHOP_OFF],
               d[D_NEXT_SAMPLE])


@njit(cache=True, _nrt=False)
def _next_drive_event(d: np.ndarray) -> float:
    """The next event other than an output sample, s."""
    return min(d[D_NEXT_BOUNDARY], d[D_NEXT_FALL], d[D_NEXT_TICK], d[D_CHOP_OFF])


@njit(cache=True, _nrt=False)
def _step_to(t: float, target: float, hmax: float) -> tuple[float, float]:
    """(t_new, h): equal steps no longer than hmax that land exactly on ``target``."""
    span = target - t
    n = math.ceil(span / hmax - 1e-9)
    h = span / n if n > 1 else span
    t_new = target if n <= 1 else t + h
    return t_new, t_new - t


# --------------------------------------------------------------------------------------
# Main loop
# --------------------------------------------------------------------------------------
@njit(cache=True, _nrt=False)
def _advance(p: np.ndarray, e: np.ndarray, y: np.ndarray, d: np.ndarray, t_end: float,
             h_free: float, h_stop: float, out: np.ndarray, avg_out: np.ndarray) -> None:
    f_prs = _pressure_force(p[P_A1], p[P_A2], p[P_A3], p[P_A4], d[D_PSUP], d[D_POUT])
    t_prog = d[D_T]
    stall = 0
    k_l, l_0, b_2 = p[P_KL], p[P_L0], p[P_B2]
    geo_x = math.nan  # the position L and dL/dx were last computed for (a held spool)
    ind = 0.0
    slope = 0.0
    # the driver's voltage v_known at time t_known, valid until the next event changes the
    # drive (a step's end voltage is the next step's start voltage and the sample's)
    t_known = math.nan
    v_known = 0.0
    # the held force margin g_known of mode m_known at (i_known, ib_known, x_known)
    i_known = math.nan
    ib_known = math.nan
    x_known = math.nan
    m_known = -1
    g_known = 0.0
    f_c = p[P_FC]
    # whether a level event can be armed in this call: by a form of the electronics, or by
    # a clamp still running from the electronics before a switch (else none is looked at)
    levels = e[_el.E_PEAK_END] == _el.PEAK_THRESHOLD or e[_el.E_DECAY] != _el.DECAY_FREEWHEEL \
        or (e[_el.E_RELEASE] >= _el.RELEASE_ZENER and e[_el.E_CAPACITOR] != 0.0) \
        or d[D_PHASE] > PH_FREEWHEEL
    while True:
        t = d[D_T]
        # --- no-progress guard: a pass that does not advance time counts as a stall
        if t > t_prog:
            t_prog = t
            stall = 0
        else:
            stall += 1
        forced = stall > _STALL_LIMIT
        t_ev = _next_event(d)
        if t_ev <= t + _EPS_T:
            _process_events(t, y, p, d, e, out, avg_out)
            t_known = math.nan
            if not forced:
                continue
            t_ev = _next_event(d)
        if not t < t_end - _EPS_T:  # (also ends on a NaN time)
            break
        target = min(t_ev, t_end)
        if forced and not target > t + _EPS_T:
            # guard: events keep falling on this instant (a period below 1 ps): step past
            target = min(t + h_free, t_end)
            d[D_N_FORCED] += 1.0
        mode = int(d[D_MODE])
        phase = int(d[D_PHASE])
        level = _level_kind(phase, d, e) if levels else _LEVEL_NONE
        if level != _LEVEL_NONE and not forced:
            v_now = v_known if t == t_known else _voltage(t, phase, d, e)
            if _level_margin(level, y[Y_I], y[Y_DT], v_now, p, e) >= 0.0:
                _level_reached(level, t, y, p, d, e)  # already there (e.g. at an edge)
                t_known = math.nan
                continue
        x = y[Y_X]
        if x != geo_x:
            ind = _inductance(x, k_l, l_0, b_2)
            slope = _inductance_slope(ind, k_l, b_2)
            geo_x = x
        if mode != MODE_FREE and not forced:
            if y[Y_I] == i_known and d[D_IB] == ib_known and x == x_known \
                    and mode == m_known:
                g = g_known  # the last held step's end margin, the same numbers
            else:
                g = _leave_margin(mode, _f_active_at(y[Y_I], d[D_IB], x, ind, slope, f_prs,
                                                     p), f_c)
            if g > 0.0:
                d[D_MODE] = MODE_FREE
                continue
        t_new, h = _step_to(t, target, h_free if mode == MODE_FREE else h_stop)
        y_0 = (y[0], x, y[2], y[3], y[4], d[D_QI], d[D_QV], d[D_IB])
        v_a = v_known if t == t_known else _voltage(t, phase, d, e)
        z, v_g = _rk4_from(t, h, y_0, mode, phase, f_prs, ind, slope, v_a, p, d, e)
        d[D_N_STEPS] += 1.0
        t_level = _INF
        if level != _LEVEL_NONE:
            g_end = _level_margin(level, z[0], z[3], v_g, p, e)
            if g_end >= 0.0:
                # redo the step up to the level; an impact or release before it comes first
                t_new, z, v_g, h = _locate_level(
                    t, h, t_new, y_0, z, v_a, v_g,
                    _level_margin(level, y_0[0], y_0[3], v_a, p, e), g_end, level, mode,
                    phase, f_prs, ind, slope, p, d, e)
                t_level = t_new
        if mode == MODE_FREE:
            t_new, z = _free_step_events(t, h, t_new, y_0, z, phase, f_prs, p, d, e,
                                         _HOLD_ON_RECROSS)
        else:
            g_known = _leave_margin(mode, _f_active_at(z[0], z[7], x, ind, slope, f_prs, p),
                                    f_c)
            if g_known > 0.0:
                t_new, z = _release(t, h, t_new, y_0, z, mode, phase, f_prs, ind, slope, p,
                                    d, e)
                m_known = -1
            else:  # held for the whole step (what _release would find first)
                i_known = z[0]
                ib_known = z[7]
                x_known = x
                m_known = mode
        if forced and t_new <= t:
            # Last resort, never reached by a correct kernel: this instant has already
            # taken _STALL_LIMIT passes without progress. Step on with the spool frozen
            # (x, x_dot kept; coil and temperature integrated) so the call cannot hang.
            z = _rk4(t, h, y_0, MODE_STUCK, phase, f_prs, p, d, e)
            d[D_N_STEPS] += 1.0
            d[D_MODE] = mode
            m_known = -1
            t_new = t + h
            d[D_N_FORCED] += 1.0
        for k in range(N_Y):
            y[k] = z[k]
        d[D_QI] = z[5]
        d[D_QV] = z[6]
        d[D_IB] = z[7]
        if phase == PH_OFF and y[Y_I] < 0.0 and e[_el.E_BLOCK_REVERSE] != 0.0:
            y[Y_I] = 0.0
        d[D_T] = t_new
        t_known = t + h  # the time of the last stage
        v_known = v_g
        if level != _LEVEL_NONE and t_new == t_level:
            if level == _LEVEL_ZERO:
                y[Y_I] = 0.0  # (within 1 pA or 1 ps of the crossing)
            _level_reached(level, t_new, y, p, d, e)
            t_known = math.nan
        if t_new > t and d[D_NEXT_SAMPLE] <= t_new + _EPS_T \
                and _next_drive_event(d) > t_new + _EPS_T:
            # an output sample alone is due at the step's end: recorded here, as the
            # event pass would (the guard counts as if that pass had run)
            if t_new == t_known:
                _record_at(t_new, v_known, y, p, d, e, out)
            else:
                _record(t_new, y, p, d, e, out)
            t_prog = t_new
            stall = 0


# --------------------------------------------------------------------------------------
# Initial drive state: the one place that fills the D_* slots at t = 0
# --------------------------------------------------------------------------------------
@njit(cache=True)
def _drive_state(supply_voltage_v: float, duty: float, period_s: float,
                 first_period_start_s: float, supply_pressure_pa: float,
                 output_pressure_pa: float, sample_dt_s: float,
                 first_sample_s: float) -> np.ndarray:
    """Compiled body of :func:`new_drive_state` (also called by the batch kernels)."""
    d = np.zeros(N_D)
    d[D_MODE] = MODE_CLOSED
    d[D_PHASE] = PH_OFF
    d[D_VS] = supply_voltage_v
    d[D_PSUP] = supply_pressure_pa
    d[D_POUT] = output_pressure_pa
    # the duty in force before the first period starts is reported, never applied: the
    # first period boundary latches the pending command
    d[D_DUTY] = duty
    d[D_PERIOD] = period_s
    d[D_PEND_DUTY] = duty
    d[D_PEND_PERIOD] = period_s
    d[D_NEXT_BOUNDARY] = first_period_start_s
    d[D_NEXT_FALL] = _INF
    d[D_NEXT_TICK] = _INF
    d[D_CHOP_OFF] = _INF
    d[D_NEXT_SAMPLE] = first_sample_s if math.isfinite(sample_dt_s) else _INF
    d[D_SAMPLE_DT] = sample_dt_s
    d[D_SAMPLE_T0] = first_sample_s
    d[D_BOOST_END] = np.nan
    return d


# --------------------------------------------------------------------------------------
# Batches: rows r0 <= r < r1 of a batch, without the GIL (kernel.py spreads the rows of a
# batch over threads). They live in this file because numba's cache tracks only the file
# that defines a function: compiled callers of _advance elsewhere would keep a stale copy.
# --------------------------------------------------------------------------------------
@njit(cache=True, nogil=True)
def _step_rows(raw: np.ndarray, e: np.ndarray, voltage: np.ndarray, p_sup: np.ndarray,
               p_out: np.ndarray, duration: float, step_time: float, sample_dt: float,
               h_free: float, h_stop: float, cur: np.ndarray, pos: np.ndarray, r0: int,
               r1: int) -> None:
    """Voltage steps: rows r0..r1-1 of ``cur`` and ``pos`` (kernel.step_batch)."""
    n_s = cur.shape[1]
    for r in range(r0, r1):
        p = _derive(raw[r])
        y = np.zeros(N_Y)
        # a step is one main PWM period, longer than the run, with duty 1
        big = 2.0 * duration + 1.0
        d = _drive_state(voltage[r], 1.0, big, step_time, p_sup[r], p_out[r], sample_dt, 0.0)
        out = np.zeros((n_s, N_OUT))
        avg = np.zeros(0)
        _advance(p, e, y, d, duration, h_free, h_stop, out, avg)
        for k in range(n_s):
            cur[r, k] = out[k, O_I]
            pos[r, k] = out[k, O_X]


@njit(cache=True, nogil=True)
def _pwm_rows(raw: np.ndarray, e: np.ndarray, supply_v: np.ndarray, duty: np.ndarray,
              period: np.ndarray, p_sup: np.ndarray, p_out: np.ndarray, h_free: float,
              h_stop: float, avg: np.ndarray, r0: int, r1: int) -> None:
    """PWM runs: rows r0..r1-1 of the period averages ``avg`` (kernel.pwm_batch)."""
    n_per = avg.shape[1]
    for r in range(r0, r1):
        p = _derive(raw[r])
        y = np.zeros(N_Y)
        d = _drive_state(supply_v[r], duty[r], period[r], 0.0, p_sup[r], p_out[r], _INF, 0.0)
        out = np.zeros((0, N_OUT))
        row = np.zeros(n_per)
        # one period past the last so the boundary that closes it is processed
        _advance(p, e, y, d, n_per * period[r] + 1e-9, h_free, h_stop, out, row)
        for k in range(n_per):
            avg[r, k] = row[k]


#: An input change is applied this long before its time (the event tolerance is 1 ps), so
#: a sample or a PWM period start at the same instant sees the new input, as the model's
#: own step response does (it matters with eddy currents).
_TRACE_LEAD_S = 3e-12


@njit(cache=True)
def _trace_run(raw_r: np.ndarray, e: np.ndarray, seg_t: np.ndarray, seg_vs: np.ndarray,
               seg_duty: np.ndarray, seg_period: np.ndarray, seg_psup: np.ndarray,
               seg_pout: np.ndarray, p_sup: float, p_out: float, t_samp: np.ndarray,
               h_free: float, h_stop: float, out_r: np.ndarray, stats_r: np.ndarray) -> None:
    """One run: apply the input changes and record a row of ``out_r`` per sample time.

    The gauge pressures are ``seg_psup[k]``, ``seg_pout[k]`` from ``seg_t[k]`` on when
    given (one per input), else ``p_sup``, ``p_out`` throughout.
    """
    p = _derive(raw_r)
    y = np.zeros(N_Y)
    varying = seg_psup.shape[0] > 0
    if varying:
        p_sup = seg_psup[0]
        p_out = seg_pout[0]
    d = _drive_state(seg_vs[0], seg_duty[0], seg_period[0], 0.0, p_sup, p_out, _INF, 0.0)
    no_samples = np.zeros((0, N_OUT))
    no_avg = np.zeros(0)
    n_seg = seg_t.shape[0]
    s = 1
    for k in range(t_samp.shape[0]):
        t_k = t_samp[k]
        while s < n_seg and seg_t[s] - _TRACE_LEAD_S < t_k:
            _advance(p, e, y, d, seg_t[s] - _TRACE_LEAD_S, h_free, h_stop, no_samples, no_avg)
            d[D_VS] = seg_vs[s]
            if varying:  # (each _advance takes the pressure force at its start)
                d[D_PSUP] = seg_psup[s]
                d[D_POUT] = seg_pout[s]
            _command(seg_t[s], d, e, seg_duty[s], seg_period[s])
            s += 1
        _advance(p, e, y, d, t_k, h_free, h_stop, no_samples, no_avg)
        _record(d[D_T], y, p, d, e, out_r)  # writes row D_SAMPLE_IDX = k
    stats_r[0] = d[D_N_STEPS]
    stats_r[1] = d[D_N_FORCED]


@njit(cache=True, nogil=True)
def _trace_rows(raw: np.ndarray, e: np.ndarray, seg_t: np.ndarray, seg_vs: np.ndarray,
                seg_duty: np.ndarray, seg_period: np.ndarray, seg_psup: np.ndarray,
                seg_pout: np.ndarray, p_sup: np.ndarray, p_out: np.ndarray,
                t_samp: np.ndarray, h_free: float, h_stop: float, out: np.ndarray,
                stats: np.ndarray, r0: int, r1: int) -> None:
    """Trace runs: rows r0..r1-1 of ``out`` and ``stats`` (kernel.trace_batch)."""
    for r in range(r0, r1):
        _trace_run(raw[r], e, seg_t, seg_vs, seg_duty, seg_period, seg_psup, seg_pout,
                   p_sup[r], p_out[r], t_samp, h_free, h_stop, out[r], stats[r])


# --------------------------------------------------------------------------------------
# Banks of streaming valves (model.bank.ValveBank): one compiled call advances or samples
# every valve of a bank. Here for the same reason as the batches (numba's cache tracks
# only the defining file). Each valve runs exactly the single-valve code path (_advance
# on its own row), so a bank valve is bit-identical to a ValveStepper.
# --------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def _bank_advance(p: np.ndarray, e: np.ndarray, y: np.ndarray, d: np.ndarray,
                  t_end: np.ndarray, h_free: float, h_stop: float) -> None:
    """Advance row r of (p, e, y, d) to ``t_end[r]`` (rows already there are left alone)."""
    no_out = np.zeros((0, N_OUT))
    no_avg = np.zeros(0)
    for r in range(p.shape[0]):
        if t_end[r] > d[r, D_T]:
            _advance(p[r], e[r], y[r], d[r], t_end[r], h_free, h_stop, no_out, no_avg)


@njit(cache=True, nogil=True)
def _bank_sample(p: np.ndarray, e: np.ndarray, y: np.ndarray, d: np.ndarray,
                 orifice: np.ndarray, atmosphere_pa: float, iv: np.ndarray,
                 out: np.ndarray) -> None:
    """Row r of ``out`` (columns ``S_*``): the state of valve r now, as ValveStepper.sample.

    ``orifice[r]`` = (C_d, C_A, T, R, gamma) of valve r; the flow is eq. (12) from the
    period-average position, gauge pressures made absolute with ``atmosphere_pa``. The
    interval means end valve r's interval ``iv[r]`` (``IV_*``) if its time has advanced
    (ValveStepper.interval_means); before its first interval ends, the instantaneous values.
    """
    for r in range(p.shape[0]):
        dr = d[r]
        t = dr[D_T]
        phase = int(dr[D_PHASE])
        out[r, S_T] = t
        out[r, S_V], out[r, S_I] = _terminal_at(_voltage(t, phase, dr, e[r]), y[r], phase,
                                                p[r], e[r])
        out[r, S_X] = y[r, Y_X]
        out[r, S_XDOT] = y[r, Y_V]
        x_avg = dr[D_XAVG]
        out[r, S_XAVG] = x_avg
        up = dr[D_PSUP] + atmosphere_pa
        down = dr[D_POUT] + atmosphere_pa
        sign = 1.0
        if down > up:
            up, down, sign = down, up, -1.0
        o = orifice[r]
        out[r, S_FLOW] = sign * _mass_flow(x_avg, up, down, o[0], o[1], o[2], o[3], o[4])
        out[r, S_DUTY] = dr[D_DUTY]
        out[r, S_FREQ] = 1.0 / dr[D_PERIOD]
        out[r, S_PSUP] = dr[D_PSUP]
        out[r, S_POUT] = dr[D_POUT]
        out[r, S_DT] = y[r, Y_DT]
        w = iv[r]
        if t > w[IV_T0]:
            width = t - w[IV_T0]
            w[IV_I] = (dr[D_QI] - w[IV_QI0]) / width
            w[IV_V] = (dr[D_QV] - w[IV_QV0]) / width
            w[IV_T0] = t
            w[IV_QI0] = dr[D_QI]
            w[IV_QV0] = dr[D_QV]
            w[IV_DONE] = 1.0
        if w[IV_DONE] != 0.0:
            out[r, S_I_MEAN] = w[IV_I]
            out[r, S_V_MEAN] = w[IV_V]
        else:
            out[r, S_I_MEAN] = out[r, S_I]
            out[r, S_V_MEAN] = out[r, S_V]


# --------------------------------------------------------------------------------------
# Numba's cache checks only this file: a cache built from other kernel sources is dropped
# --------------------------------------------------------------------------------------
def _drop_stale_cache() -> None:
    """Remove this module's numba cache if it was built from other kernel sources.

    The key of every kernel source (:func:`~valve_model_pkg.model.aot.kernel_key`: the
    layouts in kernel.py, the physics modules, ...) is kept next to the cache; a cache of
    another key is removed, so the functions compile afresh on their first call.
    """
    from pathlib import Path

    from .aot import kernel_key

    cache_path = getattr(getattr(_advance, '_cache', None), '_cache_path', None)
    if cache_path is None:  # a numba without this attribute: its own check only
        return
    cache_dir = Path(cache_path)
    stamp = cache_dir / 'kernel_jit.key'
    key = kernel_key()
    try:
        if stamp.read_text(encoding='ascii') == key:
            return
    except OSError:
        pass
    for pattern in ('kernel_jit.*.nbi', 'kernel_jit.*.nbc'):
        for path in cache_dir.glob(pattern):
            path.unlink(missing_ok=True)
    try:
        cache_dir.mkdir(parents=True, exist_ok=True)
        stamp.write_text(key, encoding='ascii')
    except OSError:  # a read-only installation: numba's own check only
        pass


_drop_stale_cache()
