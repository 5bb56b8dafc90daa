"""flow_to_duty as its own process: answers, saturation, rejection, pressure tracking, refusal.

The expected duties are computed in the test process with the ROS-free inverter on the
same shipped map, so the node must reproduce them to rounding.
"""
from __future__ import annotations

import math
from pathlib import Path

import pytest
from rclpy.node import Node
from sensor_msgs.msg import FluidPressure
from valve_msgs.msg import DutyCommand, FlowCommand, FlowToDutyStatus

from valve_model_pkg.maps import (FlowStatus, FlowToDutyInverter, default_map_path,
                                  flow_per_opening, load_map)
from valve_model_pkg.model import default_parameters_path
from valve_model_pkg.nodes.common import (COMMAND_QOS, PRESSURE_QOS, TOPIC_DUTY_COMMAND,
                                          TOPIC_FLOW_COMMAND, TOPIC_FLOW_STATUS,
                                          TOPIC_OUTPUT_PRESSURE, TOPIC_SUPPLY_PRESSURE,
                                          absolute_from_gauge)

from node_harness import Diagnostics

pytestmark = pytest.mark.node


class Client(Node):
    """Commands flow and pressures; records duty commands and status messages."""

    def __init__(self) -> None:
        super().__init__('flow_to_duty_test_client')
        self.flow_pub = self.create_publisher(FlowCommand, TOPIC_FLOW_COMMAND, COMMAND_QOS)
        self.supply_pub = self.create_publisher(FluidPressure, TOPIC_SUPPLY_PRESSURE,
                                                PRESSURE_QOS)
        self.output_pub = self.create_publisher(FluidPressure, TOPIC_OUTPUT_PRESSURE,
                                                PRESSURE_QOS)
        self.duties: list[DutyCommand] = []
        self.statuses: list[FlowToDutyStatus] = []
        self.create_subscription(DutyCommand, TOPIC_DUTY_COMMAND, self.duties.append,
                                 COMMAND_QOS)
        self.create_subscription(FlowToDutyStatus, TOPIC_FLOW_STATUS, self.statuses.append,
                                 COMMAND_QOS)

    def flow(self, kg_s: float) -> None:
        msg = FlowCommand()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.mass_flow = float(kg_s)
        self.flow_pub.publish(msg)

    def pressures(self, supply_gauge_pa: float, output_gauge_pa: float = 0.0) -> None:
        self.supply_pub.publish(FluidPressure(fluid_pressure=absolute_from_gauge(
            supply_gauge_pa)))
        self.output_pub.publish(FluidPressure(fluid_pressure=absolute_from_gauge(
            output_gauge_pa)))


@pytest.fixture(scope='module')
def inverter() -> FlowToDutyInverter:
    return FlowToDutyInverter(load_map(), 50.0)


def _full_flow(inv: FlowToDutyInverter, supply_pa: float, output_pa: float = 0.0) -> float:
    k, _ = flow_per_opening(supply_pa, output_pa, inv.constants)
    return k * inv.constants.stroke_m


def _connect(ros, client: Client, node) -> None:
    """Wait until the node answers (discovery), re-sending a zero-flow command."""
    def answered() -> bool:
        if not client.statuses:
            client.flow(0.0)
            ros.spin(0.1)
        return bool(client.statuses)
    ros.wait_for(answered, 30.0, f'the first flow_to_duty status\n{node.output[-2000:]}')


def _answers(status: FlowToDutyStatus, kg_s: float) -> bool:
    """Whether ``status`` is about the flow ``kg_s`` (NaN included)."""
    asked = status.requested_mass_flow
    return asked == kg_s or (math.isnan(asked) and math.isnan(kg_s))


def _ask(ros, client: Client, kg_s: float) -> FlowToDutyStatus:
    """Send one flow command; its answer (statuses of earlier commands may still arrive)."""
    n = len(client.statuses)
    client.flow(kg_s)
    ros.wait_for(lambda: any(_answers(st, kg_s) for st in client.statuses[n:]), 10.0,
                 f'the answer to {kg_s!r} kg/s')
    return [st for st in client.statuses[n:] if _answers(st, kg_s)][-1]


def _set_pressures(ros, client: Client, supply_gauge_pa: float,
                   output_gauge_pa: float = 0.0) -> None:
    """Publish the pressures; wait until the node answers a zero-flow command with them.

    Pressures and flow commands are separate topics with no order between them: only an
    answer that carries the new pressures shows the node has taken them.
    """
    client.pressures(supply_gauge_pa, output_gauge_pa)

    def taken() -> bool:
        st = _ask(ros, client, 0.0)
        return (st.supply_pressure == pytest.approx(supply_gauge_pa)
                and st.output_pressure == pytest.approx(output_gauge_pa))
    ros.wait_for(taken, 30.0, f'the node to use {supply_gauge_pa:g} / {output_gauge_pa:g} Pa')


def test_status_codes_match_the_message() -> None:
    for status in FlowStatus:
        assert getattr(FlowToDutyStatus, f'STATUS_{status.name}') == int(status)


