"""Steps at known start times (steps_at) against steps found from setpoint changes."""
from __future__ import annotations

import numpy as np
import pytest

from valve_model_pkg.analysis import step_results, steps_at

TICK_S = 0.01


def _run() -> tuple[np.ndarray, np.ndarray]:
    """A first-order approach (tau 0.1 s) to 20 mm at 1 s, then to 60 mm at 3 s."""
    t = np.arange(0.0, 5.0, TICK_S)
    y = np.where(t < 1.0, 0.0, 0.020 * (1 - np.exp(-(t - 1.0) / 0.1)))
    y3 = y[np.searchsorted(t, 3.0)]
    y = np.where(t < 3.0, y, 0.060 + (y3 - 0.060) * np.exp(-(t - 3.0) / 0.1))
    return t, y


def test_known_starts_place_the_steps_where_late_setpoints_would_not() -> None:
    t, y = _run()
    known = steps_at(np.array([1.0, 3.0]), np.array([0.020, 0.060]), t, y)
    assert [s.start_s for s in known] == [1.0, 3.0]
    assert [s.setpoint_m for s in known] == [0.020, 0.060]
    # settling into 1 mm of a 20 mm / 40 mm step of tau 0.1 s: -tau ln(band/step)
    assert known[0].settling_time_s == pytest.approx(0.1 * np.log(20.0), abs=TICK_S)
    assert known[1].settling_time_s == pytest.approx(0.1 * np.log(40.0), abs=TICK_S)
    # the same setpoints placed 50 ms late: the steps start late, and the first one's
    # window ends inside the second step's rise, so it reads as not settled
    t_set = np.array([0.5, 1.05, 3.05])
    late = step_results(t_set, np.array([0.0, 0.020, 0.060]), t, y)
    assert [s.start_s for s in late] == pytest.approx([1.05, 3.05])
    assert known[0].settled and not late[0].settled


def test_known_starts_match_the_setpoint_changes_when_both_agree() -> None:
    t, y = _run()
    known = steps_at(np.array([1.0, 3.0]), np.array([0.020, 0.060]), t, y)
    found = step_results(np.array([0.0, 1.0, 3.0]), np.array([0.0, 0.020, 0.060]), t, y)
    assert known == found
    assert steps_at(np.array([1.0]), np.array([0.02]), t[:0], y[:0]) == []
