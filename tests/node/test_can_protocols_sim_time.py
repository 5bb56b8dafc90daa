"""valve_can_driver with protocol canopen and j1939 on simulation time (``use_sim_time``).

The rig of test_can_protocols_node (hub, stand-in device, driver as processes:
can_protocol_rig), started per test, with the test publishing /clock: a module of its own,
as that module's tests share one rclpy initialisation and these need their own.
"""
from __future__ import annotations

import numpy as np
import pytest
from can_protocol_rig import STATUSES, Client, Rig, drive_device, stamp_seconds
from rosgraph_msgs.msg import Clock
from suite_waits import SCHEDULING_ALLOWANCE_S

from valve_model_pkg.interface import TOPIC_CLOCK
from valve_model_pkg.interface.ros import CLOCK_QOS

pytestmark = [pytest.mark.node,
              pytest.mark.filterwarnings('ignore::DeprecationWarning:lark.utils')]


#: The simulation clock the test publishes starts here [s]: far from the wall clock.
SIM_START_S = 1000.0


@pytest.mark.parametrize('protocol', ['canopen', 'j1939'])
def test_a_device_driver_on_simulation_time_stamps_its_states_on_that_clock(
        protocol, start_node, ros, tmp_path) -> None:
    # use_sim_time: configure must succeed (the device core has the frame clock too), the
    # device gets the duty, and every state carries a /clock instant, never the wall clock
    rig = Rig(protocol, start_node, tmp_path, driver_params=('use_sim_time:=true',))
    try:
        client = ros.add(Client(rig.spec['label']))
        clock_pub = client.create_publisher(Clock, TOPIC_CLOCK, CLOCK_QOS)
        sent = {'ns': int(SIM_START_S * 1e9)}

        def tick() -> None:
            sent['ns'] += 10_000_000
            msg = Clock()
            msg.clock.sec, msg.clock.nanosec = divmod(sent['ns'], 1_000_000_000)
            clock_pub.publish(msg)
        client.create_timer(0.01, tick)
        ros.wait_for(lambda: client.all_ok(STATUSES[:3]) or not rig.driver.alive(), 60.0,
                     f'{protocol} driver on simulation time up')
        assert rig.driver.alive(), rig.driver.output[-3000:]
        drive_device(ros, client, rig, 0.4, f'{protocol} device output 0.4 on simulation time')
        # a state published before the driver's first /clock carries time 0 (no time yet)
        ros.wait_for(lambda: sum(stamp_seconds(m.header.stamp) > 0.0 for m in client.states) >= 5,
                     SCHEDULING_ALLOWANCE_S, 'states on the simulation clock')
        stamps = np.array([stamp_seconds(m.header.stamp) for m in client.states])
        stamps = stamps[stamps > 0.0]
        assert np.all(stamps >= SIM_START_S), stamps[:5]
        assert np.all(stamps <= sent['ns'] * 1e-9), (stamps[-5:], sent['ns'])
        drive_device(ros, client, rig, 0.0, f'{protocol} device output 0 on simulation time')
    finally:
        rig.close()
