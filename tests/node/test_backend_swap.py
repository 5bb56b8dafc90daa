"""One test, both backends: what a controller sees does not depend on simulator vs CAN.

The backend is chosen exactly as `make demo BACKEND=...` and the launch argument
`backend:=...` choose it (valve_bringup.demo.backend_processes).
"""
from __future__ import annotations

import pytest
from valve_msgs.msg import ValveState

from valve_bringup.demo import backend_processes
from valve_model_pkg.nodes.probe import StateProbe

pytestmark = pytest.mark.node

X_MAX_M = 0.33e-3
RATE_HZ = 1000.0


def _stamp_s(msg: ValveState) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def _at_duty(ros, probe: StateProbe, duty: float, settle_s: float,
             span_s: float) -> list[ValveState]:
    """The states of ``span_s`` of stamp time during which ``duty`` stayed in force, from
    ``settle_s`` after it (again) took force (the windows are the stream's own time, not
    the test's). A state at another duty after the first one at ``duty`` restarts the
    window; while a duty above 0 is commanded such a state must show the valve
    de-energised: on a loaded machine a command may reach the CAN device late, whose
    watchdog then closes the valve, as it must."""
    probe.messages.clear()
    probe.keep_messages = True
    interruptions: list[float] = []

    def window() -> list[ValveState]:
        msgs = list(probe.messages)
        first_on = next((i for i, m in enumerate(msgs) if abs(m.duty - duty) < 1e-9), None)
        if first_on is None:
            return []
        start = first_on
        interruptions.clear()
        for i in range(first_on, len(msgs)):
            if abs(msgs[i].duty - duty) >= 1e-9:
                interruptions.append(msgs[i].duty)
                start = i + 1
        tail = msgs[start:]
        if not tail:
            return []
        t0 = _stamp_s(tail[0]) + settle_s
        return [m for m in tail if _stamp_s(m) >= t0]
    ros.wait_for(lambda: (w := window()) and _stamp_s(w[-1]) - _stamp_s(w[0]) >= span_s,
                 60.0, f'{span_s:g} s of valve/state after {settle_s:g} s at duty {duty:g}')
    probe.keep_messages = False
    out = window()
    if duty != 0.0:
        assert all(d == 0.0 for d in interruptions), interruptions
    return out


def _mean(values) -> float:
    values = list(values)
    return sum(values) / len(values)


@pytest.mark.parametrize('backend, source', [('sim', ValveState.SOURCE_SIMULATOR),
                                             ('can', ValveState.SOURCE_CAN)])
def test_controller_view_is_the_same_with_either_backend(start_node, ros, backend, source):
    procs = [start_node(*spec.argv) for spec in backend_processes(backend, rate_hz=RATE_HZ)]
    probe = ros.add(StateProbe('swap_probe'))
    # A controller republishes its command (the CAN driver's watchdog closes the valve
    # when commands stop, as it must).
    command = {'duty': 0.0}
    probe.create_timer(0.05, lambda: probe.command(command['duty'], 50.0))
    ros.wait_for(lambda: probe.count > 50, 60.0, f'valve/state from the {backend} backend')

    # One time-ordered stream of samples from either backend. The simulator stamps each
    # with its model time: every stamp step is one period or whole periods it skipped (a
    # loaded machine may hold it up). The CAN driver stamps each telemetry frame on
    # receipt (wall clock), so its stamps only have to ascend; the emulator's telemetry
    # period and its loss counting are the CAN tests' to prove.
    closed = _at_duty(ros, probe, 0.0, settle_s=0.0, span_s=2.0)
    steps = [_stamp_s(b) - _stamp_s(a) for a, b in zip(closed, closed[1:])]
    assert all(d > 0.0 for d in steps), min(steps)
    if backend == 'sim':
        periods = [d * RATE_HZ for d in steps]
        assert all(abs(p - round(p)) < 1e-3 and round(p) >= 1 for p in periods), periods
    assert all(m.source == source for m in closed)
    assert 100.0 * _mean(m.spool_position_avg for m in closed) / X_MAX_M == \
        pytest.approx(0.0, abs=0.5)

    # The same duty command gives the same steady opening and flow within a few percent.
    command['duty'] = 0.5
    on = _at_duty(ros, probe, 0.5, settle_s=1.5, span_s=2.0)
    assert all(m.duty == pytest.approx(0.5, abs=1e-3) for m in on)
    assert all(m.pwm_frequency == pytest.approx(50.0, abs=0.1) for m in on)
    # Reference: valve_simulator at 4 bar, 50 Hz, duty 0.5 gives about 51 % opening and
    # 1.0 g/s; both backends run the same model, the CAN one through the protocol.
    assert 100.0 * _mean(m.spool_position_avg for m in on) / X_MAX_M == \
        pytest.approx(51.0, abs=4.0)
    assert _mean(m.mass_flow for m in on) == pytest.approx(1.0e-3, rel=0.08)
    assert 0.45 < max(m.coil_current for m in on) < 1.0
    assert all(p.alive() for p in procs), [p.output[-1500:] for p in procs]

    command['duty'] = 0.0
    off = _at_duty(ros, probe, 0.0, settle_s=1.0, span_s=0.5)
    assert 100.0 * _mean(m.spool_position_avg for m in off) / X_MAX_M == \
        pytest.approx(0.0, abs=0.5)
