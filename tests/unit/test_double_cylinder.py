"""The double-acting example: one 3/2 valve per chamber, one controller
commanding both, settles every demo step through the real valve model, drive electronics
and static duty map (ROS-free, the plant code valve_lockstep_sim runs with
cylinder:=double), also with 20 ms of extra transport delay."""
from __future__ import annotations

import numpy as np
import pytest
from suite_steps import assert_every_step_meets_the_specification

from valve_model_pkg.model import load_parameters
from valve_model_pkg.model.constants import ATMOSPHERIC_PRESSURE_PA
from valve_model_pkg.pneumatics.closed_loop import simulate_closed_loop_double
from valve_model_pkg.pneumatics.controller import DoublePositionController
from valve_model_pkg.pneumatics.double_cylinder import (DoubleCylinder, three_way_fill_flow,
                                                        three_way_flow)
from valve_model_pkg.pneumatics.goals import DEMO_GOALS, with_pre_roll

#: The demo's goals after its pre-roll at 0 mm.
DEMO = with_pre_roll(DEMO_GOALS)


@pytest.mark.parametrize('delay_s', [0.0, 0.020])
def test_every_demo_step_settles_within_specification(delay_s: float) -> None:
    r = simulate_closed_loop_double(DEMO, feedback_delay_s=delay_s)
    assert_every_step_meets_the_specification(r.t_s, r.setpoint_m, r.position_m,
                                              f'{delay_s * 1e3:.0f} ms delay')
    for duty in (r.cap_duty, r.rod_duty):
        assert np.all((duty >= 0.0) & (duty <= 1.0))
    # both valves work: at the end of every hold both chambers are pressurised (a stiff
    # axis), and the cap side is the higher where the spring pushes back harder
    ends = [int(round(t * 1000)) - 1 for t in np.cumsum([h for _, h in DEMO])[1:]]
    for k in ends:
        assert r.rod_pressure_pa[k] > ATMOSPHERIC_PRESSURE_PA + 0.5e5, k
        assert r.cap_pressure_pa[k] > ATMOSPHERIC_PRESSURE_PA + 0.5e5, k


def test_three_way_valve_fills_when_open_and_vents_when_closed() -> None:
    valve = load_parameters()
    sup = 4e5 + ATMOSPHERIC_PRESSURE_PA
    p = 2e5 + ATMOSPHERIC_PRESSURE_PA
    assert three_way_flow(valve.stroke_m, sup, p, valve) > 0.0
    assert three_way_flow(0.0, sup, p, valve) < 0.0
    assert three_way_flow(0.0, sup, ATMOSPHERIC_PRESSURE_PA, valve) == 0.0
    # the fill-flow inverse: net 0 needs a duty between 0 and 1; venting needs less
    hold = three_way_fill_flow(0.0, sup, p, valve)
    assert 0.0 < hold < three_way_flow(valve.stroke_m, sup, p, valve)
    assert three_way_fill_flow(-1.0, sup, p, valve) == 0.0


def test_force_split_gives_the_force_and_the_plant_needs_valve_parameters() -> None:
    ctl = DoublePositionController()
    for force in (-150.0, -50.0, 0.0, 40.0, 150.0):
        gc, gr = ctl.pressure_references_pa(force)
        assert 0.0 <= gc <= 4e5 and 0.0 <= gr <= 4e5
        assert ctl.cap_area_m2 * gc - ctl.rod_area_m2 * gr == pytest.approx(force, abs=1e-6)
    # beyond what the supply can pull: the most it can (cap vented, rod at supply)
    assert ctl.pressure_references_pa(-300.0) == (0.0, 4e5)
    with pytest.raises(ValueError, match='valve parameters'):
        DoubleCylinder()
    with pytest.raises(ValueError, match='not finite'):
        ctl.update(0.02, 0.0, 0.0, 0.005, float('nan'), 1e5)
