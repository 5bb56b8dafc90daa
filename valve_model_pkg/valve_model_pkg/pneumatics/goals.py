"""The position goal sequences the suite runs, and when each goal takes effect.

A sequence is ``((goal [m], hold [s]), ...)`` in the order sent. ``make demo``
(``valve_demo``) runs :data:`DEMO_GOALS` (``--quick``: :data:`DEMO_QUICK_GOALS`), the loop
in service (``valve_bench_loop --mode operation``) :data:`OPERATION_GOALS` (``--quick``:
:data:`OPERATION_QUICK_GOALS`); each after :data:`PRE_ROLL_S` of simulated time at the
initial setpoint, 0 m. In lockstep every goal takes effect at its hold point exactly
(:func:`goal_schedule`), whatever the machine's load. The ROS-free closed loop runs the
same sequences with :func:`with_pre_roll`.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

__all__ = ['GoalSequence', 'PRE_ROLL_S', 'DEMO_GOALS', 'DEMO_QUICK_GOALS', 'OPERATION_GOALS',
           'OPERATION_QUICK_GOALS', 'with_hold', 'with_pre_roll', 'ScheduledGoal',
           'goal_schedule']

#: ``((goal [m], hold [s]), ...)``.
GoalSequence = tuple[tuple[float, float], ...]

#: Simulated time before the first goal [s]: the suite settles at the initial setpoint.
PRE_ROLL_S = 0.5

#: The demo: up and down strokes of different lengths, each held 3 s.
DEMO_GOALS: GoalSequence = ((0.020, 3.0), (0.060, 3.0), (0.040, 3.0), (0.080, 3.0),
                            (0.030, 3.0))
#: ``valve_demo --quick``: the first three, held 2 s.
DEMO_QUICK_GOALS: GoalSequence = tuple((g, 2.0) for g, _ in DEMO_GOALS[:3])

#: The loop in service: strokes that fill and exhaust the chamber, each held 2 s.
OPERATION_GOALS: GoalSequence = ((0.020, 2.0), (0.060, 2.0), (0.040, 2.0), (0.080, 2.0),
                                 (0.030, 2.0))
#: ``valve_bench_loop --mode operation --quick``: three steps, a 4.5 s record after the
#: pre-roll.
OPERATION_QUICK_GOALS: GoalSequence = ((0.020, 1.5), (0.060, 1.5), (0.035, 1.5))


def with_hold(goals: Sequence[tuple[float, float]], hold_s: float) -> GoalSequence:
    """The same goals, each held ``hold_s`` [s]."""
    return tuple((float(g), float(hold_s)) for g, _ in goals)


def with_pre_roll(goals: Sequence[tuple[float, float]], pre_roll_s: float = PRE_ROLL_S,
                  initial_m: float = 0.0) -> list[tuple[float, float]]:
    """The goals after a pre-roll at ``initial_m`` [m] for ``pre_roll_s`` [s], as
    :func:`~valve_model_pkg.pneumatics.closed_loop.simulate_closed_loop` takes them."""
    return [(float(initial_m), float(pre_roll_s)), *((float(g), float(h)) for g, h in goals)]


class ScheduledGoal(NamedTuple):
    """One goal of a run [m] and the simulated instant it takes effect [s]."""

    position_m: float
    start_s: float


def goal_schedule(goals: Sequence[tuple[float, float]],
                  pre_roll_s: float = PRE_ROLL_S) -> list[ScheduledGoal]:
    """When each goal of a lockstep run takes effect.

    The demo holds the simulation at each hold point (the pre-roll, then after each hold),
    sends the goal and lets the simulation go on only after the controller acknowledged
    it.

    Parameters
    ----------
    goals : sequence of (float, float)
        (goal [m], hold [s]) in the order the run sends them.
    pre_roll_s : float
        Simulated time before the first goal [s].

    Returns
    -------
    list of ScheduledGoal
        Each goal [m] and its start [s of simulated time, rounded to 1 ms as the demo
        holds the simulation]: the pre-roll plus the holds before it.
    """
    out, t = [], pre_roll_s
    for goal_m, hold_s in goals:
        out.append(ScheduledGoal(float(goal_m), round(t, 3)))
        t += hold_s
    return out