def test_answers_flow_commands_across_processes(start_node, ros, inverter) -> None:
    node = start_node('flow_to_duty', '--ros-args', '-p', 'pwm_frequency_hz:=50.0',
                      '-p', 'republish_period_s:=0.01')
    client = ros.add(Client())
    _connect(ros, client, node)
    _set_pressures(ros, client, 4e5, 0.0)
    full = _full_flow(inverter, 4e5)
    for r in (0.1, 0.35, 0.6, 0.9):
        q = r * full
        st = _ask(ros, client, q)
        expected = inverter.compute(q, 4e5, 0.0)
        assert st.status == FlowToDutyStatus.STATUS_OK, st.message
        assert st.duty == pytest.approx(expected.duty, abs=1e-9)
        assert client.duties[-1].duty == pytest.approx(expected.duty, abs=1e-9)
        assert client.duties[-1].pwm_frequency == 50.0
        assert st.supply_pressure == pytest.approx(4e5) and st.choked
        assert st.position_fraction == pytest.approx(r)
        assert st.requested_mass_flow == pytest.approx(q)
    # beyond reach and zero
    st = _ask(ros, client, 1.5 * full)
    assert st.status == FlowToDutyStatus.STATUS_SATURATED_HIGH and st.duty == 1.0
    assert client.duties[-1].duty == 1.0 and 'beyond reach' in st.message
    st = _ask(ros, client, 0.0)
    assert st.status == FlowToDutyStatus.STATUS_SATURATED_LOW and client.duties[-1].duty == 0.0
    # a tiny positive flow is never a duty inside the dead band
    feats = load_map().features(1, load_map().pressure_index(4e5))
    for q in (1e-9, 0.004 * full, 0.02 * full):
        st = _ask(ros, client, q)
        assert st.duty == 0.0 or st.duty >= feats.opening_duty - 1e-12, st
        assert st.status in (FlowToDutyStatus.STATUS_SATURATED_LOW,
                             FlowToDutyStatus.STATUS_DEAD_BAND_LIFTED,
                             FlowToDutyStatus.STATUS_OK)
    assert node.alive()
    assert node.stop() == 0


def test_bad_commands_are_rejected_and_the_last_valid_stays(start_node, ros,
                                                            inverter) -> None:
    node = start_node('flow_to_duty', '--ros-args', '-p', 'diagnostics_period_s:=0.2')
    client = ros.add(Client())
    diag = Diagnostics(client, 'flow to duty')
    _connect(ros, client, node)
    _set_pressures(ros, client, 4e5, 0.0)
    q_valid = 0.5 * _full_flow(inverter, 4e5)
    st = _ask(ros, client, q_valid)
    assert st.status == FlowToDutyStatus.STATUS_OK
    valid_duty = st.duty
    # its duty command is on a topic of its own: it may arrive after the status
    ros.wait_for(lambda: client.duties and client.duties[-1].duty == pytest.approx(valid_duty),
                 10.0, 'the duty command of the valid flow')
    last_sequence = client.duties[-1].sequence
    for bad in (math.nan, math.inf, -math.inf, -1e-4):
        st = _ask(ros, client, bad)
        assert st.status == FlowToDutyStatus.STATUS_REJECTED, st.message
        assert 'rejected' in st.message and st.duty == pytest.approx(valid_duty)
    # the valid command is still in force: a pressure change re-evaluates it
    client.pressures(6e5, 0.0)
    ros.wait_for(lambda: client.duties[-1].sequence > last_sequence
                 and client.statuses[-1].supply_pressure == pytest.approx(6e5), 10.0,
                 'a duty and status for the new pressure')
    # no duty command for a rejected flow: the node's next duty is the very next one
    assert client.duties[-1].sequence == last_sequence + 1
    expected = inverter.compute(q_valid, 6e5, 0.0)
    assert client.duties[-1].duty == pytest.approx(expected.duty, abs=1e-9)
    assert client.statuses[-1].requested_mass_flow == pytest.approx(q_valid)
    # bad pressure messages are ignored with a warning, the node survives
    client.supply_pub.publish(FluidPressure(fluid_pressure=math.nan))
    client.supply_pub.publish(FluidPressure(fluid_pressure=-5.0))
    ros.wait_for(lambda: diag.int('bad_pressure_messages') >= 2, 30.0,
                 f'the node to count two bad pressure messages ({diag.values})')
    st = _ask(ros, client, q_valid)
    assert st.supply_pressure == pytest.approx(6e5)
    assert node.alive()
    assert node.stop() == 0
    out = node.log_path.read_text(errors='replace')
    assert 'flow command rejected: mass_flow is NaN' in out
    assert 'supply pressure rejected' in out


def test_no_pressure_difference_gives_duty_zero(start_node, ros, inverter) -> None:
    node = start_node('flow_to_duty')
    client = ros.add(Client())
    _connect(ros, client, node)
    _set_pressures(ros, client, 2e5, 3e5)   # output above supply: no forward flow
    st = _ask(ros, client, 1e-3)
    assert st.status == FlowToDutyStatus.STATUS_NO_PRESSURE and st.duty == 0.0
    node.stop()


