"""A double-acting pneumatic cylinder with one 3/2 valve per chamber.

The second example plant. Servo-pneumatic axes with switching valves use two to four
valves; here each chamber has its own 3/2 valve (valve namespaces ``cap`` and ``rod``):
energised (spool open) it connects its chamber to the supply, de-energised it vents the
chamber to atmosphere. The spool's travel x in [0, x_max] opens the supply seat by x and
the exhaust seat by x_max - x, so at every PWM switch the chamber is filled or vented,
and a duty between 0 and 1 holds a pressure between atmosphere and supply.

State: cap and rod chamber pressures p_c, p_r (absolute, Pa), piston position y (m,
0 = retracted) and velocity v (m/s). Equations (D-numbers; C-numbers are those of
:mod:`valve_model_pkg.pneumatics.cylinder`, which this plant shares):

- areas                        A_c = pi D^2 / 4,  A_r = A_c - pi d^2 / 4            (D1)
- volumes                      V_c = V_0 + A_c y,  V_r = V_0 + A_r (L - y)           (D2)
- valve flow into chamber i    m_i = eq. (12)(x_i, p_sup, p_i) - eq. (12)(x_max - x_i,
                               p_i, p_atm); reversed branches if p_i > p_sup          (D3)
- chamber pressures            dp_c/dt = n / V_c (R T m_c - p_c A_c v)
                               dp_r/dt = n / V_r (R T m_r + p_r A_r v)               (D4)
- piston                       M dv/dt = (p_c - p_atm) A_c - (p_r - p_atm) A_r
                                         - (k y + F_0) - F_load - F_f                 (D5)

friction (C5) and end stops (C6) as in the single-acting cylinder; the spring of the
parameters acts if it is set (the demo keeps the single cylinder's parameters, so the
axis has the same return spring); the bleed restrictor is not part of this plant (the
3/2 valves vent the chambers).

:func:`three_way_fill_flow` is the inverse the controller uses to turn a net chamber
flow into the supply flow ``flow_to_duty`` maps to a duty (the static duty map is the
supply seat's flow).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from valve_model_pkg.model.constants import ATMOSPHERIC_PRESSURE_PA
from valve_model_pkg.model.orifice import mass_flow_absolute as _mass_flow
from valve_model_pkg.model.parameters import ValveParameters
from valve_model_pkg.pneumatics.cylinder import CylinderParameters

__all__ = ['DoubleCylinder', 'DoubleCylinderState', 'DEFAULT_ROD_DIAMETER_M',
           'three_way_flow', 'three_way_fill_flow', 'chamber_areas_m2']

#: Piston rod diameter of the example (a 25 mm bore cylinder's usual 10 mm rod) [m].
DEFAULT_ROD_DIAMETER_M = 0.010


def chamber_areas_m2(params: CylinderParameters,
                     rod_diameter_m: float = DEFAULT_ROD_DIAMETER_M) -> tuple[float, float]:
    """(A_c, A_r) [m^2]: cap-side piston area and rod-side annulus (D1)."""
    cap = params.piston_area_m2
    return cap, cap - math.pi * rod_diameter_m ** 2 / 4.0


def _orifice(x: float, p_up: float, p_down: float, v: ValveParameters) -> float:
    """eq. (12) from p_up to p_down (absolute) at opening x; negative if reversed."""
    if x <= 0.0:
        return 0.0
    if p_up >= p_down:
        return _mass_flow(x, p_up, p_down, v.discharge_coefficient, v.orifice_area_gradient_m,
                          v.supply_temperature_k, v.gas_constant_j_per_kg_k,
                          v.heat_capacity_ratio)
    return -_mass_flow(x, p_down, p_up, v.discharge_coefficient, v.orifice_area_gradient_m,
                       v.supply_temperature_k, v.gas_constant_j_per_kg_k,
                       v.heat_capacity_ratio)


def three_way_flow(opening_m: float, supply_abs_pa: float, chamber_abs_pa: float,
                   valve: ValveParameters) -> float:
    """Net mass flow into a chamber through its 3/2 valve at spool travel x [kg/s] (D3)."""
    x = min(max(opening_m, 0.0), valve.stroke_m)
    return _orifice(x, supply_abs_pa, chamber_abs_pa, valve) \
        - _orifice(valve.stroke_m - x, chamber_abs_pa, ATMOSPHERIC_PRESSURE_PA, valve)


def three_way_fill_flow(net_kg_s: float, supply_abs_pa: float, chamber_abs_pa: float,
                        valve: ValveParameters) -> float:
    """Supply-seat flow [kg/s] of the duty whose PWM average gives ``net_kg_s`` into the chamber.

    Over a PWM period with duty d the valve is (about) a fraction d of the time open to
    the supply and 1 - d to the exhaust: net = d F_in - (1 - d) F_out, with F_in, F_out
    the fully open seats' flows (D3). So d = (net + F_out) / (F_in + F_out), and the
    supply flow at that duty, which the static duty map turns back into d, is d F_in.
    """
    f_in = max(_orifice(valve.stroke_m, supply_abs_pa, chamber_abs_pa, valve), 0.0)
    f_out = max(_orifice(valve.stroke_m, chamber_abs_pa, ATMOSPHERIC_PRESSURE_PA, valve), 0.0)
    if f_in + f_out <= 0.0:
        return 0.0
    duty = min(max((net_kg_s + f_out) / (f_in + f_out), 0.0), 1.0)
    return duty * f_in


@dataclass
class DoubleCylinderState:
    """Cap and rod chamber pressures (absolute, Pa), position (m), velocity (m/s)."""

    cap_pressure_pa: float = ATMOSPHERIC_PRESSURE_PA
    rod_pressure_pa: float = ATMOSPHERIC_PRESSURE_PA
    position_m: float = 0.0
    velocity_m_s: float = 0.0

    @property
    def pressure_pa(self) -> float:
        """The cap chamber's pressure (the chamber that extends the piston)."""
        return self.cap_pressure_pa


