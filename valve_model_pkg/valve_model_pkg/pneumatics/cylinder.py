"""A single-acting pneumatic cylinder with spring return, fed by the PWM valve.

The example plant a higher-level controller moves with the valve. The valve
fills the cap-end chamber from the supply; a fixed bleed restrictor vents the chamber to
atmosphere (with a single normally closed valve, the bleed is what lets the pressure
fall again); the rod end is open to atmosphere; a spring pushes the piston back.

State: chamber pressure p (absolute, Pa), piston position y (m, 0 = retracted),
piston velocity v (m/s). Equations (numbered C1.. to keep them apart from the paper's):

- chamber volume                 V = V_0 + A_p y                                     (C1)
- chamber pressure, polytropic   dp/dt = n / V (R T (m_in - m_bleed) - p A_p v)      (C2)
- bleed to atmosphere            m_bleed = orifice eq. (12) with C_d A_bleed,
                                 upstream p, downstream p_atm                        (C3)
- piston                         M dv/dt = (p - p_atm) A_p - (k y + F_0) - F_load - F_f (C4)
- friction                       F_f = F_c sign(v) + c v; at v = 0 the piston sticks
                                 while |net force| <= F_c (Karnopp)                   (C5)
- end stops                      0 <= y <= stroke, plastic impact (v -> 0)            (C6)

m_in is the valve's mass flow (kg/s), positive into the chamber; it may be negative if
the chamber pressure exceeds the supply (reverse flow through the open valve). Either it
is given (:meth:`Cylinder.step`), or the plant evaluates the valve's orifice, eq. (12),
at its own chamber pressure from the valve's opening (:meth:`Cylinder.step_with_valve`):

- valve flow                      m_in = eq. (12)(x, p_sup, p) with the valve's C_d, C_A,
                                  T; reversed if p > p_sup                            (C7)

The second form is what the cylinder node uses: the opening comes from valve/state at
1 kHz, and the chamber pressure that sets the flow regime is the plant's own, at every
integration step, so the stiff pressure/flow coupling is not closed through messages.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any

from valve_model_pkg.model.constants import ATMOSPHERIC_PRESSURE_PA
from valve_model_pkg.model.orifice import mass_flow_absolute as _mass_flow
from valve_model_pkg.model.parameters import ValveParameters

__all__ = ['CylinderParameters', 'CylinderState', 'Cylinder', 'PARAMETER_INFO']

#: Description, lower and upper bound of each user-settable parameter (for node parameters).
PARAMETER_INFO: dict[str, tuple[str, float, float]] = {
    'bore_diameter_m': ('Piston bore [m]', 1e-3, 0.5),
    'stroke_m': ('Stroke [m]', 1e-3, 2.0),
    'dead_volume_m3': ('Chamber volume at y = 0, incl. tubing [m^3]', 1e-9, 1e-2),
    'moving_mass_kg': ('Piston, rod and load mass [kg]', 1e-3, 1000.0),
    'spring_stiffness_n_per_m': ('Return spring stiffness [N/m]', 0.0, 1e6),
    'spring_preload_n': ('Return spring force at y = 0 [N]', -1e4, 1e4),
    'load_force_n': ('Constant external load against extension [N]', -1e4, 1e4),
    'coulomb_friction_n': ('Coulomb friction [N]', 0.0, 1e4),
    'viscous_friction_n_s_per_m': ('Viscous friction [N s/m]', 0.0, 1e5),
    'bleed_discharge_area_m2': ('C_d * A of the bleed restrictor to atmosphere [m^2]',
                                0.0, 1e-3),
    'polytropic_exponent': ('Polytropic exponent of the chamber air [1]', 1.0, 1.4),
    'temperature_k': ('Supply air temperature [K]', 200.0, 400.0),
}


@dataclass(frozen=True)
class CylinderParameters:
    """Cylinder, load and bleed. SI units; defaults: a 25 mm bore, 100 mm stroke cylinder."""

    bore_diameter_m: float = 0.025
    stroke_m: float = 0.100
    dead_volume_m3: float = 2.0e-5
    moving_mass_kg: float = 1.0
    spring_stiffness_n_per_m: float = 1000.0
    spring_preload_n: float = 20.0
    load_force_n: float = 0.0
    coulomb_friction_n: float = 5.0
    viscous_friction_n_s_per_m: float = 300.0
    bleed_discharge_area_m2: float = 0.7e-6     # C_d * A of the bleed restrictor
    polytropic_exponent: float = 1.2
    temperature_k: float = 293.15
    gas_constant_j_per_kg_k: float = 287.0
    heat_capacity_ratio: float = 1.4
    step_s: float = 1.0e-4                      # internal RK4 step

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f'cylinder parameter {f.name} = {value!r} is not a finite '
                                 'number')
        positive = ('bore_diameter_m', 'stroke_m', 'dead_volume_m3', 'moving_mass_kg',
                    'polytropic_exponent', 'temperature_k', 'gas_constant_j_per_kg_k',
                    'heat_capacity_ratio', 'step_s')
        for name in positive:
            if getattr(self, name) <= 0.0:
                raise ValueError(f'cylinder parameter {name} = {getattr(self, name)!r} must '
                                 'be > 0')
        for name in ('spring_stiffness_n_per_m', 'coulomb_friction_n',
                     'viscous_friction_n_s_per_m', 'bleed_discharge_area_m2'):
            if getattr(self, name) < 0.0:
                raise ValueError(f'cylinder parameter {name} = {getattr(self, name)!r} must '
                                 'be >= 0')

    @property
    def piston_area_m2(self) -> float:
        """A_p [m^2]."""
        return math.pi * self.bore_diameter_m ** 2 / 4.0

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CylinderParameters:
        """Build from a mapping; unknown keys are refused with their names."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f'unknown cylinder parameter(s): {", ".join(unknown)}')
        return cls(**{k: float(v) for k, v in data.items()})

    def replace(self, **changes: float) -> CylinderParameters:
        """A copy with some values changed (validated)."""
        return replace(self, **changes)

    def equilibrium_pressure_pa(self, position_m: float) -> float:
        """Absolute chamber pressure [Pa] that holds the piston still at ``position_m`` (C4)."""
        force = self.spring_stiffness_n_per_m * position_m + self.spring_preload_n \
            + self.load_force_n
        return ATMOSPHERIC_PRESSURE_PA + max(force, 0.0) / self.piston_area_m2

    def bleed_mass_flow_kg_s(self, chamber_pressure_pa: float) -> float:
        """Mass flow out through the bleed [kg/s] at an absolute chamber pressure (C3)."""
        if chamber_pressure_pa <= ATMOSPHERIC_PRESSURE_PA:
            return 0.0
        return _mass_flow(1.0, chamber_pressure_pa, ATMOSPHERIC_PRESSURE_PA,
                          self.bleed_discharge_area_m2, 1.0, self.temperature_k,
                          self.gas_constant_j_per_kg_k, self.heat_capacity_ratio)


