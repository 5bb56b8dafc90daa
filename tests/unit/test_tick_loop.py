"""The simulators' real-time loop (nodes/tick_loop.py) on a scripted clock, without ROS."""
from __future__ import annotations

import pytest

from valve_model_pkg.nodes.tick_loop import TickLoop

MS = 1_000_000  # ns


class Model:
    """Records what the loop asks of the model; a wall clock the test moves by hand."""

    def __init__(self) -> None:
        self.t_s = 0.0
        self.stamps: list[int] = []
        self.model_times: list[float] = []
        self.restarts = 0
        self.wall = 100.0
        self.work_per_sample_s = 0.0

    def advance_to(self, t_s: float) -> None:
        self.t_s = max(self.t_s, t_s)
        self.wall += self.work_per_sample_s

    def publish(self, stamp_ns: int) -> None:
        self.stamps.append(stamp_ns)
        self.model_times.append(self.t_s)

    def restart(self) -> None:
        self.restarts += 1
        self.t_s = 0.0


def _loop(model: Model, max_advance_s: float = 0.05) -> TickLoop:
    return TickLoop(1e-3, max_advance_s, advance_to=model.advance_to, publish=model.publish,
                    restart=model.restart, wall_clock=lambda: model.wall)


def test_every_grid_instant_is_published_once_stamped_on_the_grid() -> None:
    m = Model()
    loop = _loop(m)
    t0 = 5_000 * MS
    for now in (t0, t0 + MS, t0 + 2 * MS, t0 + 5_400_000, t0 + 6 * MS):  # one late tick
        m.wall += 1e-3
        loop.tick(now)
    assert m.stamps == [t0 + k * MS for k in range(7)]
    assert m.model_times == [k * 1e-3 for k in range(7)]
    assert loop.late_samples == 2 and loop.ticks == 5 and loop.behind_ticks == 0


def test_a_clock_at_zero_is_no_tick() -> None:
    m = Model()
    loop = _loop(m)
    assert loop.tick(0) == ''
    assert loop.ticks == 0 and not m.stamps


def test_work_per_tick_is_bounded_and_the_gap_skipped() -> None:
    m = Model()
    loop = _loop(m, max_advance_s=0.01)
    loop.tick(1_000 * MS)
    reason = loop.tick(1_000 * MS + 500 * MS)          # the clock jumps 0.5 s
    assert 'behind the clock' in reason and 'skipped without integration' in reason
    assert loop.behind_ticks == 1 and loop.last_behind_reason == reason
    # at most max_advance of model time integrated in the jump: the rest is skipped
    assert m.model_times[-1] <= 0.011 + 1e-12
    assert loop.skipped_model_s == pytest.approx(0.5 - m.model_times[-1], abs=1e-9)
    # stamps still follow the clock
    assert m.stamps[-1] == 1_500 * MS


def test_clock_going_backwards_restarts_the_model() -> None:
    m = Model()
    loop = _loop(m)
    loop.tick(2_000 * MS)
    loop.tick(2_003 * MS)
    assert m.restarts == 0
    loop.tick(1_000 * MS)
    assert m.restarts == 1
    assert m.stamps[-1] == 1_000 * MS and m.model_times[-1] == 0.0


def test_a_slow_tick_is_reported_and_the_window_gives_the_rate() -> None:
    m = Model()
    loop = _loop(m)
    loop.tick(1_000 * MS)
    m.wall += 1e-3
    m.work_per_sample_s = 5e-3                           # 5 ms of work per 1 ms sample
    reason = loop.tick(1_001 * MS)
    assert 'longer than their period' in reason
    assert loop.max_tick_compute_s == pytest.approx(5e-3)
    m.wall += 0.994
    loop.close_window()
    assert loop.achieved_rate_hz == pytest.approx(2.0 / (m.wall - 100.0), rel=1e-9)
