"""What the operation loop counts as a right diagnosis (loop.json `judgement`): the listed
effect itself; for an emulator form written independently of the candidates, the nearest
candidate or `unlisted`, never another listed effect; `none` for a valve without effect."""
from __future__ import annotations

import numpy as np
import pytest

from valve_bringup.bench_loop import NEAREST_CANDIDATE, expected_answers
from valve_model_pkg.model.parameters import EFFECTS, EMULATOR_EFFECTS


def test_every_emulator_form_maps_to_a_listed_candidate() -> None:
    assert set(NEAREST_CANDIDATE) == set(EMULATOR_EFFECTS)
    assert set(NEAREST_CANDIDATE.values()) <= set(EFFECTS)


def test_expected_answers() -> None:
    assert expected_answers('eddy_current') == ['eddy_current']
    assert expected_answers('none') == ['none']
    assert expected_answers('saturation_tanh') == ['magnetic_saturation', 'unlisted']
    assert 'eddy_current' not in expected_answers('saturation_tanh')


def _write_run_bag(path, goals, setpoints, n_ticks: int = 200) -> None:
    """A suite bag on simulation time: cylinder/joint_states every 5 ms (piston at 0), the
    goal and the controller's setpoint (std_msgs/Float64, no header) at given receive
    times. ``goals``/``setpoints``: (value [m], receive time [ns after the run's start])."""
    from suite_bags import header, write_bag
    from valve_model_pkg.recording import build_typestore
    store = build_typestore()
    types = store.types
    wall0 = 1_700_000_000_000_000_000
    msgs = []
    for k in range(n_ticks):
        ns = k * 5_000_000
        joint = types['sensor_msgs/msg/JointState'](
            header=header(types, ns), name=['piston'], position=np.array([0.0]),
            velocity=np.array([0.0]), effort=np.array([0.0]))
        # received 10 ms of wall time per 5 ms tick, 1 ms after the tick's start
        msgs.append(('cylinder/joint_states', 'sensor_msgs/msg/JointState',
                     wall0 + k * 10_000_000 + 1_000_000, joint))
    for topic, items in (('cylinder/position_goal', goals),
                         ('cylinder/position_setpoint', setpoints)):
        for value, rel_ns in items:
            msgs.append((topic, 'std_msgs/msg/Float64', wall0 + rel_ns,
                         types['std_msgs/msg/Float64'](data=float(value))))
    msgs.sort(key=lambda m: m[2])
    write_bag(path, store, msgs)


def test_tracking_error_counts_each_goal_from_the_controllers_acknowledgement(tmp_path):
    """The goal message may reach the recorder before the joint state of its tick (then it
    maps one tick early) and after the setpoint that acknowledges it; the error counts from
    the acknowledgement either way, so the same run always gives the same number."""
    from valve_bringup.bench_loop import tracking_error
    tick = 10_000_000   # receive-time spacing of the 5 ms joint-state ticks [ns]
    # goal 1 received before tick 40's joint state (the goal maps to tick 39), acknowledged
    # after it (tick 40); goal 2's acknowledgement received BEFORE the goal itself, both
    # after tick 120's joint state (tick 120)
    goals = [(0.02, 40 * tick + 500_000), (0.06, 120 * tick + 3_000_000)]
    setpoints = [(0.0, 10 * tick + 2_000_000), (0.02, 40 * tick + 2_000_000),
                 (0.06, 120 * tick + 2_000_000)]
    _write_run_bag(tmp_path / 'bag', goals, setpoints)
    tr = tracking_error(tmp_path / 'bag')
    assert tr['goals_from'] == 'controller acknowledgement'
    # 80 ticks at 20 mm (40..119), 80 ticks at 60 mm (120..199), piston at 0
    assert tr['samples'] == 160
    assert tr['rms_mm'] == pytest.approx(np.sqrt((80 * 20.0 ** 2 + 80 * 60.0 ** 2) / 160))
    assert tr['max_abs_mm'] == pytest.approx(60.0)