@dataclass
class CylinderState:
    """Chamber pressure (absolute, Pa), piston position (m) and velocity (m/s)."""

    pressure_pa: float = ATMOSPHERIC_PRESSURE_PA
    position_m: float = 0.0
    velocity_m_s: float = 0.0


class Cylinder:
    """The plant: advance it with the valve's mass flow, read pressure and position.

    Parameters
    ----------
    params
        Cylinder, load and bleed parameters.
    state
        Initial state (default: retracted, at atmospheric pressure).
    valve_params
        The valve's parameters, for its orifice (C7) in :meth:`step_with_valve`.
    """

    def __init__(self, params: CylinderParameters | None = None,
                 state: CylinderState | None = None,
                 valve_params: ValveParameters | None = None) -> None:
        self.params = params or CylinderParameters()
        self.state = state or CylinderState()
        self._valve = valve_params
        self._opening_m = 0.0
        self._supply_abs_pa = ATMOSPHERIC_PRESSURE_PA
        self.last_valve_flow_kg_s = 0.0
        self.t_s = 0.0
        self.last_bleed_kg_s = 0.0

    def _valve_flow(self, p: float) -> float:
        """(C7): the valve's orifice at chamber pressure ``p`` [Pa abs]; kg/s into it."""
        x, p_sup, v = self._opening_m, self._supply_abs_pa, self._valve
        if x <= 0.0 or v is None:
            return 0.0
        if p_sup >= p:
            return _mass_flow(x, p_sup, p, v.discharge_coefficient, v.orifice_area_gradient_m,
                              v.supply_temperature_k, v.gas_constant_j_per_kg_k,
                              v.heat_capacity_ratio)
        return -_mass_flow(x, p, p_sup, v.discharge_coefficient, v.orifice_area_gradient_m,
                           v.supply_temperature_k, v.gas_constant_j_per_kg_k,
                           v.heat_capacity_ratio)

    def _derivatives(self, p: float, y: float, v: float, m_in: float | None
                     ) -> tuple[float, float, float]:
        par = self.params
        if m_in is None:
            m_in = self._valve_flow(p)                                            # (C7)
        area = par.piston_area_m2
        volume = par.dead_volume_m3 + area * y                                    # (C1)
        m_out = par.bleed_mass_flow_kg_s(p)                                       # (C3)
        dp = par.polytropic_exponent / volume * (
            par.gas_constant_j_per_kg_k * par.temperature_k * (m_in - m_out)
            - p * area * v)                                                       # (C2)
        drive = (p - ATMOSPHERIC_PRESSURE_PA) * area \
            - (par.spring_stiffness_n_per_m * y + par.spring_preload_n) - par.load_force_n
        if v == 0.0 and abs(drive) <= par.coulomb_friction_n:                     # (C5)
            friction = drive  # sticking: friction balances the drive exactly
        else:
            direction = v if v != 0.0 else drive
            friction = math.copysign(par.coulomb_friction_n, direction) \
                + par.viscous_friction_n_s_per_m * v
        dv = (drive - friction) / par.moving_mass_kg                              # (C4)
        # End stops (C6): at a stop, a force pushing into it does not move the piston.
        at_closed = y <= 0.0 and dv < 0.0 and v <= 0.0
        at_open = y >= par.stroke_m and dv > 0.0 and v >= 0.0
        if at_closed or at_open:
            dv = 0.0
        return dp, v, dv

    def step_with_valve(self, dt_s: float, opening_m: float, supply_pressure_pa: float
                        ) -> CylinderState:
        """Advance by ``dt_s`` [s] with the valve held at ``opening_m`` [m].

        The valve's flow is evaluated at the chamber pressure of every integration stage
        (C7), from the supply pressure ``supply_pressure_pa`` (gauge [Pa]) and the
        valve's orifice parameters given to the constructor.
        """
        if self._valve is None:
            raise ValueError('step_with_valve needs the valve parameters (valve_params=)')
        for name, value in (('opening_m', opening_m),
                            ('supply_pressure_pa', supply_pressure_pa)):
            if not math.isfinite(value):
                raise ValueError(f'{name} = {value!r} is not finite')
        self._opening_m = max(0.0, opening_m)
        self._supply_abs_pa = supply_pressure_pa + ATMOSPHERIC_PRESSURE_PA
        state = self._integrate(dt_s, None)
        self.last_valve_flow_kg_s = self._valve_flow(state.pressure_pa)
        return state

    def step(self, dt_s: float, valve_mass_flow_kg_s: float) -> CylinderState:
        """Advance by ``dt_s`` [s] with the valve's mass flow held constant [kg/s].

        RK4 with the internal step; stick/slip and the end stops are applied after each
        step, so a velocity that changes sign sticks instead of chattering.
        """
        if not math.isfinite(valve_mass_flow_kg_s):
            raise ValueError(f'valve mass flow {valve_mass_flow_kg_s!r} is not finite')
        self.last_valve_flow_kg_s = valve_mass_flow_kg_s
        return self._integrate(dt_s, valve_mass_flow_kg_s)

    def _integrate(self, dt_s: float, valve_mass_flow_kg_s: float | None) -> CylinderState:
        if not math.isfinite(dt_s) or dt_s < 0.0:
            raise ValueError(f'dt_s = {dt_s!r} must be a finite non-negative time')
        par = self.params
        s = self.state
        p, y, v = s.pressure_pa, s.position_m, s.velocity_m_s
        n = max(1, int(math.ceil(dt_s / par.step_s - 1e-9)))
        h = dt_s / n
        for _ in range(n):
            k1 = self._derivatives(p, y, v, valve_mass_flow_kg_s)
            k2 = self._derivatives(p + h / 2 * k1[0], y + h / 2 * k1[1], v + h / 2 * k1[2],
                                   valve_mass_flow_kg_s)
            k3 = self._derivatives(p + h / 2 * k2[0], y + h / 2 * k2[1], v + h / 2 * k2[2],
                                   valve_mass_flow_kg_s)
            k4 = self._derivatives(p + h * k3[0], y + h * k3[1], v + h * k3[2],
                                   valve_mass_flow_kg_s)
            p_new = p + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
            y_new = y + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
            v_new = v + h / 6 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
            if v != 0.0 and v_new * v < 0.0:
                v_new = 0.0  # velocity reversal: stop here, (C5) decides stick or slip
            if y_new <= 0.0:                                                      # (C6)
                y_new, v_new = 0.0, max(v_new, 0.0)
            elif y_new >= par.stroke_m:
                y_new, v_new = par.stroke_m, min(v_new, 0.0)
            p, y, v = max(p_new, 1.0), y_new, v_new
        self.state = CylinderState(p, y, v)
        self.t_s += dt_s
        self.last_bleed_kg_s = par.bleed_mass_flow_kg_s(p)
        return self.state

    def net_pressure_force_n(self) -> float:
        """Net pressure force on the piston [N] (what joint_states carries as effort)."""
        return (self.state.pressure_pa - ATMOSPHERIC_PRESSURE_PA) * self.params.piston_area_m2

    @property
    def chamber_gauge_pressure_pa(self) -> float:
        """Chamber pressure, gauge [Pa]: the valve's output pressure."""
        return self.state.pressure_pa - ATMOSPHERIC_PRESSURE_PA
