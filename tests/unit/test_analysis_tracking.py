"""The position-tracking error of a suite run (analysis.tracking): on arrays with a known
error, and on hand-built bags where the goal, its acknowledgement and the joint states
reach the recorder in different orders; the goal schedule of a lockstep run."""
from __future__ import annotations

import numpy as np
import pytest

from suite_bags import header, write_bag
from valve_model_pkg.analysis import (GOALS_FROM_ACKNOWLEDGEMENT, acknowledged_goal_times,
                                      run_tracking_error, tracking_error)
from valve_model_pkg.errors import RunAnalysisError
from valve_model_pkg.pneumatics.goals import (DEMO_GOALS, PRE_ROLL_S, ScheduledGoal,
                                              goal_schedule, with_hold, with_pre_roll)
from valve_model_pkg.recording import build_typestore

#: Receive-time spacing of the 5 ms joint-state ticks in the bags below [ns].
TICK = 10_000_000


def test_tracking_error_of_a_piston_that_lags_by_a_known_amount() -> None:
    # piston 1 mm short of each goal after its start; before the first goal not counted
    t = np.arange(0, 100) * 0.01
    goal_start, goal = np.array([0.2, 0.6]), np.array([0.02, 0.05])
    in_force = np.where(t >= 0.6, 0.05, 0.02)
    pos = np.where(t >= 0.2, in_force - 1e-3, 0.0)
    pos[70] = in_force[70] + 4e-3          # one sample 4 mm beyond
    e = tracking_error(t, pos, goal_start, goal)
    assert e.samples == 80
    assert e.max_abs_mm == pytest.approx(4.0)
    assert e.rms_mm == pytest.approx(np.sqrt((79 * 1.0 + 16.0) / 80))
    assert e.mean_abs_mm == pytest.approx((79 * 1.0 + 4.0) / 80)
    assert e.duration_s == pytest.approx(0.79)


def test_tracking_error_without_a_sample_after_the_first_goal_is_refused() -> None:
    with pytest.raises(RunAnalysisError, match='no position sample'):
        tracking_error(np.array([0.0, 0.1]), np.zeros(2), np.array([0.5]), np.array([0.02]))


def test_acknowledgements_are_matched_to_the_goals_in_order() -> None:
    # setpoint 0 -> 20 mm at 0.3 s -> 60 mm at 0.9 s; the third goal never acknowledged
    placed = acknowledged_goal_times(np.array([0.29, 0.91, 1.5]), np.array([0.02, 0.06, 0.03]),
                                     np.array([0.0, 0.3, 0.5, 0.9]),
                                     np.array([0.0, 0.02, 0.02, 0.06]))
    assert placed.acknowledged == 2
    np.testing.assert_array_equal(placed.start_s, [0.3, 0.9, 1.5])


def _write_run_bag(path, goals, setpoints, n_ticks: int = 200) -> None:
    """A suite bag on simulation time: cylinder/joint_states every 5 ms (piston at 0), the
    goal and the controller's setpoint (std_msgs/Float64, no header) at given receive
    times. ``goals``/``setpoints``: (value [m], receive time [ns after the run's start])."""
    store = build_typestore()
    types = store.types
    wall0 = 1_700_000_000_000_000_000
    msgs = []
    for k in range(n_ticks):
        joint = types['sensor_msgs/msg/JointState'](
            header=header(types, k * 5_000_000), name=['piston'], position=np.array([0.0]),
            velocity=np.array([0.0]), effort=np.array([0.0]))
        # received 10 ms of wall time per 5 ms tick, 1 ms after the tick's start
        msgs.append(('cylinder/joint_states', 'sensor_msgs/msg/JointState',
                     wall0 + k * TICK + 1_000_000, joint))
    for topic, items in (('cylinder/position_goal', goals),
                         ('cylinder/position_setpoint', setpoints)):
        for value, rel_ns in items:
            msgs.append((topic, 'std_msgs/msg/Float64', wall0 + rel_ns,
                         types['std_msgs/msg/Float64'](data=float(value))))
    msgs.sort(key=lambda m: m[2])
    write_bag(path, store, msgs)


#: 80 ticks at 20 mm (40..119), 80 ticks at 60 mm (120..199), piston at 0.
RMS_TWO_GOALS_MM = np.sqrt((80 * 20.0 ** 2 + 80 * 60.0 ** 2) / 160)


