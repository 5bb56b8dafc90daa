"""Position tracking of a suite run: goal in force - piston position, and when goals count.

A run moves the piston through a sequence of goals, each held for a time. In lockstep
every goal takes effect at its hold point exactly, whatever the machine's load
(:func:`valve_model_pkg.pneumatics.goals.goal_schedule`). The bag shows the same instants
as the change of ``cylinder/position_setpoint`` to each goal
(:func:`acknowledged_goal_times`).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..errors import RunAnalysisError
from ..interface import TOPIC_JOINT_STATES, TOPIC_POSITION_GOAL, TOPIC_POSITION_SETPOINT
from ..pneumatics.goals import ScheduledGoal
from ..recording import load_bag
from .timebase import run_time_base

__all__ = ['GoalTimes', 'acknowledged_goal_times',
           'TrackingError', 'tracking_error', 'RunTracking', 'run_tracking_error',
           'GOALS_FROM_ACKNOWLEDGEMENT']

#: ``RunTracking.goals_from`` when every goal was placed at its acknowledgement.
GOALS_FROM_ACKNOWLEDGEMENT = 'controller acknowledgement'

#: An acknowledgement may lie this many control ticks off its scheduled instant.
_SCHEDULE_TOLERANCE_TICKS = 1.5


class GoalTimes(NamedTuple):
    """Goal start times [s] and how many of them an acknowledgement placed."""

    start_s: np.ndarray
    acknowledged: int


def acknowledged_goal_times(goal_s: np.ndarray, goal_m: np.ndarray, setpoint_s: np.ndarray,
                            setpoint_m: np.ndarray) -> GoalTimes:
    """Place each goal at the controller's acknowledgement: its setpoint's change to it.

    The changes of the setpoint are matched to the goals in order (the recorder may
    receive an acknowledgement before the goal message itself); a goal without one keeps
    its message's time. The result is made non-decreasing.

    Parameters
    ----------
    goal_s, goal_m : numpy.ndarray, shape (k,)
        Goal messages: times [s] and values [m].
    setpoint_s, setpoint_m : numpy.ndarray, shape (j,)
        The controller's setpoint messages: times [s] and values [m].

    Returns
    -------
    GoalTimes
    """
    times = np.array(goal_s, dtype=float)
    changes = np.flatnonzero(np.diff(setpoint_m) != 0.0) + 1
    acknowledged, c = 0, 0
    for i, value in enumerate(goal_m):
        while c < changes.size and setpoint_m[changes[c]] != value:
            c += 1
        if c == changes.size:
            break
        times[i] = setpoint_s[changes[c]]
        acknowledged += 1
        c += 1
    return GoalTimes(np.maximum.accumulate(times), acknowledged)


@dataclass(frozen=True)
class TrackingError:
    """Goal in force - piston position over a run, from the first goal on.

    Attributes
    ----------
    rms_mm, mean_abs_mm, max_abs_mm : float
        RMS, mean and largest absolute error [mm].
    duration_s : float
        From the first to the last position sample counted [s].
    samples : int
        Position samples counted.
    """

    rms_mm: float
    mean_abs_mm: float
    max_abs_mm: float
    duration_s: float
    samples: int


def tracking_error(t_s: np.ndarray, position_m: np.ndarray, goal_start_s: np.ndarray,
                   goal_m: np.ndarray) -> TrackingError:
    """The tracking error of a position record against a sequence of goals.

    Parameters
    ----------
    t_s, position_m : numpy.ndarray, shape (n,)
        Piston position samples: times [s, ascending] and positions [m].
    goal_start_s, goal_m : numpy.ndarray, shape (k,)
        When each goal takes effect [s, non-decreasing, the samples' time base] and the
        goal [m]. A goal is in force from its start to the next goal's start.

    Returns
    -------
    TrackingError
        Over the samples at or after the first goal's start.

    Raises
    ------
    RunAnalysisError
        No position sample at or after the first goal.
    """
    k = np.searchsorted(goal_start_s, t_s, side='right') - 1
    sel = k >= 0
    if not np.any(sel):
        raise RunAnalysisError('no position sample at or after the first goal')
    err = np.asarray(goal_m, dtype=float)[k[sel]] - position_m[sel]
    return TrackingError(rms_mm=float(np.sqrt(np.mean(err ** 2)) * 1e3),
                         mean_abs_mm=float(np.mean(np.abs(err)) * 1e3),
                         max_abs_mm=float(np.max(np.abs(err)) * 1e3),
                         duration_s=float(t_s[sel][-1] - t_s[sel][0]),
                         samples=int(err.size))


@dataclass(frozen=True)
class RunTracking:
    """The tracking error of a run's bag and how its goals were placed.

    Attributes
    ----------
    error : TrackingError
    goals_from : str
        :data:`GOALS_FROM_ACKNOWLEDGEMENT`, the schedule (with the largest distance of the
        acknowledgements from it), or how many goals fell back to their message's time.
    bag : str
        The bag.
    """

    error: TrackingError
    goals_from: str
    bag: str

    def to_json(self) -> dict:
        """``loop.json`` ``tracking`` of one run."""
        e = self.error
        return {'rms_mm': e.rms_mm, 'mean_abs_mm': e.mean_abs_mm, 'max_abs_mm': e.max_abs_mm,
                'duration_s': e.duration_s, 'samples': e.samples,
                'goals_from': self.goals_from, 'bag': self.bag}


class _RunGoals(NamedTuple):
    """The bag's positions and goals on the run's clock (seconds from the first stamp)."""

    t_s: np.ndarray
    position_m: np.ndarray
    origin_ns: int
    goal_m: np.ndarray
    placed: GoalTimes


def _run_goals(bag: Path) -> _RunGoals:
    """Positions and goals of a bag; each goal placed at its acknowledgement."""
    data = load_bag(bag, ['/' + TOPIC_JOINT_STATES, '/' + TOPIC_POSITION_GOAL,
                          '/' + TOPIC_POSITION_SETPOINT])
    joints = data.get('/' + TOPIC_JOINT_STATES)
    goals = data.get('/' + TOPIC_POSITION_GOAL)
    if joints is None or goals is None or not len(joints) or not len(goals):
        raise RunAnalysisError(f'{bag}: no {TOPIC_JOINT_STATES} or {TOPIC_POSITION_GOAL} '
                               'messages')
    stamps = joints.stamp_ns if joints.stamp_ns is not None else joints.log_time_ns
    origin = int(stamps[0])
    t_s = (np.asarray(stamps, dtype=np.int64) - origin) * 1e-9
    position = np.array([p[0] for p in joints['position']], dtype=float)
    clock = run_time_base(data, origin)
    goal_m = np.asarray(goals['data'], dtype=float)
    placed = GoalTimes(clock.times_s(goals), 0)
    setp = data.get('/' + TOPIC_POSITION_SETPOINT)
    if setp is not None and len(setp):
        placed = acknowledged_goal_times(placed.start_s, goal_m, clock.times_s(setp),
                                         np.asarray(setp['data'], dtype=float))
    return _RunGoals(t_s, position, origin, goal_m, placed)


def _scheduled_starts(bag: Path, run: _RunGoals, schedule: Sequence[ScheduledGoal]
                      ) -> tuple[np.ndarray, float]:
    """The schedule's starts on the bag's clock, checked against the acknowledgements.

    Returns the starts [s] and the largest distance of an acknowledgement from them [s].
    """
    want = np.array([g for g, _ in schedule], dtype=float)
    if want.size != run.goal_m.size or not np.allclose(want, run.goal_m, rtol=0.0,
                                                       atol=1e-9):
        raise RunAnalysisError(f'{bag}: goals {run.goal_m.tolist()} are not the '
                               f'schedule\'s {want.tolist()}')
    starts = np.array([t for _, t in schedule], dtype=float) - run.origin_ns * 1e-9
    tick = float(np.median(np.diff(run.t_s))) if run.t_s.size > 1 else 0.0
    off = np.abs(starts - run.placed.start_s)
    if np.any(off > _SCHEDULE_TOLERANCE_TICKS * tick):
        raise RunAnalysisError(f'{bag}: goals took effect at '
                               f'{run.placed.start_s.round(4).tolist()} s, not at the '
                               f'schedule\'s {starts.round(4).tolist()} s')
    return starts, float(off.max())


def run_tracking_error(bag: str | Path,
                       schedule: Sequence[ScheduledGoal] | None = None) -> RunTracking:
    """Position-tracking error of a suite run, from its bag.

    Each goal counts from the controller's acknowledgement (the change of
    ``cylinder/position_setpoint`` to it; the goal message's own time when none
    acknowledges it). Both topics are ``std_msgs/Float64`` without a header and are placed
    on the joint states' clock (:class:`RunTimeBase`). With ``schedule`` the goals count
    from the schedule's instants instead, so the same run gives the same number to the
    last digit, and the bag must be the run the schedule describes.

    Parameters
    ----------
    bag : str or pathlib.Path
        A bag of the suite (``cylinder/joint_states``, ``cylinder/position_goal``,
        ``cylinder/position_setpoint``).
    schedule : sequence of ScheduledGoal, optional
        :func:`~valve_model_pkg.pneumatics.goals.goal_schedule` of the run (simulated
        time).

    Returns
    -------
    RunTracking

    Raises
    ------
    RunAnalysisError
        A topic missing; with ``schedule``: the bag's goals are not the schedule's, or an
        acknowledgement lies more than 1.5 control ticks off its scheduled instant.
    """
    bag = Path(bag)
    run = _run_goals(bag)
    n_goals = run.goal_m.size
    if run.placed.acknowledged == n_goals:
        goals_from = GOALS_FROM_ACKNOWLEDGEMENT
    else:
        goals_from = (f'{run.placed.acknowledged} of {n_goals} goals acknowledged, others '
                      'at the goal message')
    starts = run.placed.start_s
    if schedule is not None:
        starts, off_s = _scheduled_starts(bag, run, schedule)
        goals_from = ('demo schedule (each goal at its hold point, simulated time); the '
                      f'acknowledgements agree within {off_s * 1e3:.1f} ms')
    return RunTracking(tracking_error(run.t_s, run.position_m, starts, run.goal_m),
                       goals_from, str(bag))