def _write_other_params(tmp_path: Path) -> Path:
    text = default_parameters_path().read_text().replace(
        'coil_resistance_ohm: 13.0', 'coil_resistance_ohm: 15.0')
    path = tmp_path / 'other_valve.yaml'
    path.write_text(text)
    return path


@pytest.mark.parametrize('case', ['missing', 'malformed', 'other_params', 'frequency'])
def test_bad_map_is_refused_at_start(start_node, tmp_path: Path, case: str) -> None:
    args = []
    if case == 'missing':
        path, reason = tmp_path / 'no_such_map.json', 'no such map file'
        args = ['-p', f'map_file:={path}']
    elif case == 'malformed':
        path, reason = tmp_path / 'broken.json', 'not valid JSON'
        path.write_text('{"format": "valve_suite/duty_map", ')
        args = ['-p', f'map_file:={path}']
    elif case == 'other_params':
        path, reason = default_map_path(), 'made for other valve parameters'
        args = ['-p', f'params_file:={_write_other_params(tmp_path)}']
    else:
        path, reason = default_map_path(), '75 Hz is not in the map'
        args = ['-p', 'pwm_frequency_hz:=75.0']
    node = start_node('flow_to_duty', '--ros-args', *args)
    code = node.proc.wait(timeout=60)
    out = node.output
    assert code != 0, out
    assert str(path) in out and reason in out, out
    assert 'cannot start' in out


#: Rounds (one flow command, two pressure messages) per burst: well below the queue depth
#: of the topics (1000), so no burst can overwrite what the node has not yet taken.
BURST_ROUNDS = 200


def test_processes_every_command_of_fast_flow_and_pressure_streams(start_node, ros,
                                                                   inverter) -> None:
    """The demo drives it with pressures at 1 kHz and flow commands at 100-1000 Hz.

    The client sends bursts of rounds (one flow command and two pressure messages each) as
    fast as it can; after each burst it waits until the node has counted every command
    of it (its own count in /diagnostics). The node must process every command and answer
    the last one correctly. How fast it does so is measured by the benchmarks, not here.
    """
    node = start_node('flow_to_duty', '--ros-args', '-p', 'diagnostics_period_s:=0.2')
    client = ros.add(Client())
    diag = Diagnostics(client, 'flow to duty')
    _connect(ros, client, node)
    full = _full_flow(inverter, 4e5)
    ros.wait_for(lambda: diag.int('commands') >= 0, 10.0, 'flow_to_duty diagnostics')
    before = diag.int('commands')
    sent = 0
    for _ in range(5):
        for _ in range(BURST_ROUNDS):
            client.pressures(4e5 + 1e5 * math.sin(sent / 50.0),
                             1e5 + 5e4 * math.cos(sent / 70.0))
            client.flow((0.3 + 0.2 * math.sin(sent / 30.0)) * full)
            sent += 1
        ros.wait_for(lambda: diag.int('commands') >= before + sent, 60.0,
                     f'the node to count all {sent} flow commands sent so far')
    # and it still answers correctly
    _set_pressures(ros, client, 4e5, 0.0)
    st = _ask(ros, client, 0.5 * full)
    expected = inverter.compute(0.5 * full, 4e5, 0.0).duty
    assert st.requested_mass_flow == pytest.approx(0.5 * full)
    assert st.duty == pytest.approx(expected, abs=1e-9)
    ros.wait_for(lambda: client.duties[-1].duty == pytest.approx(expected, abs=1e-9), 10.0,
                 'the duty command of the last answer')
    assert node.alive() and node.stop() == 0


def test_live_parameters(start_node, ros) -> None:
    """pwm_frequency_hz can switch to another map frequency; map_file cannot change live."""
    node = start_node('flow_to_duty')
    client = ros.add(Client())
    _connect(ros, client, node)

    def set_param(name: str, value: object):  # noqa: ANN202 - SetParametersResult
        (result,) = ros.set_parameters('flow_to_duty', {name: value})
        return result

    inv100 = FlowToDutyInverter(load_map(), 100.0)
    q = 0.5 * _full_flow(inv100, 4e5)
    client.pressures(4e5, 0.0)
    assert set_param('pwm_frequency_hz', 100.0).successful
    st = _ask(ros, client, q)
    assert st.pwm_frequency == 100.0 and client.duties[-1].pwm_frequency == 100.0
    assert st.duty == pytest.approx(inv100.compute(q, 4e5, 0.0).duty, abs=1e-9)
    bad = set_param('pwm_frequency_hz', 75.0)
    assert not bad.successful and '75 Hz is not in the map' in bad.reason
    refused = set_param('map_file', '/tmp/other.json')
    assert not refused.successful and 'restart' in refused.reason
    assert _ask(ros, client, q).pwm_frequency == 100.0
    assert node.alive() and node.stop() == 0
