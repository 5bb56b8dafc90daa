"""Why the loop in service calibrates the flow scale (docs/loop.md).

The ROS-free closed loop (controller -> flow_to_duty's inverter -> valve model -> cylinder)
on a valve that discharges with C_d = 0.62 where the suite's set says 0.8: with the
suite's map the valve delivers 0.78 of the commanded flow, the position loop stalls short of
the goal until its integral zone is reached; with the map recalibrated to the valve's
orifice (curves unchanged, the loop's ``recalibrated_map``) it tracks the same goals
closer. And on the suite's own valve the recalibrated map is the suite's map: the same
run to the last digit.
"""
from __future__ import annotations

import numpy as np

from valve_model_pkg.maps import load_map
from valve_model_pkg.maps.flow_identification import recalibrated_map
from valve_model_pkg.maps.inversion import OrificeConstants
from valve_model_pkg.model import load_parameters
from valve_model_pkg.pneumatics.closed_loop import simulate_closed_loop
from valve_model_pkg.pneumatics.goals import OPERATION_QUICK_GOALS, with_pre_roll

#: The loop's quick goals after its pre-roll at 0 mm.
GOALS = with_pre_roll(OPERATION_QUICK_GOALS)


def _rms_mm(duty_map, valve) -> float:
    r = simulate_closed_loop(GOALS, duty_map=duty_map, valve=valve)
    e = (r.setpoint_m - r.position_m)[r.t_s > 0.5]
    return float(np.sqrt(np.mean(e ** 2)) * 1e3)


def test_a_map_calibrated_to_the_valves_orifice_tracks_closer() -> None:
    suite_map = load_map()
    plant = load_parameters().replace(discharge_coefficient=0.62)
    calibrated = recalibrated_map(suite_map, plant, 'the test valve')
    assert OrificeConstants.from_parameters(calibrated.parameters).discharge_coefficient \
        == 0.62
    before, after = _rms_mm(suite_map, plant), _rms_mm(calibrated, plant)
    assert after < before - 0.5, (before, after)


def test_on_the_suites_own_valve_the_default_map_is_used() -> None:
    suite = load_parameters()
    a = simulate_closed_loop(GOALS[:2], valve=suite)
    b = simulate_closed_loop(GOALS[:2], valve=suite, duty_map=load_map())
    np.testing.assert_array_equal(a.position_m, b.position_m)
