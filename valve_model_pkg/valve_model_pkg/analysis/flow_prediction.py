"""How well parameter sets predict the mass flow a run's valve delivered.

Measured: the valve's flow into the chamber, window by window, from the chamber's mass
balance (C2, C3: pressure, piston position, the suite's cylinder; ``chamber_valve_flow``).
The ``mass_flow`` of ``valve/state`` is no measurement: the CAN driver derives it from the
spool position with the suite's own orifice constants. Predicted: the model with each
set, driven by the recorded duty commands (``InputTrace.pwm_commands`` on the period grid
the identification's reader reconstructs) at the record's median pressures for the
spool's flow force; eq. (12) of its spool position with the set's C_d C_A at the supply
and chamber pressures of each instant, averaged over the same windows.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..errors import RunAnalysisError
from ..identification.measurement import Measurement
from ..identification.readers import read_measurements
from ..maps.flow_identification import chamber_valve_flow
from ..model import (InputTrace, ValveParameters, load_parameters, orifice_mass_flow,
                     simulate_trace_batch)
from ..pneumatics.cylinder import CylinderParameters
from .chamber import RunChamber, run_chamber

__all__ = ['FLOW_PREDICTION_WINDOW_S', 'FlowPrediction', 'FlowPredictionError',
           'flow_prediction_error', 'window_means']

#: Windows of the flow prediction error [s]: five 50 Hz PWM periods, short against a step.
FLOW_PREDICTION_WINDOW_S = 0.1

#: Sample step of the simulated spool position [s]: it resolves the stroke (under 1 ms).
_SIMULATION_STEP_S = 1e-4

#: Fewest windows covered by both the chamber and the simulation.
_MIN_WINDOWS = 3


def window_means(t_s: np.ndarray, values: np.ndarray, window_starts_s: np.ndarray,
                 window_s: float) -> np.ndarray:
    """Mean of ``values`` over consecutive windows of equal length.

    Parameters
    ----------
    t_s, values : numpy.ndarray, shape (n,)
        Sample times [s] and values.
    window_starts_s : numpy.ndarray, shape (w,)
        Start of each window [s]: ``window_starts_s[0] + i * window_s``.
    window_s : float
        Window length [s].

    Returns
    -------
    numpy.ndarray, shape (w,)
        The mean of the samples in [start, start + window_s) of each window; NaN for a
        window without samples.
    """
    idx = np.floor((t_s - window_starts_s[0]) / window_s).astype(int)
    inside = (idx >= 0) & (idx < window_starts_s.size)
    sums = np.bincount(idx[inside], values[inside], window_starts_s.size)
    counts = np.bincount(idx[inside], minlength=window_starts_s.size)
    with np.errstate(invalid='ignore', divide='ignore'):
        return sums / counts


@dataclass(frozen=True)
class FlowPrediction:
    """One parameter set's flow prediction against the measured windows.

    Attributes
    ----------
    rms_kg_s : float
        RMS of predicted - measured window flow [kg/s].
    rms_pct : float
        The same in % of full flow.
    mean_predicted_kg_s, mean_measured_kg_s : float
        Mean window flows [kg/s].
    """

    rms_kg_s: float
    rms_pct: float
    mean_predicted_kg_s: float
    mean_measured_kg_s: float

    def to_json(self) -> dict:
        """As ``loop.json`` has it."""
        return {'rms_kg_s': self.rms_kg_s, 'rms_pct': self.rms_pct,
                'mean_predicted_kg_s': self.mean_predicted_kg_s,
                'mean_measured_kg_s': self.mean_measured_kg_s}


@dataclass(frozen=True)
class FlowPredictionError:
    """The flow prediction of several parameter sets on one run.

    Attributes
    ----------
    full_flow_kg_s : float
        Eq. (12) of the nominal set, spool open, at the median supply pressure into the
        atmosphere [kg/s]: the scale of ``rms_pct``.
    samples : int
        ``valve/state`` samples of the record.
    duration_s : float
        Their span [s].
    bag : str
    windows : int
        Windows compared (covered by both the chamber and the simulation).
    window_s : float
        Window length [s].
    sets : dict of str to FlowPrediction
        Per label of the parameter sets, in the order given.
    """

    full_flow_kg_s: float
    samples: int
    duration_s: float
    bag: str
    windows: int
    window_s: float
    sets: dict[str, FlowPrediction]

    def to_json(self) -> dict:
        """``loop.json`` ``flow.runs`` of one run."""
        return {'full_flow_kg_s': self.full_flow_kg_s, 'samples': self.samples,
                'duration_s': self.duration_s, 'bag': self.bag, 'windows': self.windows,
                'window_s': self.window_s,
                'measured_by': 'chamber mass balance (C2, C3) of the suite\'s cylinder',
                **{label: p.to_json() for label, p in self.sets.items()}}


class _Simulated(NamedTuple):
    """Simulated flow of each set on a fine grid, on the chamber's clock."""

    t_abs_s: np.ndarray
    flows_kg_s: list[np.ndarray]


