"""The demo's control loop without ROS: controller -> flow_to_duty -> valve model -> cylinder.

The same pieces the nodes run (PositionController, FlowToDutyInverter, and the
SimulatedAxis of valve model and cylinder that ``valve_lockstep_sim`` runs), connected
directly with the node rates. The controller sees the plant at its tick and its command
acts from that tick on, as in the lockstep protocol; ``feedback_delay_s`` adds transport
delay to check robustness. Used to tune the controller and to test the loop
deterministically.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from valve_model_pkg.maps.dutymap import DutyMap, load_map
from valve_model_pkg.model.constants import ATMOSPHERIC_PRESSURE_PA
from valve_model_pkg.maps.inversion import FlowToDutyInverter
from valve_model_pkg.model import ValveParameters, load_parameters
from valve_model_pkg.pneumatics.controller import ControllerGains, PositionController
from valve_model_pkg.pneumatics.axis import SimulatedAxis
from valve_model_pkg.pneumatics.cylinder import CylinderParameters

__all__ = ['LoopResult', 'simulate_closed_loop', 'DoubleLoopResult', 'simulate_closed_loop_double']


@dataclass(frozen=True)
class LoopResult:
    """Traces of a closed-loop run, sampled every valve tick (shape (n,) each)."""

    t_s: np.ndarray
    setpoint_m: np.ndarray
    position_m: np.ndarray
    chamber_pressure_pa: np.ndarray   # absolute
    flow_command_kg_s: np.ndarray
    valve_flow_kg_s: np.ndarray       # into the chamber, at the chamber pressure (C7)
    duty: np.ndarray
    current_a: np.ndarray


def simulate_closed_loop(goals: list[tuple[float, float]], *, supply_pressure_pa: float = 4e5,
                         pwm_frequency_hz: float = 50.0, control_rate_hz: float = 200.0,
                         valve_rate_hz: float = 1000.0,
                         gains: ControllerGains | None = None,
                         plant: CylinderParameters | None = None,
                         valve: ValveParameters | None = None,
                         feedback_delay_s: float = 0.0,
                         duty_map: DutyMap | None = None) -> LoopResult:
    """Run the loop through ``goals`` = [(position [m], hold [s]), ...].

    ``duty_map`` is the map ``flow_to_duty`` inverts (default: the package's map of the
    nominal valve); ``valve`` the valve the plant carries (default: the nominal one): a
    map of another valve shows what a miscalibrated map does to the loop.

    The valve model advances in ``1/valve_rate_hz`` ticks; the plant integrates each tick
    with the valve's instantaneous opening (as the cylinder node does with valve/state).
    ``feedback_delay_s`` delays the position and velocity the controller sees (transport
    and scheduling delays of the nodes), to check the loop's robustness to them.
    """
    valve = valve or load_parameters()
    plant = plant or CylinderParameters()
    ctl = PositionController(gains, plant)
    inverter = FlowToDutyInverter(duty_map or load_map(), pwm_frequency_hz)
    axis = SimulatedAxis('single', step_ns=int(round(1e9 / valve_rate_hz)), valve=valve,
                         plant=plant, supply_pressure_pa=supply_pressure_pa,
                         pwm_frequency_hz=pwm_frequency_hz)
    cyl = axis.cylinder
    dt = 1.0 / valve_rate_hz
    every = max(1, int(round(valve_rate_hz / control_rate_hz)))
    n = int(round(sum(h for _, h in goals) * valve_rate_hz))
    out = {k: np.empty(n) for k in LoopResult.__dataclass_fields__}
    setpoints = np.concatenate([np.full(int(round(h * valve_rate_hz)), g) for g, h in goals])
    flow_cmd = 0.0
    duty = 0.0
    lag = int(round(feedback_delay_s * valve_rate_hz))
    history = [(0.0, 0.0, ATMOSPHERIC_PRESSURE_PA)] * (lag + 1)  # (y, v, p) ring, oldest first
    for k in range(n):
        t = k * dt
        sp = float(setpoints[min(k, setpoints.size - 1)])
        history.append((cyl.state.position_m, cyl.state.velocity_m_s, cyl.state.pressure_pa))
        del history[0]
        if k % every == 0:
            y_seen, v_seen, p_seen = history[0]
            flow_cmd = ctl.update(sp, y_seen, v_seen, every * dt, p_seen)
            result = inverter.compute(flow_cmd, supply_pressure_pa,
                                      cyl.chamber_gauge_pressure_pa)
            duty = result.duty
            axis.set_command('', duty, pwm_frequency_hz)
        axis.step()
        sample = axis.sample('')
        out['t_s'][k] = t + dt
        out['setpoint_m'][k] = sp
        out['position_m'][k] = cyl.state.position_m
        out['chamber_pressure_pa'][k] = cyl.state.pressure_pa
        out['flow_command_kg_s'][k] = flow_cmd
        out['valve_flow_kg_s'][k] = cyl.last_valve_flow_kg_s
        out['duty'][k] = duty
        out['current_a'][k] = sample.coil_current_a
    return LoopResult(**out)


@dataclass(frozen=True)
class DoubleLoopResult:
    """Traces of a closed-loop run of the double-acting axis, every valve tick."""

    t_s: np.ndarray
    setpoint_m: np.ndarray
    position_m: np.ndarray
    cap_pressure_pa: np.ndarray       # absolute
    rod_pressure_pa: np.ndarray       # absolute
    cap_duty: np.ndarray
    rod_duty: np.ndarray


def simulate_closed_loop_double(goals: list[tuple[float, float]], *,
                                supply_pressure_pa: float = 4e5,
                                pwm_frequency_hz: float = 50.0,
                                control_rate_hz: float = 200.0,
                                valve_rate_hz: float = 1000.0,
                                gains: ControllerGains | None = None,
                                plant: CylinderParameters | None = None,
                                valve: ValveParameters | None = None,
                                feedback_delay_s: float = 0.0) -> DoubleLoopResult:
    """The double-acting axis's loop: one controller, two flow_to_duty, two 3/2 valves.

    As :func:`simulate_closed_loop` (same rates and tick order as ``valve_lockstep_sim``
    with ``cylinder:=double``), with :class:`DoublePositionController`, one
    :class:`FlowToDutyInverter` per valve and the :class:`SimulatedAxis` of kind
    ``'double'``.
    """
    from valve_model_pkg.pneumatics.controller import DoublePositionController
    valve = valve or load_parameters()
    plant = plant or CylinderParameters()
    ctl = DoublePositionController(gains, plant, valve, supply_pressure_pa=supply_pressure_pa)
    dmap = load_map()
    inverters = {n: FlowToDutyInverter(dmap, pwm_frequency_hz) for n in ctl.names}
    axis = SimulatedAxis('double', step_ns=int(round(1e9 / valve_rate_hz)), valve=valve,
                         plant=plant, supply_pressure_pa=supply_pressure_pa,
                         pwm_frequency_hz=pwm_frequency_hz)
    cyl = axis.cylinder
    dt = 1.0 / valve_rate_hz
    every = max(1, int(round(valve_rate_hz / control_rate_hz)))
    n = int(round(sum(h for _, h in goals) * valve_rate_hz))
    out = {k: np.empty(n) for k in DoubleLoopResult.__dataclass_fields__}
    setpoints = np.concatenate([np.full(int(round(h * valve_rate_hz)), g) for g, h in goals])
    lag = int(round(feedback_delay_s * valve_rate_hz))
    s0 = cyl.state
    history = [(s0.position_m, s0.velocity_m_s, s0.cap_pressure_pa, s0.rod_pressure_pa)] \
        * (lag + 1)
    duty = {n: 0.0 for n in ctl.names}
    for k in range(n):
        sp = float(setpoints[min(k, setpoints.size - 1)])
        s = cyl.state
        history.append((s.position_m, s.velocity_m_s, s.cap_pressure_pa, s.rod_pressure_pa))
        del history[0]
        if k % every == 0:
            y, v, pc, pr = history[0]
            flows = ctl.update(sp, y, v, every * dt, pc, pr)
            for name, flow in flows.items():
                duty[name] = inverters[name].compute(
                    flow, supply_pressure_pa, cyl.chamber_gauge_pressure_pa(name)).duty
                axis.set_command(name, duty[name], pwm_frequency_hz)
        axis.step()
        s = cyl.state
        out['t_s'][k] = (k + 1) * dt
        out['setpoint_m'][k] = sp
        out['position_m'][k] = s.position_m
        out['cap_pressure_pa'][k] = s.cap_pressure_pa
        out['rod_pressure_pa'][k] = s.rod_pressure_pa
        out['cap_duty'][k] = duty['cap']
        out['rod_duty'][k] = duty['rod']
    return DoubleLoopResult(**out)
