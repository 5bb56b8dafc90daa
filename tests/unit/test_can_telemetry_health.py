"""Telemetry loss on simulated time: frames missing -> ERROR; late but complete -> no ERROR.

:class:`TelemetryHealth` keeps no clock, so these tests state exactly when each frame
arrives and when the driver looks, and assert the documented rule: ERROR on silence beyond
the timeout (50 periods, at least 100 ms) or on 3 consecutive 0.1 s windows with at least
half their frames missing; OK again after 3 good windows.
"""
from __future__ import annotations

import pytest

from valve_driver_pkg.driver import DriverConfig
from valve_driver_pkg.driver.health import TelemetryHealth

PERIOD = 0.001
CFG = DriverConfig()


def health() -> TelemetryHealth:
    h = TelemetryHealth(CFG.telemetry_period_s, CFG.telemetry_timeout_s,
                        CFG.telemetry_window_s, CFG.telemetry_loss_fraction,
                        CFG.telemetry_error_windows, CFG.telemetry_ok_windows)
    h.reset(0.0)
    return h


def run(h: TelemetryHealth, arrivals: list[tuple[float, int]], until: float,
        tick: float = 0.0005) -> list:
    """Feed ``(arrival time, missing before it)`` frames; the driver looks every ``tick``."""
    changes = []
    arrivals = sorted(arrivals)
    i, t = 0, 0.0
    while t <= until:
        while i < len(arrivals) and arrivals[i][0] <= t:
            h.frame(*arrivals[i])
            i += 1
        change = h.update(t)
        if change is not None:
            changes.append((round(t, 4), change))
        t += tick
    return changes


def steady(t0: float, t1: float) -> list[tuple[float, int]]:
    return [(k * PERIOD, 0) for k in range(round(t0 / PERIOD), round(t1 / PERIOD))]


def test_the_documented_timeout() -> None:
    assert CFG.telemetry_timeout_s == pytest.approx(0.1)          # max(50 periods, 100 ms)
    assert DriverConfig(telemetry_rate_hz=100.0).telemetry_timeout_s == pytest.approx(0.5)


def test_fault_free_telemetry_never_errs() -> None:
    assert run(health(), steady(0.0, 5.0), 5.0) == []


def test_late_but_complete_frames_are_no_loss() -> None:
    # The receive thread starved for 80 ms, then reads the queued frames in one burst:
    # counters continuous, nothing missing -> no ERROR.
    frames = steady(0.0, 1.0) + [(1.08, 0)] * 80 + steady(1.08, 3.0)
    assert run(health(), frames, 3.0) == []


def test_silence_beyond_the_timeout_is_an_error_and_recovers_with_hysteresis() -> None:
    h = health()
    frames = steady(0.0, 1.0) + steady(1.3, 3.0)                  # 300 ms of silence
    changes = run(h, frames, 3.0)
    (t_lost, lost), (t_back, back) = changes
    assert lost.lost and lost.reason == 'silence'
    last = 0.999
    assert last + 0.1 < t_lost <= last + 0.1 + 0.001             # just after the timeout
    assert not back.lost
    assert 1.3 + 2 * CFG.telemetry_window_s <= t_back <= 1.3 + 4 * CFG.telemetry_window_s


def test_a_silence_shorter_than_the_timeout_is_no_error() -> None:
    assert run(health(), steady(0.0, 1.0) + steady(1.09, 2.0), 2.0) == []


def test_counter_gaps_in_three_windows_are_an_error() -> None:
    # From 1 s on, 3 of every 4 frames are missing (the counter shows gaps of 3).
    lossy = [(t, 3) for t, _ in steady(1.0, 2.0)[::4]]
    changes = run(health(), steady(0.0, 1.0) + lossy + steady(2.0, 3.0), 3.0)
    (t_lost, lost), (t_back, back) = changes
    assert lost.reason == 'counter gaps'
    assert 1.3 <= t_lost <= 1.4 + 1e-9                           # 3 bad windows
    assert 2.3 <= t_back <= 2.4 + 1e-9 and not back.lost          # 3 good windows


def test_moderate_gaps_or_a_single_bad_window_are_no_error() -> None:
    some = [(t, int(k % 5 == 0)) for k, (t, _) in enumerate(steady(1.0, 2.0))
            if k % 5 != 4]                                         # 20 % missing
    one_bad = [(t, 3) for t, _ in steady(1.0, 1.1)[::4]]          # one bad window only
    assert run(health(), steady(0.0, 1.0) + some + steady(2.0, 2.5), 2.5) == []
    assert run(health(), steady(0.0, 1.0) + one_bad + steady(1.1, 2.0), 2.0) == []


def test_a_gap_across_a_long_pause_is_not_trusted() -> None:
    # 20 periods between frames: the 4-bit counter may have wrapped; its gap says nothing.
    h = health()
    h.frame(0.0, 0)
    h.frame(0.02, 15)
    assert h._missing == 0
