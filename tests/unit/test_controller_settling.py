"""The example position controller settles every demo step, through the
real valve model, drive electronics and static duty map (ROS-free closed loop, the same
plant code valve_lockstep_sim runs), also with 20 ms of extra transport delay."""
from __future__ import annotations

import numpy as np
import pytest
from suite_steps import assert_every_step_meets_the_specification

from valve_model_pkg.pneumatics.closed_loop import simulate_closed_loop
from valve_model_pkg.pneumatics.controller import ControllerGains, PositionController
from valve_model_pkg.pneumatics.goals import DEMO_GOALS, with_pre_roll

#: The demo's goals after its pre-roll at 0 mm.
DEMO = with_pre_roll(DEMO_GOALS)


@pytest.mark.parametrize('delay_s', [0.0, 0.020])
def test_every_demo_step_settles_within_specification(delay_s: float) -> None:
    r = simulate_closed_loop(DEMO, feedback_delay_s=delay_s)
    assert_every_step_meets_the_specification(r.t_s, r.setpoint_m, r.position_m,
                                              f'{delay_s * 1e3:.0f} ms delay')
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
