"""Every node ends on SIGINT (Ctrl-C) and on SIGTERM with exit 0 and no traceback.

Each node is started as its own process, the test waits until it is up (in the ROS graph;
the emulator: its hub accepts connections), sends the signal to its process group as a
terminal's Ctrl-C does, and checks the exit status and the output.
"""
from __future__ import annotations

import os
import signal
import socket
import time

import pytest

rclpy = pytest.importorskip('rclpy')

from valve_bringup.backend import can_backend_commands, free_loopback_port  # noqa: E402

pytestmark = pytest.mark.node

SIGNALS = (signal.SIGINT, signal.SIGTERM)
NODES = ('valve_simulator', 'flow_to_duty', 'pneumatic_cylinder', 'position_controller',
         'valve_recorder', 'valve_can_driver', 'valve_controller_emulator',
         'valve_lockstep_sim', 'valve_bank_simulator')


def _hub_up(port: int) -> bool:
    try:
        with socket.create_connection(('127.0.0.1', port), timeout=0.2):
            return True
    except OSError:
        return False


@pytest.mark.parametrize('sig', SIGNALS, ids=lambda s: signal.Signals(s).name)
@pytest.mark.parametrize('name', NODES)
def test_node_ends_cleanly_on_signal(name, sig, start_node, ros, tmp_path) -> None:
    port = free_loopback_port()
    commands = can_backend_commands(1000.0, port=port)
    if name in ('valve_can_driver', 'valve_controller_emulator'):
        # The driver runs configured and active (bus threads running), against an emulator.
        emulator = start_node(*commands['valve_controller_emulator'])
        ros.wait_for(lambda: _hub_up(port) or not emulator.alive(), 30.0, 'the emulator hub')
    if name == 'valve_controller_emulator':
        proc = emulator
    elif name == 'valve_can_driver':
        proc = start_node(*commands['valve_can_driver'])
    elif name == 'valve_recorder':
        proc = start_node('valve_recorder', '-o', str(tmp_path / 'bag'))
    else:
        proc = start_node(name)
    if name != 'valve_controller_emulator':
        # Up = built: in the graph with its own publishers, beyond the two every node has
        # from its first moment (rosout, parameter_events).
        probe = ros.add(rclpy.create_node('signal_probe'))

        def up() -> bool:
            if name not in probe.get_node_names():
                return False
            return len(probe.get_publisher_names_and_types_by_node(name, '/')) > 2
        ros.wait_for(lambda: up() or not proc.alive(), 60.0, f'{name} up in the ROS graph')
    assert proc.alive(), proc.output
    time.sleep(1.0)  # up and running, not just constructed
    os.killpg(proc.proc.pid, sig)
    code = proc.proc.wait(timeout=30)
    out = proc.output
    assert code == 0, f'{name} exit {code} on {signal.Signals(sig).name}:\n{out[-3000:]}'
    assert 'Traceback' not in out, out[-3000:]