def test_tracking_error_falls_back_to_the_goal_message_without_setpoints(tmp_path):
    from valve_bringup.bench_loop import tracking_error
    tick = 10_000_000
    _write_run_bag(tmp_path / 'bag', [(0.02, 40 * tick + 500_000)], [])
    tr = tracking_error(tmp_path / 'bag')
    assert tr['samples'] == 161   # from tick 39, where the goal message maps
    assert tr['goals_from'].startswith('0 of 1 goals acknowledged')


def test_tracking_error_on_the_demo_schedule_ignores_receive_order(tmp_path):
    """With the demo's schedule each goal counts from its hold point, wherever the
    recorder received the goal and its acknowledgement (here both one tick early)."""
    from valve_bringup.bench_loop import tracking_error
    tick = 10_000_000
    goals = [(0.02, 39 * tick + 1_500_000), (0.06, 120 * tick + 3_000_000)]
    setpoints = [(0.0, 10 * tick + 2_000_000), (0.02, 39 * tick + 2_000_000),
                 (0.06, 120 * tick + 2_000_000)]
    _write_run_bag(tmp_path / 'bag', goals, setpoints)
    by_ack = tracking_error(tmp_path / 'bag')
    assert by_ack['samples'] == 161          # the early acknowledgement: from tick 39
    tr = tracking_error(tmp_path / 'bag', [(0.02, 0.200), (0.06, 0.600)])
    assert tr['samples'] == 160              # ticks 40..199, as the run was driven
    assert tr['rms_mm'] == pytest.approx(np.sqrt((80 * 20.0 ** 2 + 80 * 60.0 ** 2) / 160))
    assert tr['goals_from'].startswith('demo schedule')
    with pytest.raises(ValueError, match='not the schedule'):
        tracking_error(tmp_path / 'bag', [(0.02, 0.200), (0.05, 0.600)])
    with pytest.raises(ValueError, match='took effect'):
        tracking_error(tmp_path / 'bag', [(0.02, 0.200), (0.06, 0.700)])


def test_goal_schedule_starts_after_the_pre_roll() -> None:
    from valve_bringup.bench_loop import goal_schedule
    from valve_bringup.demo import PRE_ROLL_S
    assert goal_schedule(((0.02, 1.5), (0.06, 2.0))) == [(0.02, PRE_ROLL_S),
                                                         (0.06, round(PRE_ROLL_S + 1.5, 3))]


@pytest.mark.parametrize('value', ['nan', '0', '-0.5', '1.2', 'inf'])
def test_plant_discharge_coefficient_outside_0_1_is_refused_in_one_line(value, capsys,
                                                                        tmp_path) -> None:
    from valve_bringup.bench_loop import main
    with pytest.raises(SystemExit) as exc:
        main(['--mode', 'operation', '--plant-discharge-coefficient', value,
              '--out', str(tmp_path / 'out')])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert '--plant-discharge-coefficient' in err[-1] and 'expected a number in (0, 1]' \
        in err[-1], err
    assert not (tmp_path / 'out').exists()


def test_the_valve_in_service_differs_from_the_suite_only_in_its_discharge_coefficient(
        tmp_path) -> None:
    from valve_bringup.bench_loop import write_plant_parameters
    from valve_model_pkg.model import load_parameters
    plant = write_plant_parameters(tmp_path / 'plant.yaml', 0.62)
    suite, loaded = load_parameters(), load_parameters(str(tmp_path / 'plant.yaml'))
    assert loaded == suite.replace(discharge_coefficient=0.62)
    assert plant['full_opening_area_m2'] == pytest.approx(
        0.62 * suite.orifice_area_gradient_m * suite.stroke_m)
    assert plant['suite_full_opening_area_m2'] / plant['full_opening_area_m2'] == \
        pytest.approx(0.8 / 0.62)
