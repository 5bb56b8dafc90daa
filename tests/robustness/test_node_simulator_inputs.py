"""valve_simulator survives any duty command and pressure message, and counts what it refuses.

Hypothesis draws DutyCommand and FluidPressure messages (NaN, +-inf, negative, huge, 0,
odd frame_ids, malformed stamps, any sequence); they are published in one burst to the real
node process, which must stay alive, keep publishing valve/state, and report in
/diagnostics at least as many rejections per input as the test counts by the rule of
docs/safety.md, "Node inputs" (written here independently of the node).
"""
from __future__ import annotations

import math

import pytest
from hypothesis import strategies as st

from node_harness import Diagnostics
from robustness.node_fuzz import (any_float, collect, frame_ids, sequences, set_header, stamps,
                                  wait_counts)

pytestmark = pytest.mark.node

ATMOSPHERE_PA = 101_325.0
MAX_ABSOLUTE_PA = 1.0e7 + ATMOSPHERE_PA       # 100 bar gauge
MIN_PWM_HZ, MAX_PWM_HZ = 0.1, 1000.0


def duty_invalid(duty: float, freq: float, nanosec: int) -> bool:
    """Rejected or clamped: not finite, frequency neither 0 nor in range, duty outside [0, 1]."""
    if not (math.isfinite(duty) and math.isfinite(freq)):
        return True
    if freq != 0.0 and not MIN_PWM_HZ <= freq <= MAX_PWM_HZ:
        return True
    return nanosec >= 10**9 or not 0.0 <= duty <= 1.0


def pressure_invalid(absolute_pa: float, nanosec: int) -> bool:
    return (not math.isfinite(absolute_pa) or not 0.0 <= absolute_pa <= MAX_ABSOLUTE_PA
            or nanosec >= 10**9)


duties = st.tuples(st.just('duty'), st.one_of(st.floats(0.0, 1.0), any_float),
                   st.one_of(st.sampled_from([0.0, 0.1, 50.0, 1000.0]), any_float),
                   frame_ids, stamps, sequences)
pressures = st.tuples(st.sampled_from(['supply', 'output']),
                      st.one_of(st.floats(0.0, 2.0e6), any_float), any_float, frame_ids,
                      stamps, sequences)


def test_any_input_is_survived_and_counted(start_node, ros):
    from sensor_msgs.msg import FluidPressure
    from valve_msgs.msg import DutyCommand

    from valve_model_pkg.nodes.common import (COMMAND_QOS, PRESSURE_QOS, TOPIC_DUTY_COMMAND,
                                              TOPIC_OUTPUT_PRESSURE, TOPIC_SUPPLY_PRESSURE)
    from valve_model_pkg.nodes.probe import StateProbe

    examples = collect(st.one_of(duties, pressures))
    sim = start_node('valve_simulator', '--ros-args', '-p', 'publish_rate_hz:=200.0',
                     '-p', 'diagnostics_period_s:=0.2')
    probe = ros.add(StateProbe('fuzz_probe'))
    diag = Diagnostics(probe, 'real-time model')
    pubs = {'supply': probe.create_publisher(FluidPressure, TOPIC_SUPPLY_PRESSURE, PRESSURE_QOS),
            'output': probe.create_publisher(FluidPressure, TOPIC_OUTPUT_PRESSURE, PRESSURE_QOS)}
    duty_pub = probe.create_publisher(DutyCommand, TOPIC_DUTY_COMMAND, COMMAND_QOS)
    ros.wait_for(lambda: probe.count > 10, 60.0, f'valve/state\n{sim.output[-2000:]}')
    ros.wait_matched([duty_pub, *pubs.values()], 'valve_simulator')
    wait_counts(ros, lambda: diag.count > 0, 'the simulator diagnostics')

    expected = {'duty_command': 0, 'supply_pressure': 0, 'output_pressure': 0}
    sent = 0
    for kind, a, b, frame_id, stamp, seq in examples:          # the burst
        if kind == 'duty':
            msg = set_header(DutyCommand(), frame_id, stamp)
            msg.duty, msg.pwm_frequency, msg.sequence = a, b, seq
            duty_pub.publish(msg)
            expected['duty_command'] += duty_invalid(a, b, stamp[1])
        else:
            msg = set_header(FluidPressure(), frame_id, stamp)
            msg.fluid_pressure, msg.variance = a, b
            pubs[kind].publish(msg)
            expected[f'{kind}_pressure'] += pressure_invalid(a, stamp[1])
        sent += 1
    assert sum(expected.values()) > 10, expected     # the draw exercised the rejections

    rule_kinds = ('not_finite', 'out_of_range', 'bad_stamp', 'frequency_out_of_range',
                  'duty_clamped')
    wait_counts(ros, lambda: all(diag.rejected(k, rule_kinds) >= n
                                 for k, n in expected.items()),
                f'rejections {expected} in the diagnostics (have {diag.values})')
    before = probe.count
    ros.spin_for(1.0)
    wait_counts(ros, lambda: probe.count > before + 20, 'valve/state after the burst')
    assert sim.alive(), sim.output[-3000:]
    for name, n in expected.items():
        # every rule violation counted once; the model may refuse more (near vacuum)
        assert diag.rejected(name, rule_kinds) == n, (name, diag.values)
        assert diag.rejected(name) >= n
    assert diag.int('rejected_commands') >= sum(expected.values())
    assert diag.int('duty_commands_received') == sum(1 for e in examples if e[0] == 'duty')
    last = probe.window().last
    assert last is not None and math.isfinite(last.supply_pressure)
    valid_supplies = {a - ATMOSPHERE_PA for kind, a, _, _, stamp, _ in examples
                      if kind == 'supply' and not pressure_invalid(a, stamp[1])}
    assert any(last.supply_pressure == pytest.approx(p) for p in valid_supplies | {4.0e5})
    out = sim.output
    assert 'not finite' in out                      # the first warning of a kind appears
    assert sim.stop() == 0
    print(f'{sent} messages, rejections expected {expected}, node counts '
          f'{ {k: v for k, v in diag.values.items() if k.startswith("rejected")} }')
