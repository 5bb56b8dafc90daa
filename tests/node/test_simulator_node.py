"""valve_simulator as its own process: rate, duty following, diagnostics, bad input."""
from __future__ import annotations

import math

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import FluidPressure
from suite_waits import TEST_READER_DEPTH

from valve_model_pkg.nodes.common import (COMMAND_QOS, TOPIC_DIAGNOSTICS,
                                          TOPIC_SUPPLY_PRESSURE, absolute_from_gauge)
from valve_model_pkg.nodes.probe import StateProbe

from node_harness import Diagnostics

pytestmark = pytest.mark.node

X_MAX_M = 0.33e-3  # Table 2 identified stroke
SIM_STATUS = 'valve_simulator: real-time model'


def _start_sim(start_node, rate_hz: float, *extra: str):
    return start_node('valve_simulator', '--ros-args', '-p', f'publish_rate_hz:={rate_hz}',
                      *extra)


def _wait_for_duty(ros, probe: StateProbe, duty: float, timeout_s: float = 30.0) -> None:
    """Until the state the probe last took carries ``duty`` (a loaded machine may delay
    the command and the test's reading of the stream alike)."""
    def in_force() -> bool:
        last = probe.window().last
        return last is not None and last.duty == pytest.approx(duty)
    ros.wait_for(in_force, timeout_s, f'the duty command {duty} in force')


@pytest.mark.parametrize('rate_hz', [1000.0, 200.0])
def test_state_arrives_at_the_configured_rate_and_follows_duty(start_node, ros, rate_hz):
    sim = _start_sim(start_node, rate_hz)
    probe = ros.add(StateProbe('test_probe', TEST_READER_DEPTH))
    diags: list[DiagnosticArray] = []
    probe.create_subscription(DiagnosticArray, TOPIC_DIAGNOSTICS, diags.append, 10)
    ros.wait_for(lambda: probe.count > 10, 30.0, 'the first valve/state messages')

    # The stream is the model's sample grid, one message per 1/rate of model time: every
    # stamp step is one period, or whole periods the node skipped and reported (a loaded
    # machine may hold the process up; the node then skips model time and says so).
    probe.reset_window()
    probe.keep_messages = True
    ros.spin_for(3.0)
    probe.keep_messages = False
    stamps = [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in probe.messages]
    periods = [(b - a) * rate_hz for a, b in zip(stamps, stamps[1:])]
    assert len(periods) > 10
    assert all(abs(p - round(p)) < 1e-3 and round(p) >= 1 for p in periods), periods
    skipped = sum(round(p) - 1 for p in periods)
    if skipped:
        ros.wait_for(lambda: any('fell behind' in s.message for a in diags for s in a.status),
                     10.0, f'diagnostics reporting the {skipped} skipped sample(s)')
    assert probe.window().position_avg_pct == pytest.approx(0.0, abs=1e-6)  # duty 0: closed

    # Follow a duty command: 60 % at 50 Hz opens the valve for part of each period.
    probe.command(0.6, 50.0)
    _wait_for_duty(ros, probe, 0.6)
    ros.spin_for(1.0)
    probe.reset_window()
    ros.spin_for(1.0)
    w = probe.window(x_max_m=X_MAX_M)
    assert w.last is not None
    assert w.last.duty == pytest.approx(0.6)
    assert w.last.pwm_frequency == pytest.approx(50.0)
    assert 10.0 < w.position_avg_pct < 95.0
    assert w.current_max_a > 0.3
    assert w.mass_flow_kg_s > 0.0

    probe.command(0.0, 50.0)
    _wait_for_duty(ros, probe, 0.0)
    ros.spin_for(1.0)
    probe.reset_window()
    ros.spin_for(0.5)
    assert probe.window(x_max_m=X_MAX_M).position_avg_pct == pytest.approx(0.0, abs=0.5)
    assert probe.gaps == 0
    assert sim.alive()
    assert sim.stop() == 0


