"""The example position controller settles every demo step, through the
real valve model, drive electronics and static duty map (ROS-free closed loop, the same
plant code valve_lockstep_sim runs), also with 20 ms of extra transport delay."""
from __future__ import annotations

import numpy as np
import pytest

from valve_model_pkg.analysis import step_results
from valve_model_pkg.pneumatics.closed_loop import simulate_closed_loop
from valve_model_pkg.pneumatics.controller import ControllerGains, PositionController
from valve_model_pkg.pneumatics.goals import DEMO_GOALS, with_pre_roll

#: The demo's goals after its pre-roll at 0 mm.
DEMO = with_pre_roll(DEMO_GOALS)


@pytest.mark.parametrize('delay_s', [0.0, 0.020])
def test_every_demo_step_settles_within_specification(delay_s: float) -> None:
    r = simulate_closed_loop(DEMO, feedback_delay_s=delay_s)
    steps = step_results(r.t_s, r.setpoint_m, r.t_s, r.position_m, band_m=1e-3)
    assert [round(s.setpoint_m, 3) for s in steps] == [0.02, 0.06, 0.04, 0.08, 0.03]
    for s in steps:
        what = f'{s.setpoint_m * 1e3:.0f} mm step with {delay_s * 1e3:.0f} ms delay: {s}'
        assert s.settled, what
        assert s.settling_time_s <= 2.0, what
        assert s.overshoot_m <= 3e-3, what
        assert abs(s.steady_error_m) <= 0.5e-3, what
    assert np.all((r.duty >= 0.0) & (r.duty <= 1.0))


def test_cascade_needs_the_pressure_and_falls_back_to_the_flow_pid_without_it() -> None:
    ctl = PositionController()
    assert ctl.gains.structure == 'cascade'
    with_p = ctl.update(0.02, 0.0, 0.0, 0.005, pressure_pa=101325.0)
    assert with_p > 0.0 and np.isfinite(ctl.last_pressure_reference_pa)
    pid = PositionController(ControllerGains(structure='pid'))
    assert PositionController().update(0.02, 0.0, 0.0, 0.005) == \
        pytest.approx(pid.update(0.02, 0.0, 0.0, 0.005))
    with pytest.raises(ValueError, match='structure'):
        ControllerGains(structure='bang-bang')
    with pytest.raises(ValueError, match='pressure_pa'):
        ctl.update(0.02, 0.0, 0.0, 0.005, pressure_pa=float('nan'))
