"""Position controller for the pneumatic cylinder that commands mass flow, not duty.

This is the "higher-level pneumatic position controller" the suite is built for: it
thinks in mass flow and leaves duty, dead band and PWM frequency to flow_to_duty.

    m_cmd = m_ff(y_ref) + K_p e + K_i integral(e) - K_d v,   e = y_ref - y,
    m_ff(y_ref) = bleed flow at the pressure that holds the piston at y_ref (C3, C4),

clamped to [0, m_max]. The integrator stops while the output is clamped in the direction
of the error (conditional integration), so a long saturated move does not wind it up.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from valve_model_pkg.pneumatics.cylinder import CylinderParameters

__all__ = ['ControllerGains', 'PositionController']


@dataclass(frozen=True)
class ControllerGains:
    """Gains and limits of the flow-commanding position controller (SI units)."""

    kp_kg_s_per_m: float = 0.04
    ki_kg_s_per_m_s: float = 0.04
    kd_kg_per_m: float = 0.004
    max_mass_flow_kg_s: float = 2.0e-3
    feedforward: bool = True

    def __post_init__(self) -> None:
        for name in ('kp_kg_s_per_m', 'ki_kg_s_per_m_s', 'kd_kg_per_m', 'max_mass_flow_kg_s'):
            value = getattr(self, name)
            if not math.isfinite(value) or value < 0.0:
                raise ValueError(f'controller gain {name} = {value!r} must be finite and >= 0')


class PositionController:
    """Discrete PID with bleed feedforward; call :meth:`update` at a fixed rate."""

    def __init__(self, gains: ControllerGains | None = None,
                 plant: CylinderParameters | None = None) -> None:
        self.gains = gains or ControllerGains()
        self.plant = plant or CylinderParameters()
        self.integral_m_s = 0.0
        self.last_feedforward_kg_s = 0.0

    def reset(self) -> None:
        """Forget the integral (e.g. after a manual move)."""
        self.integral_m_s = 0.0

    def feedforward_kg_s(self, setpoint_m: float) -> float:
        """Mass flow that balances the bleed at the setpoint's equilibrium pressure."""
        if not self.gains.feedforward:
            return 0.0
        return self.plant.bleed_mass_flow_kg_s(self.plant.equilibrium_pressure_pa(setpoint_m))

    def update(self, setpoint_m: float, position_m: float, velocity_m_s: float,
               dt_s: float) -> float:
        """One control step; returns the mass-flow command [kg/s] in [0, max]."""
        for name, value in (('setpoint_m', setpoint_m), ('position_m', position_m),
                            ('velocity_m_s', velocity_m_s), ('dt_s', dt_s)):
            if not math.isfinite(value):
                raise ValueError(f'{name} = {value!r} is not finite')
        g = self.gains
        error = setpoint_m - position_m
        ff = self.feedforward_kg_s(setpoint_m)
        self.last_feedforward_kg_s = ff
        unclamped = ff + g.kp_kg_s_per_m * error + g.ki_kg_s_per_m_s * self.integral_m_s \
            - g.kd_kg_per_m * velocity_m_s
        command = min(max(unclamped, 0.0), g.max_mass_flow_kg_s)
        saturated_with_error = (unclamped > g.max_mass_flow_kg_s and error > 0.0) or \
            (unclamped < 0.0 and error < 0.0)
        if not saturated_with_error:
            self.integral_m_s += error * dt_s
        return command