def test_bad_commands_are_rejected_and_the_node_survives(start_node, ros):
    sim = _start_sim(start_node, 500.0)
    probe = ros.add(StateProbe('test_probe', TEST_READER_DEPTH))
    diag = Diagnostics(probe, SIM_STATUS)
    supply_pub = probe.create_publisher(FluidPressure, TOPIC_SUPPLY_PRESSURE, COMMAND_QOS)
    ros.wait_for(lambda: probe.count > 10, 30.0, 'valve/state')

    def rejected() -> int:
        return diag.int('rejected_commands', 0)

    probe.command(0.4, 50.0)
    _wait_for_duty(ros, probe, 0.4)
    for duty, freq in [(math.nan, 50.0), (0.5, math.inf), (0.5, -3.0), (0.5, 1e9)]:
        probe.command(duty, freq)
    supply_pub.publish(FluidPressure(fluid_pressure=math.nan))
    ros.wait_for(lambda: rejected() >= 5, 30.0,
                 f'diagnostics counting 5 rejected inputs ({rejected()})')
    probe.reset_window()
    ros.wait_for(lambda: probe.window().count > 20, 30.0, 'states after the rejections')
    last = probe.window().last
    assert last.duty == pytest.approx(0.4)  # last valid command still in force
    assert last.pwm_frequency == pytest.approx(50.0)

    probe.command(1.7, 50.0)  # out of range: clamped and reported
    supply_pub.publish(FluidPressure(fluid_pressure=absolute_from_gauge(2.0e5)))
    _wait_for_duty(ros, probe, 1.0)
    ros.wait_for(lambda: probe.window().last.supply_pressure == pytest.approx(2.0e5), 30.0,
                 'the new supply pressure in the state')
    ros.wait_for(lambda: rejected() >= 6, 30.0,
                 f'diagnostics counting the clamped command too ({rejected()})')
    assert sim.alive()
    out = sim.output
    assert 'not finite' in out and 'clamped' in out
    assert sim.stop() == 0


def test_a_bad_parameter_file_is_refused_at_start(start_node, tmp_path):
    bad = tmp_path / 'bad.yaml'
    bad.write_text('this: is not a valve\n')
    sim = start_node('valve_simulator', '--ros-args', '-p', f'params_file:={bad}')
    sim.proc.wait(timeout=60)
    assert sim.proc.returncode != 0
    assert 'cannot start' in sim.output
    assert str(bad) in sim.output or 'missing' in sim.output


def test_the_electronics_file_sets_the_drive_and_a_bad_one_is_refused(
        start_node, ros, tmp_path):
    bad = tmp_path / 'driver.yaml'
    bad.write_text('hold: pi\nrelease: varistor\n')
    sim = start_node('valve_simulator', '--ros-args', '-p', f'electronics_file:={bad}')
    sim.proc.wait(timeout=60)
    assert sim.proc.returncode == 2
    assert f'{bad}:2: release must be one of' in sim.output

    good = tmp_path / 'zener.yaml'
    good.write_text('electronics:\n  release: zener\n  zener_voltage_v: 36.0\n')
    sim = start_node('valve_simulator', '--ros-args', '-p', f'electronics_file:={good}',
                     '-p', 'capacitor:=true')
    probe = ros.add(StateProbe('test_probe', TEST_READER_DEPTH))
    ros.wait_for(lambda: probe.count > 10, 30.0, 'valve/state')
    assert f'electronics: {good}, current control True, release zener' in sim.output
    assert sim.stop() == 0


@pytest.mark.parametrize('env, sim_time, expected', [
    ({}, False, 'events'),                          # the default of the 1 kHz simulators
    ({'VALVE_EXECUTOR': 'single'}, False, 'single'),  # the fallback, asked for
    ({}, True, 'single'),                           # on simulated time: the Python executor
])
def test_executor_choice_and_the_stream_on_it(start_node, ros, env, sim_time, expected):
    """The node says which executor spins it, and publishes and follows commands on it."""
    extra = ('-p', 'use_sim_time:=true') if sim_time else ()
    sim = start_node('valve_simulator', '--ros-args', '-p', 'publish_rate_hz:=500.0', *extra,
                     env=env)
    ros.wait_for(lambda: f'executor: {expected}' in sim.output, 60.0,
                 f'the log line "executor: {expected}"')
    assert f'executor: {"single" if expected == "events" else "events"}' not in sim.output
    if sim_time:
        assert sim.stop() == 0   # no /clock here: nothing to publish, a clean stop
        return
    probe = ros.add(StateProbe('test_probe_executor'))
    ros.wait_for(lambda: probe.count > 10, 30.0, 'the first valve/state messages')
    probe.command(0.6, 50.0)
    _wait_for_duty(ros, probe, 0.6, timeout_s=10.0)
    probe.command(0.0, 50.0)
    _wait_for_duty(ros, probe, 0.0, timeout_s=10.0)
    assert sim.stop() == 0