class DoubleCylinder:
    """The double-acting plant: advance it with both valves' openings.

    Parameters
    ----------
    params : CylinderParameters | None
        Bore, stroke, dead volume (of each chamber), mass, spring, load, friction, gas.
    valve_params : ValveParameters
        The 3/2 valves' orifice (both valves alike).
    rod_diameter_m : float
        Piston rod diameter [m].
    """

    def __init__(self, params: CylinderParameters | None = None,
                 valve_params: ValveParameters | None = None,
                 rod_diameter_m: float = DEFAULT_ROD_DIAMETER_M) -> None:
        if valve_params is None:
            raise ValueError('DoubleCylinder needs the valve parameters (valve_params=)')
        self.params = params or CylinderParameters()
        if not 0.0 < rod_diameter_m < self.params.bore_diameter_m:
            raise ValueError(f'rod_diameter_m = {rod_diameter_m!r} must lie in (0, bore)')
        self.rod_diameter_m = float(rod_diameter_m)
        self.cap_area_m2, self.rod_area_m2 = chamber_areas_m2(self.params, rod_diameter_m)
        self._valve = valve_params
        self.state = DoubleCylinderState()
        self._openings = {'cap': 0.0, 'rod': 0.0}
        self._supply_abs_pa = ATMOSPHERIC_PRESSURE_PA
        self.last_valve_flows_kg_s = {'cap': 0.0, 'rod': 0.0}
        self.t_s = 0.0

    def chamber_gauge_pressure_pa(self, name: str) -> float:
        """Gauge pressure [Pa] of chamber ``'cap'`` or ``'rod'``."""
        p = self.state.cap_pressure_pa if name == 'cap' else self.state.rod_pressure_pa
        return p - ATMOSPHERIC_PRESSURE_PA

    def net_pressure_force_n(self) -> float:
        """Net pressure force on the piston, extending positive [N] (D5)."""
        s = self.state
        return (s.cap_pressure_pa - ATMOSPHERIC_PRESSURE_PA) * self.cap_area_m2 \
            - (s.rod_pressure_pa - ATMOSPHERIC_PRESSURE_PA) * self.rod_area_m2

    def _derivatives(self, pc: float, pr: float, y: float, v: float
                     ) -> tuple[float, float, float, float]:
        par, valve = self.params, self._valve
        rt = par.gas_constant_j_per_kg_k * par.temperature_k
        mc = three_way_flow(self._openings['cap'], self._supply_abs_pa, pc, valve)   # (D3)
        mr = three_way_flow(self._openings['rod'], self._supply_abs_pa, pr, valve)
        vc = par.dead_volume_m3 + self.cap_area_m2 * y                                # (D2)
        vr = par.dead_volume_m3 + self.rod_area_m2 * (par.stroke_m - y)
        n = par.polytropic_exponent
        dpc = n / vc * (rt * mc - pc * self.cap_area_m2 * v)                          # (D4)
        dpr = n / vr * (rt * mr + pr * self.rod_area_m2 * v)
        drive = (pc - ATMOSPHERIC_PRESSURE_PA) * self.cap_area_m2 \
            - (pr - ATMOSPHERIC_PRESSURE_PA) * self.rod_area_m2 \
            - (par.spring_stiffness_n_per_m * y + par.spring_preload_n) - par.load_force_n
        if v == 0.0 and abs(drive) <= par.coulomb_friction_n:                         # (C5)
            friction = drive
        else:
            direction = v if v != 0.0 else drive
            friction = math.copysign(par.coulomb_friction_n, direction) \
                + par.viscous_friction_n_s_per_m * v
        dv = (drive - friction) / par.moving_mass_kg                                  # (D5)
        if (y <= 0.0 and dv < 0.0 and v <= 0.0) or \
                (y >= par.stroke_m and dv > 0.0 and v >= 0.0):                        # (C6)
            dv = 0.0
        return dpc, dpr, v, dv

    def step_with_valves(self, dt_s: float, openings_m: dict[str, float],
                         supply_pressure_pa: float) -> DoubleCylinderState:
        """Advance by ``dt_s`` [s] with each valve held at its opening [m] (supply gauge Pa)."""
        for name in ('cap', 'rod'):
            value = float(openings_m[name])
            if not math.isfinite(value):
                raise ValueError(f'opening of valve {name!r} = {value!r} is not finite')
            self._openings[name] = value
        if not math.isfinite(supply_pressure_pa):
            raise ValueError(f'supply_pressure_pa = {supply_pressure_pa!r} is not finite')
        if not math.isfinite(dt_s) or dt_s < 0.0:
            raise ValueError(f'dt_s = {dt_s!r} must be a finite non-negative time')
        self._supply_abs_pa = supply_pressure_pa + ATMOSPHERIC_PRESSURE_PA
        par = self.params
        s = self.state
        x = [s.cap_pressure_pa, s.rod_pressure_pa, s.position_m, s.velocity_m_s]
        n = max(1, int(math.ceil(dt_s / par.step_s - 1e-9)))
        h = dt_s / n
        for _ in range(n):  # RK4, as the single-acting plant
            k1 = self._derivatives(*x)
            k2 = self._derivatives(*[a + h / 2 * b for a, b in zip(x, k1)])
            k3 = self._derivatives(*[a + h / 2 * b for a, b in zip(x, k2)])
            k4 = self._derivatives(*[a + h * b for a, b in zip(x, k3)])
            new = [a + h / 6 * (b + 2 * c + 2 * d + e)
                   for a, b, c, d, e in zip(x, k1, k2, k3, k4)]
            v_old = x[3]
            if v_old != 0.0 and new[3] * v_old < 0.0:
                new[3] = 0.0  # velocity reversal: (C5) decides stick or slip
            if new[2] <= 0.0:                                                         # (C6)
                new[2], new[3] = 0.0, max(new[3], 0.0)
            elif new[2] >= par.stroke_m:
                new[2], new[3] = par.stroke_m, min(new[3], 0.0)
            x = [max(new[0], 1.0), max(new[1], 1.0), new[2], new[3]]
        self.state = DoubleCylinderState(*x)
        self.t_s += dt_s
        for name, p in (('cap', x[0]), ('rod', x[1])):
            self.last_valve_flows_kg_s[name] = three_way_flow(
                self._openings[name], self._supply_abs_pa, p, self._valve)
        return self.state
