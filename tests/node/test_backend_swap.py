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


@pytest.mark.serial   # a rate in wall time (1 kHz +-20 %)
@pytest.mark.parametrize('backend, source', [('sim', ValveState.SOURCE_SIMULATOR),
                                             ('can', ValveState.SOURCE_CAN)])
def test_controller_view_is_the_same_with_either_backend(start_node, ros, backend, source):
    procs = [start_node(*spec.argv) for spec in backend_processes(backend, rate_hz=1000.0)]
    probe = ros.add(StateProbe('swap_probe'))
    # A controller republishes its command (the CAN driver's watchdog closes the valve
    # when commands stop, as it must).
    command = {'duty': 0.0}
    probe.create_timer(0.05, lambda: probe.command(command['duty'], 50.0))
    ros.wait_for(lambda: probe.count > 50, 60.0, f'valve/state from the {backend} backend')

    probe.reset_window()
    ros.spin_for(2.0)
    w = probe.window()
    assert w.last.source == source
    assert w.rate_hz == pytest.approx(1000.0, rel=0.2)
    assert w.position_avg_pct == pytest.approx(0.0, abs=0.5)

    # The same duty command gives the same steady opening and flow within a few percent.
    command['duty'] = 0.5
    ros.spin_for(1.5)
    probe.reset_window()
    ros.spin_for(2.0)
    w = probe.window(x_max_m=X_MAX_M)
    assert w.last.duty == pytest.approx(0.5, abs=1e-3)
    assert w.last.pwm_frequency == pytest.approx(50.0, abs=0.1)
    # Reference: valve_simulator at 4 bar, 50 Hz, duty 0.5 gives about 51 % opening and
    # 1.0 g/s; both backends run the same model, the CAN one through the protocol.
    assert w.position_avg_pct == pytest.approx(51.0, abs=4.0)
    assert w.mass_flow_kg_s == pytest.approx(1.0e-3, rel=0.08)
    assert 0.45 < w.current_max_a < 1.0
    assert all(p.alive() for p in procs), [p.output[-1500:] for p in procs]

    command['duty'] = 0.0
    ros.spin_for(1.0)
    probe.reset_window()
    ros.spin_for(0.5)
    assert probe.window(x_max_m=X_MAX_M).position_avg_pct == pytest.approx(0.0, abs=0.5)
