"""The CAN protocol rig of the node tests: tcp_loopback hub, stand-in device and
valve_can_driver as processes, the test joined to the hub as a bus client, and the test's
ROS node (states, diagnostics, duty commands) (tests/node/test_can_protocols_node.py)."""
from __future__ import annotations

import re
import sys

import can
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from std_srvs.srv import Trigger
from suite_waits import SCHEDULING_ALLOWANCE_S
from valve_msgs.msg import DutyCommand, ValveState

from valve_driver_pkg.canbus import TcpLoopbackBus
from valve_driver_pkg.devices.dbc_protocol import example_dbc_path, example_mapping_path

STATUSES = ('CAN bus', 'device', 'commands', 'faults')
_OUTPUT = re.compile(r': output duty ([0-9.]+) at monotonic ([0-9.]+): (.*)$', re.M)
#: The example board's DBC file, the dbc protocol's.
DBC_FILE = example_dbc_path()


PROTOCOLS = {
    'canopen': dict(
        device=['valve_canopen_device', '--node-id', '5'], first_device_args=[],
        params=['canopen.node_id:=5', 'canopen.heartbeat_ms:=100'],
        label='canopen node 5', timeout_s=0.3, period_s=0.01, duty_step=0.001,
        has_current=True),
    'j1939': dict(
        device=['valve_j1939_device', '--valve-index', '2'],
        first_device_args=['--dtc', '1907:5'],     # an active DTC the clear test clears
        params=['j1939.valve_index:=2', 'j1939.source_address:=128',
                'j1939.command_period_ms:=100'],
        label='j1939 valve 2', timeout_s=0.3, period_s=0.1, duty_step=0.01,
        has_current=False),
    'dbc': dict(
        device=['valve_dbc_device'], first_device_args=[],
        params=[f'dbc.file:={DBC_FILE}', f'dbc.mapping_file:={example_mapping_path()}'],
        label='dbc board', timeout_s=0.2, period_s=0.02, duty_step=0.0001,
        has_current=True),
}


def stamp_seconds(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def outputs(proc) -> list[tuple[float, float, str]]:
    """(duty, monotonic time, reason) of every output change a stand-in printed."""
    return [(float(d), float(t), r) for d, t, r in _OUTPUT.findall(proc.output)]


class Rig:
    """Hub, device, driver and the test's bus client for one protocol."""

    def __init__(self, name: str, start, folder, driver_params: tuple[str, ...] = ()) -> None:
        self.name = name
        self.spec = PROTOCOLS[name]
        self.start = start
        self.procs = []
        self.hub = self._start(sys.executable, '-m', 'valve_driver_pkg.canbus.cli')
        self.hub.wait_ready('tcp_loopback hub ready')
        self.channel = re.search(r'hub ready: (\S+)', self.hub.output).group(1)
        self.currents_ma: list[int] = []
        self.bus = TcpLoopbackBus(self.channel)
        self.notifier = can.Notifier(self.bus, [self._on_frame], timeout=0.1)
        self.log_file = folder / f'bus-{name}.log'
        self.device = self.start_device(self.spec['first_device_args'])
        self.driver = self._start(
            'valve_can_driver', '--ros-args', '-p', f'protocol:={name}',
            '-p', 'interface:=tcp_loopback', '-p', f'channel:={self.channel}',
            '-p', 'autostart:=true', '-p', 'command_timeout_s:=0.0',
            '-p', f'log_frames_file:={self.log_file}',
            *(a for p in (*self.spec['params'], *driver_params) for a in ('-p', p)))

    def _start(self, *argv: str):
        proc = self.start(*argv)
        self.procs.append(proc)
        return proc

    def start_device(self, extra: list[str] = ()):
        proc = self._start(*self.spec['device'], *extra, '--interface', 'tcp_loopback',
                           '--channel', self.channel, '--no-hub')
        proc.wait_ready('ready')
        self.device = proc
        return proc

    def _on_frame(self, msg: can.Message) -> None:
        data = bytes(msg.data)
        if self.name == 'canopen' and msg.arbitration_id == 0x185 and len(data) >= 2:
            self.currents_ma.append(int.from_bytes(data[:2], 'little', signed=True))
        if self.name == 'dbc' and msg.arbitration_id == 0x18FF2021 and data[0] == 0:
            self.currents_ma.append(int.from_bytes(data[1:3], 'big', signed=True))

    def close(self) -> None:
        """Stop the driver, the devices, the test's bus client, the hub (in that order)."""
        for proc in reversed(self.procs[1:]):
            proc.stop()
        self.notifier.stop()
        self.bus.shutdown()
        self.hub.stop()


class Client(Node):
    def __init__(self, label: str) -> None:
        super().__init__(f'can_protocol_test_client_{label.replace(" ", "_")}')
        self.prefix = f'valve_can_driver {label}: '
        self.states: list[ValveState] = []
        self.status: dict[str, object] = {}
        self.device_errors_s: list[float] = []   # stamps of the device ERROR reports
        self.create_subscription(ValveState, 'valve/state', self.states.append, 1000)
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 100)
        self.pub = self.create_publisher(DutyCommand, 'valve/duty_command', 10)
        self.clear = self.create_client(Trigger, 'valve_can_driver/clear_faults')

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith(self.prefix):
                name = status.name[len(self.prefix):]
                self.status[name] = status
                if name == 'device' and self.level(name) == 2:
                    self.device_errors_s.append(stamp_seconds(msg.header.stamp))

    def device_error_after(self, t_s: float) -> float | None:
        """Stamp of the first device ERROR report stamped after ``t_s`` (wall clock, s)."""
        return next((e for e in self.device_errors_s if e > t_s), None)

    def level(self, name: str) -> int:
        status = self.status.get(name)
        if status is None:
            return -1
        return status.level[0] if isinstance(status.level, bytes) else int(status.level)

    def all_ok(self, names: tuple[str, ...] = STATUSES) -> bool:
        return all(self.level(n) == 0 for n in names)

    def messages(self) -> dict[str, str]:
        return {k: v.message for k, v in self.status.items()}

    def value(self, name: str, key: str) -> str:
        return {kv.key: kv.value for kv in self.status[name].values}[key]

    def command(self, duty: float) -> None:
        msg = DutyCommand()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.duty, msg.pwm_frequency = float(duty), 50.0
        self.pub.publish(msg)


def drive_device(ros, client: Client, rig: Rig, duty: float, what: str) -> None:
    """Command ``duty`` until the device's output is that duty (within its resolution)."""
    step = rig.spec['duty_step']

    def arrived() -> bool:
        client.command(duty)
        outs = outputs(rig.device)
        return bool(outs) and abs(outs[-1][0] - duty) <= step

    ros.wait_for(arrived, SCHEDULING_ALLOWANCE_S, what)
