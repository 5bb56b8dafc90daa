"""valve_can_driver with protocol canopen, j1939 and dbc against the stand-in devices.

Each protocol gets a hub (in the test process), its stand-in device and the driver as
processes, shared by the tests of that protocol in the order below (the last kills the
driver). The test joins the hub as a bus client and decodes the device's frames itself
(CiA 401 TPDO1: analog input 1 in mA; the example board's status page 0: coil current in
mA, Motorola), so the current on ``valve/state`` is checked against the bus, not against
the driver's code. The device prints every change of its output with CLOCK_MONOTONIC; the
duty it received and the fail-safe time come from those lines.

Fail-safe bound after SIGKILL of the driver: the device's own timeout (CANopen: its
heartbeat consumer, 3 x ``canopen.heartbeat_ms``; J1939: the valve's command timeout,
300 ms; DBC: the board's, 200 ms) plus one command period. The device counts that timeout
from the last frame it received, which is before the kill; what a loaded machine adds is
the device's own scheduling delay, bounded here by ``SCHEDULING_SLACK_S``.
"""
from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import time
from pathlib import Path

import can
import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from valve_msgs.msg import DutyCommand, ValveState

from valve_driver_pkg.canbus import TcpLoopbackBus, TcpLoopbackHub
from valve_driver_pkg.devices.dbc_protocol import example_dbc_path, example_mapping_path
from valve_model_pkg.maps import load_map
from valve_model_pkg.model import load_parameters

pytestmark = [pytest.mark.node]

SCHEDULING_SLACK_S = 1.5
_OUTPUT = re.compile(r': output duty ([0-9.]+) at monotonic ([0-9.]+): (.*)$', re.M)
_DBC = example_dbc_path()


PROTOCOLS = {
    'canopen': dict(
        device=['valve_canopen_device', '--node-id', '5'],
        params=['canopen.node_id:=5', 'canopen.heartbeat_ms:=100'],
        label='canopen node 5', timeout_s=0.3, period_s=0.01, duty_step=0.001,
        has_current=True),
    'j1939': dict(
        device=['valve_j1939_device', '--valve-index', '2'],
        params=['j1939.valve_index:=2', 'j1939.source_address:=128',
                'j1939.command_period_ms:=100'],
        label='j1939 valve 2', timeout_s=0.3, period_s=0.1, duty_step=0.01,
        has_current=False),
    'dbc': dict(
        device=['valve_dbc_device'],
        params=[f'dbc.file:={_DBC}', f'dbc.mapping_file:={example_mapping_path()}'],
        label='dbc board', timeout_s=0.2, period_s=0.02, duty_step=0.0001,
        has_current=True),
}


class Proc:
    """A process with its output in a file."""

    def __init__(self, argv: list[str], log: Path) -> None:
        self.log_path = log
        self._log = open(log, 'w')
        env = dict(os.environ, PYTHONUNBUFFERED='1')
        self.proc = subprocess.Popen(argv, stdout=self._log, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL, env=env,
                                     start_new_session=True)

    @property
    def output(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors='replace')

    def outputs(self) -> list[tuple[float, float, str]]:
        """(duty, monotonic time, reason) of every output change the device printed."""
        return [(float(d), float(t), r) for d, t, r in _OUTPUT.findall(self.output)]

    def kill(self) -> float:
        t = time.monotonic()
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()
        return t

    def stop(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGINT)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.kill()
        self._log.close()


def poll(predicate, timeout_s: float, what: str, spin=None) -> None:
    """Wait (spinning ROS when given) until ``predicate()``; fail naming ``what``."""
    end = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > end:
            raise AssertionError(f'timed out after {timeout_s:g} s waiting for {what}')
        if spin is not None:
            spin()
        else:
            time.sleep(0.02)   # a poll step of the deadline loop


