"""How the piston answered each position step: settling time, overshoot, steady error."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ['StepResult', 'step_results', 'steps_at', 'SETTLING_BAND_M', 'MIN_SETTLED_DWELL_S']

#: Half-width of the band a settled position stays in [m].
SETTLING_BAND_M = 1e-3

#: Least time the position must stay in the band at the end of a step's window to count as
#: settled [s]: a swing that passes through the band as the window ends is not settled.
MIN_SETTLED_DWELL_S = 0.25

#: Fewest position samples in a step's window for it to be characterised.
_MIN_STEP_SAMPLES = 5


@dataclass(frozen=True)
class StepResult:
    """How the piston answered one setpoint step (SI units).

    Attributes
    ----------
    start_s : float
        When the setpoint changed [s].
    setpoint_m, final_m : float
        The setpoint and the last position of the step's window [m].
    overshoot_m : float
        Largest excursion beyond the setpoint in the direction of the step [m], >= 0.
    settling_time_s : float or None
        From the step until the position entered the band and stayed in it [s]; None if
        it never settled.
    steady_error_m : float
        Mean position - setpoint over the last 10 % of the window [m].
    """

    start_s: float
    setpoint_m: float
    final_m: float
    overshoot_m: float
    settling_time_s: float | None
    steady_error_m: float

    @property
    def settled(self) -> bool:
        """Whether the position entered the band and stayed in it to the end of the window."""
        return self.settling_time_s is not None

    def to_json(self) -> dict:
        """The step as report.json has it (mm, s)."""
        return {'start_s': round(self.start_s, 6), 'setpoint_mm': self.setpoint_m * 1e3,
                'final_mm': self.final_m * 1e3, 'overshoot_mm': self.overshoot_m * 1e3,
                'settling_s': self.settling_time_s, 'steady_error_mm': self.steady_error_m * 1e3,
                'settled': self.settled}


def step_results(t_set: np.ndarray, setpoint: np.ndarray, t_pos: np.ndarray,
                 position: np.ndarray, band_m: float = SETTLING_BAND_M,
                 include_initial: bool = False) -> list[StepResult]:
    """Split the run at setpoint changes and characterise each step.

    Parameters
    ----------
    t_set, setpoint : numpy.ndarray, shape (k,)
        Setpoint messages: times [s] and values [m].
    t_pos, position : numpy.ndarray, shape (n,)
        Piston position: times [s, ascending, the setpoints' time base] and values [m].
    band_m : float
        Half-width of the settling band [m].
    include_initial : bool
        Also characterise the segment before the first setpoint change (the pre-roll at
        the initial setpoint, no step).

    Returns
    -------
    list of StepResult
        One per step whose window holds at least 5 position samples, in time order.

    Notes
    -----
    Settling time: from the step to the first instant after which the position stays
    within ``band_m`` of the setpoint until the next step, for at least
    :data:`MIN_SETTLED_DWELL_S` (or half the window if that is shorter); otherwise the step
    is not settled. Steady-state error: mean error over the last 10 % of the step.
    """
    if setpoint.size == 0 or position.size == 0:
        return []
    change = np.flatnonzero(np.abs(np.diff(setpoint)) > 1e-9) + 1
    starts = np.concatenate([[0], change])
    if not include_initial:
        starts = starts[1:]
    return steps_at(t_set[starts], setpoint[starts], t_pos, position, band_m)


def steps_at(start_s: np.ndarray, setpoint_m: np.ndarray, t_pos: np.ndarray,
             position: np.ndarray, band_m: float = SETTLING_BAND_M) -> list[StepResult]:
    """Characterise steps whose start times are known, each until the next one's start.

    A run that knows when each goal took effect (the lockstep demo: the simulation time it
    held while the controller acknowledged the goal) places its steps there, independent
    of when the recorder received the setpoints.

    Parameters
    ----------
    start_s, setpoint_m : numpy.ndarray, shape (k,)
        Start times [s, ascending, the positions' time base] and setpoints [m] of the steps.
    t_pos, position : numpy.ndarray, shape (n,)
        Piston position: times [s, ascending] and values [m].
    band_m : float
        Half-width of the settling band [m].

    Returns
    -------
    list of StepResult
        As :func:`step_results`: one per step with at least 5 position samples.
    """
    results = []
    if position.size == 0:
        return results
    for k, (t0, sp) in enumerate(zip(start_s, setpoint_m)):
        t1 = start_s[k + 1] if k + 1 < len(start_s) else t_pos[-1]
        step = _step(float(t0), float(t1), float(sp), t_pos, position, band_m)
        if step is not None:
            results.append(step)
    return results


def _step(t0: float, t1: float, sp: float, t_pos: np.ndarray, position: np.ndarray,
          band_m: float) -> StepResult | None:
    """One step's window [t0, t1) characterised; None with fewer than 5 samples."""
    sel = (t_pos >= t0) & (t_pos < t1)
    if sel.sum() < _MIN_STEP_SAMPLES:
        return None
    tt, yy = t_pos[sel], position[sel]
    err = yy - sp
    previous = float(position[np.searchsorted(t_pos, t0) - 1]) if t0 > t_pos[0] else yy[0]
    direction = np.sign(sp - previous) or 1.0
    overshoot = max(0.0, float(np.max(direction * err)))
    outside = np.flatnonzero(np.abs(err) > band_m)
    dwell = min(MIN_SETTLED_DWELL_S, 0.5 * (t1 - t0))
    if outside.size == 0:
        settle = 0.0
    elif outside[-1] + 1 < tt.size and t1 - tt[outside[-1] + 1] >= dwell:
        settle = float(tt[outside[-1] + 1] - t0)
    else:
        settle = None
    tail = tt >= t1 - 0.1 * (t1 - t0)
    return StepResult(t0, sp, float(yy[-1]), overshoot, settle, float(np.mean(err[tail])))
