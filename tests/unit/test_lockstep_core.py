"""The lockstep protocol's ROS-free bookkeeping: pace cap, the per-tick gate, the
real-time factor (valve_model_pkg.pneumatics.lockstep)."""
from __future__ import annotations

import pytest

from valve_model_pkg.pneumatics.lockstep import LockstepGate, Pacer, RealTimeFactor

MS = 1_000_000


def test_pacer_caps_the_pace_at_the_factor_and_never_races_to_catch_up() -> None:
    pacer = Pacer(max_factor=1.0, slack_s=0.05)
    assert pacer.may_step(10.0, 0)
    # 1 ms of simulation is due 1 ms of wall time later, not before.
    assert not pacer.may_step(10.0005, 1 * MS)
    assert pacer.wait_s(10.0005, 1 * MS) == pytest.approx(0.0005)
    assert pacer.may_step(10.001, 1 * MS)
    # Far behind (a stall): the pace restarts from here instead of bursting to catch up.
    assert pacer.may_step(11.0, 2 * MS)
    assert not pacer.may_step(11.0005, 3 * MS)


def test_pacer_without_a_cap_always_steps() -> None:
    pacer = Pacer(max_factor=0.0)
    assert all(pacer.may_step(0.0, k * MS) for k in range(100))
    assert pacer.wait_s(0.0, 10**12) == 0.0


def test_gate_waits_for_every_valve_of_the_tick_and_ignores_older_stamps() -> None:
    gate = LockstepGate(('cap', 'rod'), timeout_s=1.0)
    gate.open_tick(5 * MS, wall_s=0.0)
    assert gate.waiting
    gate.answer('cap', 0, wall_s=0.01)          # an answer to an older tick
    assert gate.owed == {'cap', 'rod'}
    gate.answer('cap', 5 * MS, wall_s=0.01)
    assert gate.waiting
    gate.answer('rod', 5 * MS, wall_s=0.02)
    assert not gate.waiting
    assert gate.max_wait_s == pytest.approx(0.02)
    assert gate.timeouts == 0 and gate.ticks == 1


def test_gate_counts_an_answer_that_came_before_its_tick_opened_and_flags_stale_ones() -> None:
    """The t = 0 tick is answered while the simulation is held, before the gate opens it:
    that answer counts; a tick's answer sent again after a newer one is stale."""
    gate = LockstepGate(('cap', 'rod'), timeout_s=1.0)
    gate.answer('cap', 0, wall_s=0.0)
    gate.open_tick(0, wall_s=0.5)
    assert gate.owed == {'rod'}
    gate.answer('rod', 0, wall_s=0.6)
    assert not gate.waiting
    gate.open_tick(5 * MS, wall_s=0.7)
    assert gate.owed == {'cap', 'rod'}
    gate.answer('cap', 5 * MS, wall_s=0.71)
    assert gate.is_stale('cap', 0) and not gate.is_stale('cap', 5 * MS)
    assert not gate.is_stale('rod', 0)
    gate.answer('cap', 0, wall_s=0.72)      # a stale answer does not lower the newest
    assert gate.is_stale('cap', 0)


def test_gate_timeout_is_counted_and_named_not_hidden() -> None:
    gate = LockstepGate(('',), timeout_s=0.5)
    gate.open_tick(10 * MS, wall_s=1.0)
    assert not gate.check_timeout(1.4)
    assert gate.check_timeout(1.6)
    assert not gate.waiting
    assert gate.timeouts == 1
    assert 't = 0.010 s' in gate.last_timeout and '0.5 s' in gate.last_timeout


def test_real_time_factor_over_a_window_and_overall() -> None:
    rtf = RealTimeFactor(window_s=1.0)
    rtf.update(0.0, 0)
    rtf.update(0.5, 250 * MS)
    assert rtf.last_window == 0.0   # window not complete yet
    rtf.update(1.0, 500 * MS)
    assert rtf.last_window == pytest.approx(0.5)
    assert rtf.overall(2.0, 1000 * MS) == pytest.approx(0.5)
