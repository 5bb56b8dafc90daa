"""The cylinder chamber of a suite run, from its bag, on the joint states' stamps.

Unlike :func:`valve_model_pkg.maps.flow_identification.chamber_record_from_bag` (the
valve state's time base and the recorded spool position), this record carries the duty
command in force at each control tick, for the flow scale calibration on the static map's
opening and for the flow prediction of a model driven by the recorded commands.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import RunAnalysisError
from ..interface import (ATMOSPHERIC_PRESSURE_PA, TOPIC_DUTY_COMMAND, TOPIC_JOINT_STATES,
                         TOPIC_OUTPUT_PRESSURE, TOPIC_STATE)
from ..maps.flow_identification import ChamberRecord, chamber_volume_m3
from ..pneumatics.cylinder import CylinderParameters
from ..recording import TopicData, load_bag

__all__ = ['RunChamber', 'run_chamber', 'strictly_increasing']


def strictly_increasing(t: np.ndarray) -> np.ndarray:
    """Mask keeping the last of each run of equal times: a strictly ascending time base.

    Parameters
    ----------
    t : numpy.ndarray, shape (n,)
        Non-decreasing times.

    Returns
    -------
    numpy.ndarray of bool, shape (n,)
    """
    return np.concatenate((np.diff(t) > 0.0, [True]))


@dataclass(frozen=True)
class RunChamber:
    """The chamber of a suite run at each control tick (arrays of shape (n,)).

    Attributes
    ----------
    t_s : numpy.ndarray
        Joint-state stamps [s of simulation time], strictly ascending, all > 0.
    position_m : numpy.ndarray
        Piston position [m].
    pressure_pa : numpy.ndarray
        Chamber pressure, gauge [Pa] (``valve/output_pressure`` interpolated).
    duty : numpy.ndarray
        The duty command in force [1].
    pwm_frequency_hz : float
        Median PWM frequency of the duty commands [Hz].
    supply_pressure_pa : float
        Median supply pressure of ``valve/state``, gauge [Pa].
    state : TopicData
        The bag's ``valve/state``.
    """

    t_s: np.ndarray
    position_m: np.ndarray
    pressure_pa: np.ndarray
    duty: np.ndarray
    pwm_frequency_hz: float
    supply_pressure_pa: float
    state: TopicData

    def chamber_record(self, cylinder: CylinderParameters, opening_m: np.ndarray | None = None,
                       *, from_zero: bool = False) -> ChamberRecord:
        """The record the chamber mass balance (C1-C3) reads.

        Parameters
        ----------
        cylinder : CylinderParameters
            Bore and dead volume give the chamber volume (C1); the bag does not carry them.
        opening_m : numpy.ndarray, shape (n,), optional
            The valve's opening at each tick [m]; zeros when only the chamber's own flow
            is wanted (:func:`~valve_model_pkg.maps.flow_identification.chamber_valve_flow`).
        from_zero : bool
            Time from the first tick (else the stamps as they are).
        """
        t = self.t_s - self.t_s[0] if from_zero else self.t_s
        opening = np.zeros_like(t) if opening_m is None else opening_m
        return ChamberRecord(t, self.pressure_pa,
                             chamber_volume_m3(self.position_m, cylinder.bore_diameter_m,
                                               cylinder.dead_volume_m3),
                             opening, np.full_like(t, self.supply_pressure_pa))


def run_chamber(bag: str | Path) -> RunChamber:
    """The chamber of a suite run on the joint states' simulation stamps.

    The CAN driver's ``valve/state`` stamps are not the time base (they can repeat a
    step). Repeated stamps keep their last message; messages stamped 0 come before the
    lockstep clock's first step, only in some runs, and are dropped, so the windows of a
    mass balance (which start at the first stamp) fall alike in every run.

    Parameters
    ----------
    bag : str or pathlib.Path
        A bag of the suite (``cylinder/joint_states``, ``valve/output_pressure``,
        ``valve/duty_command``, ``valve/state``).

    Returns
    -------
    RunChamber

    Raises
    ------
    RunAnalysisError
        The bag lacks one of the topics.
    """
    topics = [TOPIC_JOINT_STATES, TOPIC_OUTPUT_PRESSURE, TOPIC_DUTY_COMMAND, TOPIC_STATE]
    data = load_bag(bag, ['/' + t for t in topics])
    missing = [t for t in topics if data.get('/' + t) is None or not len(data['/' + t])]
    if missing:
        raise RunAnalysisError(f'{bag}: no {", ".join(missing)} messages')
    joints, pres, duty_cmd, state = (data['/' + t] for t in topics)
    tj = np.asarray(joints.stamp_ns, dtype=np.int64) * 1e-9
    y = np.array([p[0] for p in joints['position']], dtype=float)
    keep = strictly_increasing(tj) & (tj > 0.0)
    tj, y = tj[keep], y[keep]
    tp = np.asarray(pres.stamp_ns, dtype=np.int64) * 1e-9
    kp = strictly_increasing(tp)
    p_gauge = np.interp(tj, tp[kp], np.asarray(pres['fluid_pressure'], float)[kp]) \
        - ATMOSPHERIC_PRESSURE_PA
    td = np.asarray(duty_cmd.stamp_ns, dtype=np.int64) * 1e-9
    k = np.clip(np.searchsorted(td, tj, side='right') - 1, 0, None)
    return RunChamber(
        t_s=tj, position_m=y, pressure_pa=p_gauge,
        duty=np.asarray(duty_cmd['duty'], float)[k],
        pwm_frequency_hz=float(np.median(np.asarray(duty_cmd['pwm_frequency'], float))),
        supply_pressure_pa=float(np.median(np.asarray(state['supply_pressure'], float))),
        state=state)
