"""The demo's step specification, judged the same way for every closed loop that runs it
(the single-acting and the double-acting example, with and without transport delay)."""
from __future__ import annotations

import numpy as np

from valve_model_pkg.analysis import step_results

#: The demo's setpoints after its pre-roll at 0 mm [m].
DEMO_SETPOINTS_M = [0.02, 0.06, 0.04, 0.08, 0.03]
SETTLING_BAND_M = 1e-3
MAX_SETTLING_S = 2.0
MAX_OVERSHOOT_M = 3e-3
MAX_STEADY_ERROR_M = 0.5e-3


def assert_every_step_meets_the_specification(t_s: np.ndarray, setpoint_m: np.ndarray,
                                              position_m: np.ndarray, label: str) -> None:
    """Every demo step settles within the band, in time, without too much overshoot."""
    steps = step_results(t_s, setpoint_m, t_s, position_m, band_m=SETTLING_BAND_M)
    assert [round(s.setpoint_m, 3) for s in steps] == DEMO_SETPOINTS_M
    for s in steps:
        what = f'{s.setpoint_m * 1e3:.0f} mm step with {label}: {s}'
        assert s.settled, what
        assert s.settling_time_s <= MAX_SETTLING_S, what
        assert s.overshoot_m <= MAX_OVERSHOOT_M, what
        assert abs(s.steady_error_m) <= MAX_STEADY_ERROR_M, what