def _read_record(bag: Path) -> tuple[Measurement, RunChamber]:
    """The bag as an operational record (drive reconstructed) and its chamber."""
    m = read_measurements([bag])[0]
    if m.drive is None:
        raise RunAnalysisError(f'{bag}: valve/state is not an operational record (no duty '
                               'commands)')
    chamber = run_chamber(bag)
    if len(chamber.state) != m.t_s.size:
        raise RunAnalysisError(f'{bag}: {len(chamber.state)} valve/state messages but '
                               f'{m.t_s.size} samples')
    return m, chamber


def _simulate_flows(m: Measurement, chamber: RunChamber,
                    sets: list[ValveParameters]) -> _Simulated:
    """Eq. (12) of each set's simulated spool position at the recorded pressures."""
    p_sup = np.asarray(chamber.state['supply_pressure'], dtype=float)
    p_out = np.asarray(chamber.state['output_pressure'], dtype=float)
    d = m.drive
    trace = InputTrace.pwm_commands(d.t_s, d.duty, d.pwm_frequency_hz, d.supply_voltage_v)
    t_fine = np.arange(1, int(np.ceil(m.t_s[-1] / _SIMULATION_STEP_S)) + 1) \
        * _SIMULATION_STEP_S
    res = simulate_trace_batch(sets, trace, t_fine, sampling='instant',
                               supply_pressure_pa=float(np.median(p_sup)),
                               output_pressure_pa=float(np.median(p_out)))
    ps_f = np.interp(t_fine, m.t_s, p_sup)
    po_f = np.interp(t_fine, m.t_s, p_out)
    flows = [orifice_mass_flow(np.clip(res.spool_position_m[n], 0.0, None), ps_f, po_f, par)
             for n, par in enumerate(sets)]
    # valve/state stamps are simulation time, as the joint states' are (they can repeat a
    # step, so only the first anchors the record's own time axis)
    t0 = int(chamber.state.stamp_ns[0]) * 1e-9 - float(m.t_s[0])
    return _Simulated(t_fine + t0, flows)


def flow_prediction_error(bag: str | Path, parameter_sets: Mapping[str, ValveParameters],
                          cylinder: CylinderParameters | None = None,
                          window_s: float = FLOW_PREDICTION_WINDOW_S) -> FlowPredictionError:
    """Mass-flow prediction error of parameter sets against the flow the chamber received.

    Parameters
    ----------
    bag : str or pathlib.Path
        A bag of the suite (``valve/state`` through the drive electronics, the chamber).
    parameter_sets : mapping of str to ValveParameters
        Label -> parameter set.
    cylinder : CylinderParameters, optional
        The suite's cylinder as the demo runs it (default ``CylinderParameters()``).
    window_s : float
        Window length [s].

    Returns
    -------
    FlowPredictionError

    Raises
    ------
    RunAnalysisError
        The bag is no operational record, or fewer than 3 windows are covered by both the
        chamber and ``valve/state``.
    """
    bag = Path(bag)
    cyl = CylinderParameters() if cylinder is None else cylinder
    m, chamber = _read_record(bag)
    nominal = load_parameters()
    starts_w, measured = chamber_valve_flow(
        chamber.chamber_record(cyl), nominal,
        bleed_discharge_area_m2=cyl.bleed_discharge_area_m2,
        polytropic_exponent=cyl.polytropic_exponent, window_s=window_s)
    sim = _simulate_flows(m, chamber, list(parameter_sets.values()))
    ends_w = starts_w + window_s
    use = (starts_w >= sim.t_abs_s[0]) & (ends_w <= sim.t_abs_s[-1]) \
        & (ends_w <= chamber.t_s[-1])
    if np.count_nonzero(use) < _MIN_WINDOWS:
        raise RunAnalysisError(f'{bag}: fewer than {_MIN_WINDOWS} flow windows of '
                               f'{window_s:g} s covered by both the chamber and valve/state')
    p_sup = np.asarray(chamber.state['supply_pressure'], dtype=float)
    full = float(orifice_mass_flow(nominal.stroke_m, float(np.median(p_sup)), 0.0, nominal))
    sets = {}
    for label, flow in zip(parameter_sets, sim.flows_kg_s):
        predicted = window_means(sim.t_abs_s, flow, starts_w, window_s)
        err = (predicted - measured)[use]
        rms = float(np.sqrt(np.mean(err ** 2)))
        sets[label] = FlowPrediction(rms, 100.0 * rms / full, float(np.mean(predicted[use])),
                                     float(np.mean(measured[use])))
    return FlowPredictionError(full, int(m.t_s.size), float(m.t_s[-1] - m.t_s[0]), str(bag),
                               int(np.count_nonzero(use)), window_s, sets)
