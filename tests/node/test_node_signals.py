"""Every node ends on SIGINT (Ctrl-C) and on SIGTERM with exit 0 and no traceback.

Each node is started as its own process, the test waits until it runs (its executor
answers a parameter request; the emulator: it says it is ready), sends the signal to its
process group as a terminal's Ctrl-C does, and checks the exit status and the output.
"""
from __future__ import annotations

import signal

import pytest

from node_harness import poll_until
from valve_bringup.backend import can_backend_commands, free_loopback_port

pytestmark = pytest.mark.node

SIGNALS = (signal.SIGINT, signal.SIGTERM)
NODES = ('valve_simulator', 'flow_to_duty', 'pneumatic_cylinder', 'position_controller',
         'valve_recorder', 'valve_can_driver', 'valve_controller_emulator',
         'valve_lockstep_sim', 'valve_bank_simulator')


def _ready(emulator) -> bool:  # noqa: ANN001 - a NodeProcess
    """The emulator says it is ready once its signal handlers are in place and it runs."""
    return 'valve_controller_emulator ready' in emulator.output or not emulator.alive()


@pytest.mark.parametrize('sig', SIGNALS, ids=lambda s: signal.Signals(s).name)
@pytest.mark.parametrize('name', NODES)
def test_node_ends_cleanly_on_signal(name, sig, start_node, ros, tmp_path) -> None:
    port = free_loopback_port()
    commands = can_backend_commands(1000.0, port=port)
    if name in ('valve_can_driver', 'valve_controller_emulator'):
        # The driver runs configured and active (bus threads running), against an emulator.
        emulator = start_node(*commands['valve_controller_emulator'])
        poll_until(lambda: _ready(emulator), 60.0, 'the emulator to be ready')
    if name == 'valve_controller_emulator':
        proc = emulator
    elif name == 'valve_can_driver':
        proc = start_node(*commands['valve_can_driver'])
    elif name == 'valve_recorder':
        proc = start_node('valve_recorder', '-o', str(tmp_path / 'bag'))
    else:
        proc = start_node(name)
    assert proc.alive(), proc.output
    if name != 'valve_controller_emulator':
        # Up and running, not just constructed: its executor answers a parameter request.
        ros.wait_spinning(name, timeout_s=60.0)
    assert proc.alive(), proc.output
    proc.signal(sig)
    code = proc.proc.wait(timeout=30)
    out = proc.output
    assert code == 0, f'{name} exit {code} on {signal.Signals(sig).name}:\n{out[-3000:]}'
    assert 'Traceback' not in out, out[-3000:]
