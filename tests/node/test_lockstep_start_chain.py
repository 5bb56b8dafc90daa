"""The CAN lockstep chain's start (emulator on /clock -> CAN -> driver -> valve/state ->
valve_lockstep_sim): the simulation is asked to run before the CAN driver exists, and its
first step must not be lost. A telemetry frame sent before the driver is on the bus reaches
nobody and cannot be sent again; the start handshake holds step 1 until the t = 0 state
has gone the whole chain, so a driver that comes up last costs no lockstep timeout ("no
valve/state for t = 0.001 s").

Asserts counts (no lockstep timeout, the steps reached), not a timing: the
driver starts only after the simulation was told to run (an order of events); the
lockstep timeout is set long so that a slow start-up on a loaded computer is no timeout.
"""
from __future__ import annotations

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64

from valve_bringup.backend import can_backend_commands
from valve_model_pkg.interface import TOPIC_CLOCK, TOPIC_DIAGNOSTICS, TOPIC_RUN_UNTIL
from valve_model_pkg.interface.ros import CLOCK_QOS, COMMAND_QOS, DIAGNOSTICS_QOS

pytestmark = pytest.mark.node

#: Long enough that no start-up counts as a timeout; a lost first step waits this long [s].
TIMEOUT_S = 30.0
#: Four 1 ms steps: before the first control tick after t = 0 (no controller needed) [s].
RUN_UNTIL_S = 0.004


def test_first_step_is_not_lost_when_the_driver_comes_up_last(start_node, ros):
    commands = can_backend_commands(
        1000.0, emulator_args=('--clock', 'sim', '--step-s', '0.001',
                               '--lockstep-timeout-s', f'{TIMEOUT_S:g}'),
        driver_args=('-p', 'use_sim_time:=true', '-p', 'telemetry_timeout_min_s:=10.0'))
    emulator = start_node(*commands['valve_controller_emulator'])
    sim = start_node('valve_lockstep_sim', '--ros-args', '-p', 'start_paused:=true',
                     '-p', 'real_time_factor_max:=0.0', '-p', 'valve_source:=external',
                     '-p', f'lockstep_timeout_s:={TIMEOUT_S}',
                     '-p', 'diagnostics_period_s:=0.2')
    node = ros.add(rclpy.create_node('start_chain_probe'))
    seen = {'clock_ns': -1, 'values': {}}

    def on_clock(msg: Clock) -> None:
        seen['clock_ns'] = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if 'lockstep simulation' in status.name:
                seen['values'] = {kv.key: kv.value for kv in status.values}

    node.create_subscription(Clock, TOPIC_CLOCK, on_clock, CLOCK_QOS)
    node.create_subscription(DiagnosticArray, TOPIC_DIAGNOSTICS, on_diagnostics,
                             DIAGNOSTICS_QOS)
    run_until = node.create_publisher(Float64, TOPIC_RUN_UNTIL, COMMAND_QOS)
    ros.wait_for(lambda: bool(seen['values']) and run_until.get_subscription_count() > 0,
                 60.0, 'the lockstep simulation')
    # The simulation is told to run now, before the driver exists (run_until is sent
    # again below: idempotent, for a subscription that matched late).
    run_until.publish(Float64(data=RUN_UNTIL_S))
    ros.spin_for(0.5)
    driver = start_node(*commands['valve_can_driver'])

    def reached() -> bool:
        run_until.publish(Float64(data=RUN_UNTIL_S))
        return seen['clock_ns'] >= int(RUN_UNTIL_S * 1e9)
    ros.wait_for(reached, 2 * TIMEOUT_S + 30.0, f'simulation time {RUN_UNTIL_S} s')
    steps = round(RUN_UNTIL_S / 0.001)
    ros.wait_for(lambda: int(seen['values'].get('steps', '0')) >= steps, 10.0,
                 'diagnostics at the hold')
    values = seen['values']
    # No loss at all: the driver's t = 0 state may be published before its DDS writer has
    # matched the simulation's reader (the simulation sees the writer first), and the
    # writer keeps it for that reader (durable valve/state), so the handshake completes.
    assert int(values['lockstep_timeouts']) == 0, values.get('last_lockstep_timeout')
    assert values['start_handshake'] == 'done', values
    assert int(values['steps']) == steps
    assert all(p.alive() for p in (emulator, sim, driver)), \
        [p.output[-1500:] for p in (emulator, sim, driver)]
    assert 'start handshake' in emulator.output
