"""A simulated servo-pneumatic axis: the valve model(s) and the cylinder, stepped together.

The one piece of plant code the lockstep simulation node (``valve_lockstep_sim``) and the
ROS-free closed-loop simulation (:mod:`valve_model_pkg.pneumatics.closed_loop`) share, so
what the offline tests show is what the demo runs. Each :meth:`SimulatedAxis.step`:

1. gives every valve the supply pressure and its chamber's pressure as output pressure
   (the valve's flow regime and pressure force, eq. 12 and eqs. 9-11),
2. advances every valve model to the end of the step (exact PWM and chopper edges),
3. integrates the cylinder over the step with each valve held at its opening at the end
   of the step (the cylinder evaluates the valve orifices at its own chamber pressures at
   every integration stage, C7), as the closed-loop tuning always did.

Time is kept as an integer number of nanoseconds, so a step never drifts and the ticks of
a run are the same in every run.
"""
from __future__ import annotations

from valve_model_pkg.model import ElectronicsConfig, ValveParameters, ValveSample, \
    ValveStepper, load_parameters
from valve_model_pkg.pneumatics.cylinder import Cylinder, CylinderParameters

__all__ = ['SimulatedAxis', 'CYLINDER_KINDS', 'DOUBLE_VALVES', 'valve_names']

#: The cylinders an axis can carry.
CYLINDER_KINDS = ('single', 'double')
#: The valve namespaces of the double-acting cylinder: one 3/2 valve per chamber.
DOUBLE_VALVES = ('cap', 'rod')


def valve_names(kind: str) -> tuple[str, ...]:
    """The valve namespaces of a cylinder kind ('' = the topics without a namespace)."""
    if kind == 'single':
        return ('',)
    if kind == 'double':
        return DOUBLE_VALVES
    raise ValueError(f'cylinder kind {kind!r}: expected one of {", ".join(CYLINDER_KINDS)}')


class SimulatedAxis:
    """Valve model(s) + cylinder, advanced in fixed steps of ``step_ns``.

    Parameters
    ----------
    kind : str
        ``'single'``: single-acting cylinder, one 2/2 valve filling it, a bleed venting it.
        ``'double'``: double-acting cylinder, one 3/2 valve per chamber (``'cap'``,
        ``'rod'``), each filling its chamber when open and venting it when closed.
    step_ns : int
        Step [ns].
    valve, plant : parameters of the valve(s) and the cylinder (default: paper, defaults).
    supply_pressure_pa : float
        Supply pressure, gauge [Pa].
    pwm_frequency_hz : float
        Initial main PWM frequency of every valve [Hz] (duty 0).
    electronics : ElectronicsConfig | None
        Drive electronics (default: all on).
    supply_voltage_v : float
        Drive supply [V].
    initial_position_m : float
        Initial piston position [m].
    """

    def __init__(self, kind: str = 'single', *, step_ns: int = 1_000_000,
                 valve: ValveParameters | None = None,
                 plant: CylinderParameters | None = None,
                 supply_pressure_pa: float = 4e5, pwm_frequency_hz: float = 50.0,
                 electronics: ElectronicsConfig | None = None,
                 supply_voltage_v: float = 24.0, initial_position_m: float = 0.0) -> None:
        if step_ns <= 0:
            raise ValueError(f'step_ns = {step_ns!r} must be > 0')
        self.kind = kind
        self.names = valve_names(kind)
        self.valve = valve or load_parameters()
        self.step_ns = int(step_ns)
        self.supply_pressure_pa = float(supply_pressure_pa)
        electronics = electronics or ElectronicsConfig()
        self.steppers: dict[str, ValveStepper] = {}
        for name in self.names:
            stepper = ValveStepper(self.valve, electronics, supply_voltage_v=supply_voltage_v,
                                   supply_pressure_pa=supply_pressure_pa)
            stepper.set_command(0.0, pwm_frequency_hz)
            self.steppers[name] = stepper
        if kind == 'single':
            self.cylinder: Cylinder = Cylinder(plant, valve_params=self.valve)
        else:
            from valve_model_pkg.pneumatics.double_cylinder import DoubleCylinder
            self.cylinder = DoubleCylinder(plant, valve_params=self.valve)
        state = self.cylinder.state
        state.position_m = float(initial_position_m)
        self.steps = 0
        self._samples = {name: s.sample() for name, s in self.steppers.items()}

    @property
    def t_ns(self) -> int:
        """Simulated time [ns] (the end of the last step)."""
        return self.steps * self.step_ns

    @property
    def plant_params(self) -> CylinderParameters:
        """The cylinder's parameters."""
        return self.cylinder.params

    def set_command(self, name: str, duty: float, pwm_frequency_hz: float) -> None:
        """Command valve ``name``; it takes effect at its next main PWM period start."""
        self.steppers[name].set_command(duty, pwm_frequency_hz)

    def chamber_gauge_pressure_pa(self, name: str) -> float:
        """Gauge pressure [Pa] of the chamber valve ``name`` feeds (its output pressure)."""
        if self.kind == 'single':
            return self.cylinder.chamber_gauge_pressure_pa
        return self.cylinder.chamber_gauge_pressure_pa(name)

    def sample(self, name: str) -> ValveSample:
        """The valve's state at the end of the last step."""
        return self._samples[name]

    def step_with_openings(self, openings_m: dict[str, float]) -> None:
        """Advance the cylinder by one step with valve openings from elsewhere [m].

        For a valve that runs in another process (the CAN backend's controller emulator on
        the simulation clock): the openings are the valves' at the end of the step, as in
        :meth:`step`; this axis's own valve models are not advanced.
        """
        dt = self.step_ns * 1e-9
        if self.kind == 'single':
            self.cylinder.step_with_valve(dt, openings_m[''], self.supply_pressure_pa)
        else:
            self.cylinder.step_with_valves(dt, openings_m, self.supply_pressure_pa)
        self.steps += 1

    def step(self) -> None:
        """Advance valves and cylinder by one step."""
        t_end = (self.steps + 1) * self.step_ns * 1e-9
        openings = {}
        for name, stepper in self.steppers.items():
            stepper.set_pressures(self.supply_pressure_pa, self.chamber_gauge_pressure_pa(name))
            stepper.advance_to(t_end)
            sample = stepper.sample()
            self._samples[name] = sample
            openings[name] = sample.spool_position_m
        dt = self.step_ns * 1e-9
        if self.kind == 'single':
            self.cylinder.step_with_valve(dt, openings[''], self.supply_pressure_pa)
        else:
            self.cylinder.step_with_valves(dt, openings, self.supply_pressure_pa)
        self.steps += 1