class Rig:
    """Hub, device, driver and the test's bus client for one protocol."""

    def __init__(self, name: str, folder: Path) -> None:
        self.name = name
        self.spec = PROTOCOLS[name]
        self.folder = folder
        self.hub = TcpLoopbackHub('127.0.0.1:0').start()
        self.channel = self.hub.channel
        self.currents_ma: list[int] = []
        self.bus = TcpLoopbackBus(self.channel)
        self.notifier = can.Notifier(self.bus, [self._on_frame], timeout=0.1)
        self.devices: list[Proc] = []
        self.device = self.start_device()
        self.driver = Proc(['valve_can_driver', '--ros-args', '-p', f'protocol:={name}',
                            '-p', 'interface:=tcp_loopback', '-p', f'channel:={self.channel}',
                            '-p', 'autostart:=true', '-p', 'command_timeout_s:=0.0']
                           + [a for p in self.spec['params'] for a in ('-p', p)],
                           folder / f'driver-{name}.log')

    def start_device(self) -> Proc:
        proc = Proc(self.spec['device'] + ['--interface', 'tcp_loopback', '--channel',
                                           self.channel, '--no-hub'],
                    self.folder / f'device-{self.name}-{len(self.devices)}.log')
        self.devices.append(proc)
        poll(lambda: 'ready' in proc.output or proc.proc.poll() is not None, 30.0,
             f'{self.name} device ready')
        assert proc.proc.poll() is None, proc.output
        self.device = proc
        return proc

    def _on_frame(self, msg: can.Message) -> None:
        data = bytes(msg.data)
        if self.name == 'canopen' and msg.arbitration_id == 0x185 and len(data) >= 2:
            self.currents_ma.append(int.from_bytes(data[:2], 'little', signed=True))
        if self.name == 'dbc' and msg.arbitration_id == 0x18FF2021 and data[0] == 0:
            self.currents_ma.append(int.from_bytes(data[1:3], 'big', signed=True))

    def close(self) -> None:
        self.driver.stop()
        for proc in self.devices:
            proc.stop()
        self.notifier.stop()
        self.bus.shutdown()
        self.hub.close()


class Client(Node):
    def __init__(self, label: str) -> None:
        super().__init__('can_protocol_test_client')
        self.prefix = f'valve_can_driver {label}: '
        self.states: list[ValveState] = []
        self.status: dict[str, object] = {}
        self.create_subscription(ValveState, 'valve/state', self.states.append, 1000)
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 100)
        self.pub = self.create_publisher(DutyCommand, 'valve/duty_command', 10)

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith(self.prefix):
                self.status[status.name[len(self.prefix):]] = status

    def level(self, name: str) -> int:
        status = self.status.get(name)
        if status is None:
            return -1
        return status.level[0] if isinstance(status.level, bytes) else int(status.level)

    def all_ok(self) -> bool:
        names = ('CAN bus', 'device', 'commands', 'faults')
        return all(self.level(n) == 0 for n in names)

    def command(self, duty: float) -> None:
        msg = DutyCommand()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.duty, msg.pwm_frequency = float(duty), 50.0
        self.pub.publish(msg)


@pytest.fixture(scope='module', params=list(PROTOCOLS))
def rig(request, tmp_path_factory):
    rig = Rig(request.param, tmp_path_factory.mktemp(request.param))
    yield rig
    rig.close()


@pytest.fixture
def client(rig, ros) -> Client:
    client = ros.add(Client(rig.spec['label']))
    ros.wait_for(lambda: client.all_ok() or rig.driver.proc.poll() is not None, 60.0,
                 f'{rig.name} driver up, every status OK')
    assert rig.driver.proc.poll() is None, rig.driver.output
    return client


def _drive(ros, client: Client, rig: Rig, duty: float, what: str) -> None:
    """Command ``duty`` until the device's output is that duty (within its resolution)."""
    step = rig.spec['duty_step']

    def arrived() -> bool:
        client.command(duty)
        outs = rig.device.outputs()
        return bool(outs) and abs(outs[-1][0] - duty) <= step

    ros.wait_for(arrived, 20.0, what)


def test_device_receives_the_duty_and_the_state_carries_its_current(ros, rig, client) -> None:
    for duty in (0.3, 0.75):
        _drive(ros, client, rig, duty, f'{rig.name}: duty {duty} at the device')
        n = len(client.states)
        ros.wait_for(lambda: len(client.states) > n + 5, 10.0, 'valve/state')
        state = client.states[-1]
        if rig.name == 'j1939':
            # the device's Estimated Flow (1 %/bit) is the duty in force
            ros.wait_for(lambda: abs(client.states[-1].duty - duty) <= 0.01, 5.0,
                         'Estimated Flow / 100 on valve/state')
            assert math.isnan(client.states[-1].coil_current)
            assert math.isnan(client.states[-1].coil_voltage)
        else:
            assert state.duty == pytest.approx(duty, abs=rig.spec['duty_step'])
            assert math.isnan(state.coil_voltage)
            ros.wait_for(lambda: client.states[-1].coil_current > 0.05, 5.0, 'coil current')
            seen = {round(c / 1000.0, 6) for c in rig.currents_ma}
            tail = client.states[-5:]
            assert all(round(s.coil_current, 6) in seen for s in tail), (
                [s.coil_current for s in tail], sorted(seen)[-5:])
        _check_position_fields(ros, client, rig, duty)
    _drive(ros, client, rig, 0.0, f'{rig.name}: duty 0 at the device')
    assert client.all_ok(), {k: v.message for k, v in client.status.items()}


