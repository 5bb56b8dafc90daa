"""The CAN lockstep start handshake, ROS-free: the emulator sends its t = 0 frames once,
only after the driver is on the bus and then the simulation's clock came; the simulation
asks for its first step only after every valve's t = 0 state (or gives up, counted)."""
from __future__ import annotations

from valve_driver_pkg.emulator.lockstep import LockstepGateState
from valve_model_pkg.pneumatics.lockstep import StartHandshake

CONTROL_NS = 5_000_000


def _bridge_start(events: list[str]) -> list[bool]:
    """start_due() after each event, as the bridge applies them ('host' frame, 'clock')."""
    gate = LockstepGateState(CONTROL_NS)
    due = []
    for event in events:
        if event == 'host':
            gate.host_seen = True
        else:   # what on_clock does: a clock counts only after the host was seen
            gate.clock_seen = gate.clock_seen or gate.host_seen
        due.append(gate.start_due())
    return due


def test_t0_frames_wait_for_the_driver_then_the_clock():
    # host first, then the clock: sent at the clock
    assert _bridge_start(['host', 'host', 'clock']) == [False, False, True]
    # a clock before the driver was on the bus does not count: the next one does
    assert _bridge_start(['clock', 'clock', 'host', 'clock']) == [False, False, False, True]


def test_t0_frames_are_sent_exactly_once():
    # one t = 0 state in all: none can reach the simulation after it asked for a step
    assert _bridge_start(['host', 'clock', 'clock', 'host', 'clock']) == \
        [False, True, False, False, False]


def test_simulation_waits_for_every_valve_state():
    hs = StartHandshake(('cap', 'rod'), timeout_s=10.0)
    assert not hs.ready
    assert hs.state('cap') is False
    assert not hs.ready
    assert hs.state('other') is False   # not one of its valves
    assert hs.state('rod') is True      # this one made it ready
    assert hs.ready
    assert hs.state('rod') is False     # again: no news


def test_handshake_timeout_counts_from_when_the_simulation_wants_to_run():
    hs = StartHandshake(('',), timeout_s=10.0)
    assert not hs.check_timeout(100.0)   # starts the wait
    assert not hs.check_timeout(110.0)   # 10 s: not yet more than the timeout
    assert hs.check_timeout(110.5)
    assert hs.ready and hs.gave_up
    assert "valve(s) ''" in hs.last_timeout and 'start handshake' in hs.last_timeout
    assert not hs.check_timeout(200.0)   # counted once


def test_no_timeout_once_ready():
    hs = StartHandshake(('',), timeout_s=1.0)
    hs.check_timeout(0.0)
    hs.state('')
    assert not hs.check_timeout(100.0)
    assert not hs.gave_up
