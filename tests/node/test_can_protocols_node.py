"""valve_can_driver with protocol canopen, j1939 and dbc against the stand-in devices.

Each protocol gets a tcp_loopback hub, its stand-in device and the driver as processes
(the hub a process of its own: the bus outlives a killed device, and the test's own work
never delays its frames), shared by the tests of that protocol in the order below (the
last kills the driver). The test joins the hub as a bus client and decodes the device's
frames itself (CiA 401 TPDO1: analog input 1 in mA; the example board's status page 0:
coil current in mA, Motorola), so the current on ``valve/state`` is checked against the
bus, not against the driver's code. The device prints every change of its output with
CLOCK_MONOTONIC; the duty it received and the fail-safe time come from those lines.

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
import time

import numpy as np
import pytest
from can_protocol_rig import (
    DBC_FILE, PROTOCOLS, STATUSES, Client, Rig, drive_device, outputs, stamp_seconds,
)
from std_srvs.srv import Trigger
from suite_waits import SCHEDULING_ALLOWANCE_S, wait_until

from valve_driver_pkg.devices.dbc_protocol import example_mapping_path
from valve_model_pkg.maps import load_map
from valve_model_pkg.model import load_parameters
from valve_model_pkg.recording import load_bag

# lark (used by mcap-ros2-support to parse .msg) imports deprecated sre modules
pytestmark = [pytest.mark.node,
              pytest.mark.filterwarnings('ignore::DeprecationWarning:lark.utils')]

SCHEDULING_SLACK_S = 1.5


@pytest.fixture(scope='module', params=list(PROTOCOLS))
def rig(request, start_module_node, tmp_path_factory):
    rig = Rig(request.param, start_module_node, tmp_path_factory.mktemp(request.param))
    yield rig
    rig.close()


@pytest.fixture(scope='module')
def client(rig, ros_module) -> Client:
    client = ros_module.add(Client(rig.spec['label']))
    ros_module.wait_for(lambda: client.all_ok(STATUSES[:3]) or not rig.driver.alive(),
                        60.0, f'{rig.name} driver up, bus, device and commands OK')
    assert rig.driver.alive(), rig.driver.output
    return client


def test_device_receives_the_duty_and_the_state_carries_its_current(ros_module, rig,
                                                                    client) -> None:
    ros = ros_module
    for duty in (0.3, 0.75):
        drive_device(ros, client, rig, duty, f'{rig.name}: duty {duty} at the device')
        n = len(client.states)
        ros.wait_for(lambda: len(client.states) > n + 5, SCHEDULING_ALLOWANCE_S, 'valve/state')
        if rig.name == 'j1939':
            # the device's Estimated Flow (1 %/bit) is the duty in force
            ros.wait_for(lambda: abs(client.states[-1].duty - duty) <= 0.01,
                         SCHEDULING_ALLOWANCE_S, 'Estimated Flow / 100 on valve/state')
            assert math.isnan(client.states[-1].coil_current)
            assert math.isnan(client.states[-1].coil_voltage)
        else:
            ros.wait_for(lambda: client.states[-1].duty == pytest.approx(
                duty, abs=rig.spec['duty_step']), SCHEDULING_ALLOWANCE_S, 'the duty sent')
            assert math.isnan(client.states[-1].coil_voltage)
            ros.wait_for(lambda: client.states[-1].coil_current > 0.05,
                         SCHEDULING_ALLOWANCE_S, 'coil current')
            # each current on valve/state is one the device put on the bus (decoded here)
            tail = client.states[-5:]
            ros.wait_for(lambda: {round(s.coil_current, 6) for s in tail}
                         <= {round(c / 1000.0, 6) for c in rig.currents_ma},
                         SCHEDULING_ALLOWANCE_S, 'the currents in the device\'s frames')
        _check_position_fields(ros, client, rig, duty)
    drive_device(ros, client, rig, 0.0, f'{rig.name}: duty 0 at the device')
    ros.wait_for(lambda: client.all_ok(STATUSES[:3]), SCHEDULING_ALLOWANCE_S,
                 'bus, device, commands OK')


def _check_position_fields(ros, client: Client, rig: Rig, duty: float) -> None:
    """A device without a position sensor: the duty map's steady state at the duty in
    force (read here from the map file), flagged not measured; the board: its own."""
    if rig.name == 'dbc':
        ros.wait_for(lambda: client.states[-1].spool_position > 0.0, SCHEDULING_ALLOWANCE_S,
                     'board position')
        state = client.states[-1]
        assert state.position_measured
        assert 0.0 < state.spool_position <= load_parameters().stroke_m * 1.001
        return
    duty_map = load_map()
    i = int(np.flatnonzero(np.isclose(duty_map.duty, duty))[0])
    expected_m = duty_map.curve(50.0, 400_000.0)[i] * load_parameters().stroke_m
    ros.wait_for(lambda: client.states[-1].spool_position == pytest.approx(expected_m,
                                                                           rel=1e-6),
                 SCHEDULING_ALLOWANCE_S, f'derived position {expected_m:.4g} m')
    state = client.states[-1]
    assert not state.position_measured
    assert state.spool_position_avg == state.spool_position
    assert state.mass_flow > 0.0


def _call_clear_faults(ros, client: Client):
    ros.wait_for(client.clear.service_is_ready, SCHEDULING_ALLOWANCE_S, 'clear_faults')
    future = client.clear.call_async(Trigger.Request())
    ros.wait_for(future.done, 10.0 + SCHEDULING_ALLOWANCE_S, 'clear_faults answer')
    return future.result()


def test_clear_faults_as_the_protocol_allows(ros_module, rig, client) -> None:
    ros = ros_module
    drive_device(ros, client, rig, 0.5, 'duty 0.5 at the device')
    if rig.name == 'j1939':   # DM1 reports the stand-in's DTC (amber lamp: a warning)
        ros.wait_for(lambda: 'SPN 1907 FMI 5' in client.status['faults'].message
                     if 'faults' in client.status else False,
                     SCHEDULING_ALLOWANCE_S, 'DM1 with SPN 1907 in faults')
        assert client.level('faults') == 1
    response = _call_clear_faults(ros, client)
    if rig.name == 'dbc':
        assert not response.success
        assert 'has no request to clear' in response.message, response.message
        return
    assert response.success, response.message
    if rig.name == 'canopen':
        assert 'NMT reset communication' in response.message
        # the module booted (reset communication), was set up and started again: the
        # commanded duty is back at its output
        assert 'NMT reset communication' in rig.device.output
        ros.wait_for(lambda: outputs(rig.device)[-1][0] == pytest.approx(0.5, abs=0.001),
                     SCHEDULING_ALLOWANCE_S, 'the duty back at the output')
    else:
        assert 'SPN 1907' in response.message and 'still active: nothing' in response.message
        assert 'DM11 from address 128' in rig.device.output
    ros.wait_for(client.all_ok, SCHEDULING_ALLOWANCE_S, 'every status OK')


def _complete_lines(path) -> list[str]:
    text = path.read_text()
    return text[:text.rfind('\n') + 1].splitlines()


def test_the_bus_log_replays_into_the_states_the_driver_published(
        ros_module, rig, client, tmp_path) -> None:
    ros = ros_module
    mcap_reader = pytest.importorskip('mcap.reader')
    decoder_factory = pytest.importorskip('mcap_ros2.decoder').DecoderFactory
    from valve_driver_pkg.replay import main as replay_main
    drive_device(ros, client, rig, 0.4, 'duty 0.4 at the device')
    n = len(client.states)
    ros.wait_for(lambda: len(client.states) >= n + 25, SCHEDULING_ALLOWANCE_S, '25 states')
    window = client.states[n + 5:n + 25]
    end_s = window[-1].header.stamp.sec + window[-1].header.stamp.nanosec * 1e-9

    def logged_past_window() -> bool:
        lines = _complete_lines(rig.log_file) if rig.log_file.exists() else []
        return bool(lines) and float(lines[-1].split()[0].strip('()')) > end_s + 0.05
    wait_until(logged_past_window, 1.0 + SCHEDULING_ALLOWANCE_S, 'the log past the window')
    log = tmp_path / 'bus.log'
    log.write_text('\n'.join(_complete_lines(rig.log_file)) + '\n')
    bag = tmp_path / 'bag'
    args = {'canopen': ['--canopen-node-id', '5'], 'j1939': ['--j1939-valve-index', '2'],
            'dbc': ['--dbc-file', str(DBC_FILE), '--dbc-mapping-file',
                    str(example_mapping_path())]}[rig.name]
    replay_main([str(log), '--protocol', rig.name, '--out', str(bag), *args])

    states = load_bag(bag, topics=['/valve/state'])['/valve/state']
    fields = ('coil_current', 'duty', 'spool_position', 'position_measured')
    if rig.name != 'dbc':       # derived from the duty (a measured position's mean depends
        fields += ('mass_flow', 'spool_position_avg')   # on the receive times)
    replayed = [tuple(states[f][i] for f in fields) for i in range(len(states))]
    published = [tuple(getattr(s, f) for f in fields) for s in window]
    stamps = states.stamp_s
    # the window is a run of consecutive replayed states (one per device reading), the
    # first one at the frame the driver received just before it published
    starts = [k for k in range(len(replayed) - len(published) + 1)
              if _same(replayed[k:k + len(published)], published)]
    assert starts, (published[:3], replayed[-40:-37])
    first_s = window[0].header.stamp.sec + window[0].header.stamp.nanosec * 1e-9
    assert min(abs(stamps[k] - first_s) for k in starts) < 0.5

    # the MCAP project's own reader and decoder see the same states
    with open(bag / 'bag.mcap', 'rb') as fh:
        reader = mcap_reader.make_reader(fh, decoder_factories=[decoder_factory()])
        decoded = [m for _, channel, _, m in reader.iter_decoded_messages()
                   if channel.topic == '/valve/state']
    assert len(decoded) == len(replayed)
    assert _same([tuple(getattr(m, f) for f in fields) for m in decoded], replayed)


def _same(a: list[tuple], b: list[tuple]) -> bool:
    """Equal, NaN equal to NaN (fields a protocol does not carry)."""
    return len(a) == len(b) and all(
        x == y or (isinstance(x, float) and isinstance(y, float) and math.isnan(x)
                   and math.isnan(y)) for ra, rb in zip(a, b) for x, y in zip(ra, rb))


def test_device_death_is_an_error_and_its_return_recovers(ros_module, rig, client) -> None:
    ros = ros_module
    drive_device(ros, client, rig, 0.5, 'duty 0.5 at the device')
    # the loss the kill causes: a device starved on a loaded machine may have been lost
    # and back before, and that report may reach this process only now
    killed_s = time.time()
    rig.device.kill()
    try:
        ros.wait_for(lambda: client.device_error_after(killed_s) is not None,
                     SCHEDULING_ALLOWANCE_S, 'device ERROR')
        error_s = client.device_error_after(killed_s)
        assert rig.spec['label'] in client.status['device'].message
        # nothing published once the device is lost: evidence over 1 s (at least 10 of its
        # periods) on the driver's own clock; judged on the states' stamps, so a state
        # delivered late to this process is no false alarm
        ros.wait_for(lambda: float(client.value('device', 'age_s')) > 1.0,
                     SCHEDULING_ALLOWANCE_S, 'the driver without a device frame for 1 s')
        late = [s for s in client.states if stamp_seconds(s.header.stamp) > error_s]
        assert not late, f'{len(late)} states published after the device was lost'
    finally:
        rig.start_device()

    def recovered() -> bool:
        client.command(0.5)
        outs = outputs(rig.device)
        return client.all_ok() and bool(outs) and abs(outs[-1][0] - 0.5) <= rig.spec[
            'duty_step']
    ros.wait_for(recovered, 30.0, 'device set up and commanded again, every status OK')
    n = len(client.states)
    ros.wait_for(lambda: len(client.states) > n, SCHEDULING_ALLOWANCE_S, 'valve/state again')


def test_sigkill_of_the_driver_de_energises_the_device(ros_module, rig, client) -> None:
    drive_device(ros_module, client, rig, 0.6, 'duty 0.6 at the device')
    t_kill = rig.driver.kill()
    bound = rig.spec['timeout_s'] + rig.spec['period_s']

    def off() -> list:
        return [o for o in outputs(rig.device) if o[1] > t_kill and o[0] == 0.0]
    wait_until(off, bound + SCHEDULING_ALLOWANCE_S, 'the device switching off')
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


def test_a_mapping_naming_what_is_not_there_is_refused(start_node, tmp_path) -> None:
    mapping = tmp_path / 'bad.yaml'
    mapping.write_text('duty: BoardCommand.NoSuchSignal\n')
    co = tmp_path / 'bad_co.yaml'
    co.write_text('duty: {object: 0x2100, subindex: 1, type: INTEGER16, scale: 0.001}\n'
                  'fail_safe: [{object: 0x2101, subindex: 1, type: UNSIGNED8, value: 0}]\n')
    cases = (('dbc', [f'dbc.file:={DBC_FILE}', f'dbc.mapping_file:={mapping}'], 'NoSuchSignal'),
             ('canopen', [f'canopen.mapping_file:={co}'], '0x2100'),
             ('j1939', ['drive_mode:=bench'], 'drive_mode'))
    procs = [(start_node('valve_can_driver', '--ros-args', '-p', f'protocol:={protocol}',
                         '-p', 'interface:=virtual', '-p', 'channel:=refused', '-p',
                         'autostart:=true', *(a for p in params for a in ('-p', p))), name)
             for protocol, params, name in cases]
    for proc, name in procs:
        assert proc.wait_exit(60.0) == 2, proc.output
        assert name in proc.output and 'Traceback' not in proc.output, proc.output