def _check_position_fields(ros, client: Client, rig: Rig, duty: float) -> None:
    """A device without a position sensor: the duty map's steady state at the duty in
    force (read here from the map file), flagged not measured; the board: its own."""
    if rig.name == 'dbc':
        ros.wait_for(lambda: client.states[-1].spool_position > 0.0, 5.0, 'board position')
        state = client.states[-1]
        assert state.position_measured
        assert 0.0 < state.spool_position <= load_parameters().stroke_m * 1.001
        return
    duty_map = load_map()
    i = int(np.flatnonzero(np.isclose(duty_map.duty, duty))[0])
    expected_m = duty_map.curve(50.0, 400_000.0)[i] * load_parameters().stroke_m
    ros.wait_for(lambda: client.states[-1].spool_position == pytest.approx(expected_m,
                                                                           rel=1e-6),
                 5.0, f'derived position {expected_m:.4g} m')
    state = client.states[-1]
    assert not state.position_measured
    assert state.spool_position_avg == state.spool_position
    assert state.mass_flow > 0.0


def test_device_death_is_an_error_and_its_return_recovers(ros, rig, client) -> None:
    _drive(ros, client, rig, 0.5, 'duty 0.5 at the device')
    rig.device.kill()
    ros.wait_for(lambda: client.level('device') == 2, 10.0, 'device ERROR')
    assert rig.spec['label'] in client.status['device'].message
    n = len(client.states)
    ros.spin_for(0.5)
    assert len(client.states) == n, 'valve/state went on without the device'
    rig.start_device()

    def recovered() -> bool:
        client.command(0.5)
        outs = rig.device.outputs()
        return client.all_ok() and bool(outs) and abs(outs[-1][0] - 0.5) <= rig.spec[
            'duty_step']
    ros.wait_for(recovered, 30.0, 'device set up and commanded again, every status OK')
    n = len(client.states)
    ros.wait_for(lambda: len(client.states) > n, 5.0, 'valve/state again')


def test_sigkill_of_the_driver_de_energises_the_device(ros, rig, client) -> None:
    _drive(ros, client, rig, 0.6, 'duty 0.6 at the device')
    t_kill = rig.driver.kill()
    bound = rig.spec['timeout_s'] + rig.spec['period_s']

    def off() -> list:
        return [o for o in rig.device.outputs() if o[1] > t_kill and o[0] == 0.0]
    poll(lambda: off(), bound + SCHEDULING_SLACK_S + 5.0, 'the device switching off')
    duty, t_off, reason = off()[0]
    elapsed = t_off - t_kill
    record = {'protocol': rig.name, 'fail_safe_s': round(elapsed, 4), 'bound_s': bound,
              'reason': reason, 'loadavg': os.getloadavg()[0]}
    print('fail-safe', json.dumps(record))
    results = os.environ.get('VALVE_FAILSAFE_RESULTS')
    if results:
        with open(results, 'a') as f:
            f.write(json.dumps(record) + '\n')
    assert 'timeout' in reason, reason
    assert 0.0 <= elapsed <= bound + SCHEDULING_SLACK_S, record


def test_a_mapping_naming_what_is_not_there_is_refused(tmp_path) -> None:
    mapping = tmp_path / 'bad.yaml'
    mapping.write_text('duty: BoardCommand.NoSuchSignal\n')
    co = tmp_path / 'bad_co.yaml'
    co.write_text('duty: {object: 0x2100, subindex: 1, type: INTEGER16, scale: 0.001}\n'
                  'fail_safe: [{object: 0x2101, subindex: 1, type: UNSIGNED8, value: 0}]\n')
    for protocol, params, name in (
            ('dbc', [f'dbc.file:={_DBC}', f'dbc.mapping_file:={mapping}'], 'NoSuchSignal'),
            ('canopen', [f'canopen.mapping_file:={co}'], '0x2100')):
        proc = Proc(['valve_can_driver', '--ros-args', '-p', f'protocol:={protocol}', '-p',
                     'interface:=virtual', '-p', 'channel:=refused', '-p', 'autostart:=true']
                    + [a for p in params for a in ('-p', p)], tmp_path / f'{protocol}.log')
        try:
            assert proc.proc.wait(timeout=60) == 2, proc.output
        finally:
            proc.stop()
        assert name in proc.output, proc.output
