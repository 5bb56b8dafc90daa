"""The CAN backend as processes: controller emulator + CAN driver on a tcp_loopback bus.

``valve_demo --backend can`` (``make demo BACKEND=can``) and the swap test start these in
place of ``valve_simulator``; ``valve/state`` then comes from the driver. Equivalent shell
commands (in a shell that sourced ``ros2_ws/env.bash``)::

    valve_controller_emulator --interface tcp_loopback --channel 127.0.0.1:29536 &
    valve_can_driver --ros-args -p interface:=tcp_loopback -p channel:=127.0.0.1:29536 \\
        -p autostart:=true

ROS-free: it only builds command lines.
"""
from __future__ import annotations

import socket
from collections.abc import Sequence

from valve_bringup.supervisor import ProcessSpec

__all__ = ['can_backend_processes', 'can_backend_commands', 'free_loopback_port',
           'device_backend_processes', 'DEVICE_STATE_PERIOD_S']

#: How often the stand-in device of each protocol reports, so how often valve/state comes
#: [s]: CiA 401 TPDO1 at the driver's command period (10 ms), the J1939 Estimated Flow
#: every 100 ms (ISO 11783-7), the example board's status every 100 ms (its DBC).
DEVICE_STATE_PERIOD_S = {'canopen': 0.01, 'j1939': 0.1, 'dbc': 0.1}


def free_loopback_port() -> int:
    """A TCP port on 127.0.0.1 that is free now (the emulator's hub binds it next)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(('127.0.0.1', 0))
        return sock.getsockname()[1]


def can_backend_commands(rate_hz: float = 1000.0, *, port: int | None = None,
                         node_id: int = 0, command_timeout_s: float = 2.0,
                         emulator_args: Sequence[str] = (),
                         driver_args: Sequence[str] = (),
                         drive_mode: str | None = None) -> dict[str, list[str]]:
    """Command lines of the emulator and the driver, by process name.

    Parameters
    ----------
    rate_hz : float
        Telemetry rate of the emulator = ``valve/state`` rate of the driver [Hz].
    port : int | None
        Loopback port of the emulator's hub; ``None`` picks a free one (parallel runs
        do not collide).
    node_id : int
        Controller node id.
    command_timeout_s : float
        The driver's duty-command watchdog [s]. The default 2 s outlasts the demo's
        longest step, which publishes each command once; a controller that republishes
        its commands can use the node's own default (0.5 s). 0 switches it off.
    emulator_args, driver_args : sequence of str
        Extra arguments (e.g. ``['--effect', 'coil_heating']`` for the emulator,
        ``['-p', 'valve_name:=valve1']`` for the driver, after ``--ros-args``).
    drive_mode : str | None
        The driver's ``drive_mode`` parameter (``'normal'`` | ``'bench'``: boost, chopper
        and capacitor bypassed, sent in every ``ValveCommand``); ``None`` = the driver's
        default (normal). The emulator takes the mode from the frames.
    """
    channel = f'127.0.0.1:{port if port is not None else free_loopback_port()}'
    return {
        'valve_controller_emulator': [
            'valve_controller_emulator', '--interface', 'tcp_loopback', '--channel', channel,
            '--node-id', str(node_id), '--telemetry-rate-hz', f'{float(rate_hz):g}',
            *emulator_args],
        'valve_can_driver': [
            'valve_can_driver', '--ros-args', '-p', 'interface:=tcp_loopback',
            '-p', f'channel:={channel}', '-p', f'node_id:={node_id}',
            '-p', f'telemetry_rate_hz:={float(rate_hz)}',
            '-p', f'command_timeout_s:={float(command_timeout_s)}',
            '-p', 'autostart:=true',
            *(('-p', f'drive_mode:={drive_mode}') if drive_mode is not None else ()),
            *driver_args],
    }


def can_backend_processes(rate_hz: float = 1000.0, **kwargs: object) -> list[ProcessSpec]:
    """:func:`can_backend_commands` as supervisor specs, emulator first (it hosts the bus)."""
    commands = can_backend_commands(rate_hz, **kwargs)
    # The emulator hosts the loopback bus: it stops after the driver, so the driver never
    # sees its bus vanish while it shuts down.
    return [ProcessSpec(name, argv, stop_last=name == 'valve_controller_emulator')
            for name, argv in commands.items()]


def device_backend_processes(protocol: str, *, port: int | None = None,
                             command_timeout_s: float = 2.0) -> list[ProcessSpec]:
    """A stand-in device of ``protocol`` (canopen, j1939, dbc; it hosts the bus) and the
    driver speaking that protocol to it, on wall-clock time (valve_driver_pkg.standins)."""
    from valve_driver_pkg.devices.dbc_protocol import example_dbc_path, example_mapping_path
    channel = f'127.0.0.1:{port if port is not None else free_loopback_port()}'
    device, params = {
        'canopen': (['valve_canopen_device', '--node-id', '1'], ['canopen.node_id:=1']),
        'j1939': (['valve_j1939_device'], []),
        'dbc': (['valve_dbc_device'], [f'dbc.file:={example_dbc_path()}',
                                       f'dbc.mapping_file:={example_mapping_path()}']),
    }[protocol]
    driver = ['valve_can_driver', '--ros-args', '-p', f'protocol:={protocol}',
              '-p', 'interface:=tcp_loopback', '-p', f'channel:={channel}',
              '-p', f'command_timeout_s:={float(command_timeout_s)}', '-p', 'autostart:=true',
              *(a for p in params for a in ('-p', p))]
    return [ProcessSpec(device[0], [*device, '--interface', 'tcp_loopback', '--channel',
                                    channel], stop_last=True),
            ProcessSpec('valve_can_driver', driver)]
