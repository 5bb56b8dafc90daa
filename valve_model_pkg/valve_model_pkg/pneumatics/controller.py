"""Position controller for the pneumatic cylinder that commands mass flow, not duty.

This is the "higher-level pneumatic position controller" the suite is built for: it
thinks in mass flow and leaves duty, dead band and PWM frequency to flow_to_duty. Two
structures (``ControllerGains.structure``):

``'cascade'`` (default; used whenever the chamber pressure is measured) -- a position loop
that asks for a chamber pressure, and a pressure loop that asks for the mass flow which
moves the chamber there, built on the plant model (the C-equations of ``cylinder.py``):

    F_ref = k y_ref + F_0 + F_load + K_y e + K_i integral(e) - D v,   e = y_ref - y,
    p_ref = p_atm + F_ref / A_p                                  (force balance, C4)
    m_cmd = m_bleed(p) + A_p p v / (R T)                         (what holds p: C2, C3)
            + V(y) / (n R T) (p_ref - p) / tau_p                 (first-order approach)

clamped to [0, m_max]. The first line is a model-based feed-forward (the pressure that
holds the piston at y_ref against spring and load) plus PID on position in newtons; the
last two lines invert the chamber's pressure equation (C2) with the bleed (C3) and the
volume change, so the pressure follows p_ref with the time constant tau_p whatever the
chamber volume. The stiff loop (K_y much larger than the spring) pushes through the
Coulomb friction, which would otherwise leave a band of F_c / k = 5 mm; the integrator
removes what is left. Why not PID on position alone: the flow that holds a pressure and
the gain from flow to position change several-fold over the stroke (volume, bleed), so one
set of flow gains overshoots the long steps or leaves the short ones unsettled; the
pressure loop makes the plant seen by the position loop nearly the same everywhere.

``'pid'`` (the earlier law; used when no pressure is given) -- PID on position in mass flow
with a bleed feed-forward:

    m_cmd = m_ff(y_ref) + K_p e + K_i integral(e) - K_d v,
    m_ff(y_ref) = bleed flow at the pressure that holds the piston at y_ref (C3, C4).

In both the integrator stops while the output is clamped in the direction of the error
(conditional integration), so a long saturated move does not wind it up.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from valve_model_pkg.model.constants import ATMOSPHERIC_PRESSURE_PA
from valve_model_pkg.pneumatics.cylinder import CylinderParameters

__all__ = ['ControllerGains', 'PositionController', 'STRUCTURES']

#: The control laws :class:`PositionController` implements.
STRUCTURES = ('cascade', 'pid')


@dataclass(frozen=True)
class ControllerGains:
    """Gains and limits of the flow-commanding position controller (SI units).

    ``kp_kg_s_per_m``, ``ki_kg_s_per_m_s``, ``kd_kg_per_m`` are the flow PID's (structure
    ``'pid'``); ``stiffness_n_per_m``, ``integral_n_per_m_s``, ``damping_n_s_per_m`` and
    ``pressure_time_constant_s`` the cascade's (position error -> force -> pressure ->
    flow).
    """

    kp_kg_s_per_m: float = 0.04
    ki_kg_s_per_m_s: float = 0.04
    kd_kg_per_m: float = 0.004
    max_mass_flow_kg_s: float = 2.0e-3
    feedforward: bool = True
    structure: str = 'cascade'
    stiffness_n_per_m: float = 3000.0
    integral_n_per_m_s: float = 20000.0
    damping_n_s_per_m: float = 250.0
    pressure_time_constant_s: float = 0.08
    # Wider than the friction band F_c / K_y (5 N / 3000 N/m = 1.7 mm): a piston that sticks
    # in that band outside the zone would never get the integral and stay ~2 mm off (seen
    # with the CAN backend's valve); inside 3 mm the integral removes it.
    integral_zone_m: float = 0.003

    def __post_init__(self) -> None:
        for name in ('kp_kg_s_per_m', 'ki_kg_s_per_m_s', 'kd_kg_per_m', 'max_mass_flow_kg_s',
                     'stiffness_n_per_m', 'integral_n_per_m_s', 'damping_n_s_per_m',
                     'integral_zone_m'):
            value = getattr(self, name)
            if not math.isfinite(value) or value < 0.0:
                raise ValueError(f'controller gain {name} = {value!r} must be finite and >= 0')
        tau = self.pressure_time_constant_s
        if not math.isfinite(tau) or tau <= 0.0:
            raise ValueError(f'controller gain pressure_time_constant_s = {tau!r} must be '
                             'finite and > 0')
        if self.structure not in STRUCTURES:
            raise ValueError(f'controller structure {self.structure!r}: expected one of '
                             f'{", ".join(STRUCTURES)}')


class PositionController:
    """Position control in mass flow; call :meth:`update` at a fixed rate."""

    def __init__(self, gains: ControllerGains | None = None,
                 plant: CylinderParameters | None = None) -> None:
        self.gains = gains or ControllerGains()
        self.plant = plant or CylinderParameters()
        self.integral_m_s = 0.0
        self.last_feedforward_kg_s = 0.0
        self.last_pressure_reference_pa = math.nan

    def reset(self) -> None:
        """Forget the integral (e.g. after a manual move)."""
        self.integral_m_s = 0.0

    def feedforward_kg_s(self, setpoint_m: float) -> float:
        """Mass flow that balances the bleed at the setpoint's equilibrium pressure."""
        if not self.gains.feedforward:
            return 0.0
        return self.plant.bleed_mass_flow_kg_s(self.plant.equilibrium_pressure_pa(setpoint_m))

    def update(self, setpoint_m: float, position_m: float, velocity_m_s: float,
               dt_s: float, pressure_pa: float | None = None) -> float:
        """One control step; returns the mass-flow command [kg/s] in [0, max].

        ``pressure_pa`` is the measured chamber pressure (absolute [Pa]); with it and the
        ``'cascade'`` structure the pressure loop runs, without it the flow PID.
        """
        for name, value in (('setpoint_m', setpoint_m), ('position_m', position_m),
                            ('velocity_m_s', velocity_m_s), ('dt_s', dt_s)):
            if not math.isfinite(value):
                raise ValueError(f'{name} = {value!r} is not finite')
        if pressure_pa is not None and not math.isfinite(pressure_pa):
            raise ValueError(f'pressure_pa = {pressure_pa!r} is not finite')
        if self.gains.structure == 'cascade' and pressure_pa is not None:
            unclamped, error = self._cascade(setpoint_m, position_m, velocity_m_s, pressure_pa)
        else:
            unclamped, error = self._pid(setpoint_m, position_m, velocity_m_s)
        g = self.gains
        command = min(max(unclamped, 0.0), g.max_mass_flow_kg_s)
        saturated_with_error = (unclamped > g.max_mass_flow_kg_s and error > 0.0) or \
            (unclamped < 0.0 and error < 0.0)
        # The cascade integrates only near the setpoint: during a long move the stiff
        # proportional part does the work, and an integral gathered on the way overshoots.
        far = self.gains.structure == 'cascade' and pressure_pa is not None \
            and abs(error) > self.gains.integral_zone_m
        if not saturated_with_error and not far:
            self.integral_m_s += error * dt_s
        return command

    def _pid(self, setpoint_m: float, position_m: float, velocity_m_s: float
             ) -> tuple[float, float]:
        g = self.gains
        error = setpoint_m - position_m
        ff = self.feedforward_kg_s(setpoint_m)
        self.last_feedforward_kg_s = ff
        return (ff + g.kp_kg_s_per_m * error + g.ki_kg_s_per_m_s * self.integral_m_s
                - g.kd_kg_per_m * velocity_m_s), error

    def _cascade(self, setpoint_m: float, position_m: float, velocity_m_s: float,
                 pressure_pa: float) -> tuple[float, float]:
        g, par = self.gains, self.plant
        error = setpoint_m - position_m
        area = par.piston_area_m2
        hold = par.spring_stiffness_n_per_m * setpoint_m + par.spring_preload_n \
            + par.load_force_n if g.feedforward else 0.0
        force = hold + g.stiffness_n_per_m * error + g.integral_n_per_m_s * self.integral_m_s \
            - g.damping_n_s_per_m * velocity_m_s
        p_ref = ATMOSPHERIC_PRESSURE_PA + max(force, 0.0) / area
        self.last_pressure_reference_pa = p_ref
        rt = par.gas_constant_j_per_kg_k * par.temperature_k
        volume = par.dead_volume_m3 + area * min(max(position_m, 0.0), par.stroke_m)
        p = max(pressure_pa, 1.0)
        holding = par.bleed_mass_flow_kg_s(p) + area * p * velocity_m_s / rt      # C2, C3
        self.last_feedforward_kg_s = holding
        approach = volume / (par.polytropic_exponent * rt) * (p_ref - p) \
            / g.pressure_time_constant_s
        return holding + approach, error