def test_each_goal_counts_from_the_controllers_acknowledgement(tmp_path):
    """The goal message may reach the recorder before the joint state of its tick (then it
    maps one tick early) and after the setpoint that acknowledges it; the error counts from
    the acknowledgement either way, so the same run always gives the same number."""
    # goal 1 received before tick 40's joint state (the goal maps to tick 39), acknowledged
    # after it (tick 40); goal 2's acknowledgement received BEFORE the goal itself, both
    # after tick 120's joint state (tick 120)
    goals = [(0.02, 40 * TICK + 500_000), (0.06, 120 * TICK + 3_000_000)]
    setpoints = [(0.0, 10 * TICK + 2_000_000), (0.02, 40 * TICK + 2_000_000),
                 (0.06, 120 * TICK + 2_000_000)]
    _write_run_bag(tmp_path / 'bag', goals, setpoints)
    tr = run_tracking_error(tmp_path / 'bag')
    assert tr.goals_from == GOALS_FROM_ACKNOWLEDGEMENT
    assert tr.error.samples == 160
    assert tr.error.rms_mm == pytest.approx(RMS_TWO_GOALS_MM)
    assert tr.error.max_abs_mm == pytest.approx(60.0)
    assert tr.to_json()['rms_mm'] == tr.error.rms_mm and tr.to_json()['bag'] == str(
        tmp_path / 'bag')


def test_without_setpoints_a_goal_counts_from_its_message(tmp_path):
    _write_run_bag(tmp_path / 'bag', [(0.02, 40 * TICK + 500_000)], [])
    tr = run_tracking_error(tmp_path / 'bag')
    assert tr.error.samples == 161   # from tick 39, where the goal message maps
    assert tr.goals_from.startswith('0 of 1 goals acknowledged')


def test_on_the_schedule_the_receive_order_does_not_matter(tmp_path):
    """With the demo's schedule each goal counts from its hold point, wherever the
    recorder received the goal and its acknowledgement (here both one tick early)."""
    goals = [(0.02, 39 * TICK + 1_500_000), (0.06, 120 * TICK + 3_000_000)]
    setpoints = [(0.0, 10 * TICK + 2_000_000), (0.02, 39 * TICK + 2_000_000),
                 (0.06, 120 * TICK + 2_000_000)]
    _write_run_bag(tmp_path / 'bag', goals, setpoints)
    assert run_tracking_error(tmp_path / 'bag').error.samples == 161  # acknowledged at 39
    tr = run_tracking_error(tmp_path / 'bag', [ScheduledGoal(0.02, 0.200),
                                               ScheduledGoal(0.06, 0.600)])
    assert tr.error.samples == 160              # ticks 40..199, as the run was driven
    assert tr.error.rms_mm == pytest.approx(RMS_TWO_GOALS_MM)
    assert tr.goals_from.startswith('demo schedule')
    with pytest.raises(RunAnalysisError, match='not the schedule'):
        run_tracking_error(tmp_path / 'bag', [(0.02, 0.200), (0.05, 0.600)])
    with pytest.raises(RunAnalysisError, match='took effect'):
        run_tracking_error(tmp_path / 'bag', [(0.02, 0.200), (0.06, 0.700)])


def test_a_bag_without_goals_is_refused(tmp_path):
    _write_run_bag(tmp_path / 'bag', [], [])
    with pytest.raises(RunAnalysisError, match='no cylinder/joint_states or '
                                               'cylinder/position_goal'):
        run_tracking_error(tmp_path / 'bag')


def test_goal_schedule_starts_after_the_pre_roll() -> None:
    assert goal_schedule(((0.02, 1.5), (0.06, 2.0)), 0.5) == [(0.02, 0.5), (0.06, 2.0)]
    schedule = goal_schedule(DEMO_GOALS)
    assert schedule[0].start_s == PRE_ROLL_S
    holds = [h for _, h in DEMO_GOALS]
    assert [s.start_s for s in schedule] == pytest.approx(
        PRE_ROLL_S + np.concatenate([[0.0], np.cumsum(holds[:-1])]))
    assert [s.position_m for s in schedule] == [g for g, _ in DEMO_GOALS]


def test_goal_sequences_with_another_hold_and_a_pre_roll() -> None:
    assert with_hold(((0.02, 3.0), (0.06, 3.0)), 1.5) == ((0.02, 1.5), (0.06, 1.5))
    assert with_pre_roll(((0.02, 3.0),), 0.5) == [(0.0, 0.5), (0.02, 3.0)]