class DoublePositionController:
    """The cascade for the double-acting cylinder: one controller, two 3/2 valves.

    The position loop is the single cylinder's (force reference with the model-based
    feed-forward of spring and load, PID in newtons); the force is split into two chamber
    pressure references around a mean gauge pressure ``g_0`` (half the supply)::

        g_r = g_0 - F_ref / (2 A_r),   g_c = g_0 A_r / A_c + F_ref / (2 A_c)
        so that A_c g_c - A_r g_r = F_ref                                  (D5)

    (clamped to [0, supply]; when one is clamped the other takes the whole force), which
    keeps both chambers pressurised, so the axis is stiff in both directions. Each
    chamber's pressure loop asks for the net flow that moves it to its reference with the
    time constant tau_p, with its volume change (D4); :func:`three_way_fill_flow` turns
    that net flow into the supply-seat flow the chamber's ``flow_to_duty`` maps to a duty.

    Parameters
    ----------
    gains : ControllerGains | None
        The cascade's gains (``structure`` is ignored: the two-valve law is a cascade).
    plant : CylinderParameters | None
        The cylinder's parameters (as the plant's).
    valve : ValveParameters | None
        The 3/2 valves' parameters (for the fill-flow inverse); default: the paper's.
    rod_diameter_m : float
        Piston rod diameter [m].
    supply_pressure_pa : float
        Supply pressure, gauge [Pa].
    """

    names = ('cap', 'rod')

    def __init__(self, gains: ControllerGains | None = None,
                 plant: CylinderParameters | None = None, valve=None,
                 rod_diameter_m: float | None = None,
                 supply_pressure_pa: float = 4e5) -> None:
        from valve_model_pkg.model import load_parameters
        from valve_model_pkg.pneumatics.double_cylinder import (DEFAULT_ROD_DIAMETER_M,
                                                                chamber_areas_m2)
        self.gains = gains or ControllerGains(stiffness_n_per_m=6000.0,
                                              integral_n_per_m_s=40000.0,
                                              damping_n_s_per_m=300.0,
                                              pressure_time_constant_s=0.04)
        self.plant = plant or CylinderParameters()
        self.valve = valve or load_parameters()
        self.rod_diameter_m = rod_diameter_m or DEFAULT_ROD_DIAMETER_M
        self.cap_area_m2, self.rod_area_m2 = chamber_areas_m2(self.plant, self.rod_diameter_m)
        self.supply_pressure_pa = float(supply_pressure_pa)
        self.integral_m_s = 0.0
        self.last_pressure_references_pa: dict[str, float] = {}

    def reset(self) -> None:
        """Forget the integral."""
        self.integral_m_s = 0.0

    def pressure_references_pa(self, force_n: float) -> tuple[float, float]:
        """(g_c, g_r): gauge chamber pressures that give the net force ``force_n`` (D5)."""
        ac, ar, ps = self.cap_area_m2, self.rod_area_m2, self.supply_pressure_pa
        g0 = 0.5 * ps
        gr = g0 - force_n / (2.0 * ar)
        gc = g0 * ar / ac + force_n / (2.0 * ac)
        if gr < 0.0 or gc > ps:      # pushing hard: rod side vents, cap side takes it
            gr = min(max(gr, 0.0), ps)
            gc = (force_n + ar * gr) / ac
        if gc < 0.0 or gr > ps:      # pulling hard: cap side vents, rod side takes it
            gc = min(max(gc, 0.0), ps)
            gr = (ac * gc - force_n) / ar
        return min(max(gc, 0.0), ps), min(max(gr, 0.0), ps)

    def update(self, setpoint_m: float, position_m: float, velocity_m_s: float, dt_s: float,
               cap_pressure_pa: float, rod_pressure_pa: float) -> dict[str, float]:
        """One control step; returns the supply-flow command of each valve [kg/s].

        Pressures are absolute [Pa].
        """
        for name, value in (('setpoint_m', setpoint_m), ('position_m', position_m),
                            ('velocity_m_s', velocity_m_s), ('dt_s', dt_s),
                            ('cap_pressure_pa', cap_pressure_pa),
                            ('rod_pressure_pa', rod_pressure_pa)):
            if not math.isfinite(value):
                raise ValueError(f'{name} = {value!r} is not finite')
        from valve_model_pkg.pneumatics.double_cylinder import three_way_fill_flow
        g, par = self.gains, self.plant
        error = setpoint_m - position_m
        hold = par.spring_stiffness_n_per_m * setpoint_m + par.spring_preload_n \
            + par.load_force_n if g.feedforward else 0.0
        force = hold + g.stiffness_n_per_m * error + g.integral_n_per_m_s * self.integral_m_s \
            - g.damping_n_s_per_m * velocity_m_s
        gc, gr = self.pressure_references_pa(force)
        refs = {'cap': gc + ATMOSPHERIC_PRESSURE_PA, 'rod': gr + ATMOSPHERIC_PRESSURE_PA}
        self.last_pressure_references_pa = refs
        rt = par.gas_constant_j_per_kg_k * par.temperature_k
        y = min(max(position_m, 0.0), par.stroke_m)
        chambers = {'cap': (cap_pressure_pa, self.cap_area_m2,
                            par.dead_volume_m3 + self.cap_area_m2 * y, velocity_m_s),
                    'rod': (rod_pressure_pa, self.rod_area_m2,
                            par.dead_volume_m3 + self.rod_area_m2 * (par.stroke_m - y),
                            -velocity_m_s)}
        supply_abs = self.supply_pressure_pa + ATMOSPHERIC_PRESSURE_PA
        out = {}
        saturated = False
        for name, (p, area, volume, growth) in chambers.items():
            p = max(p, 1.0)
            net = area * p * growth / rt + volume / (par.polytropic_exponent * rt) \
                * (refs[name] - p) / g.pressure_time_constant_s                   # (D4)
            fill = three_way_fill_flow(net, supply_abs, p, self.valve)
            command = min(max(fill, 0.0), g.max_mass_flow_kg_s)
            saturated |= command != fill
            out[name] = command
        # Integrate only near the setpoint and while no valve is saturated (no wind-up).
        if abs(error) <= g.integral_zone_m and not saturated:
            self.integral_m_s += error * dt_s
        return out
