"""`make demo`, as the README tells a user to run it: it runs the suite through position steps,
records a bag that loses nothing, writes a report, exits, and leaves no process behind."""
from __future__ import annotations

import json

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from valve_bringup.demo import demo_goals

pytestmark = pytest.mark.e2e


def _setpoints_mm(goals) -> list[int]:  # noqa: ANN001 - a goal sequence
    return [round(g * 1e3) for g, _ in goals]


def _lockstep_lines(text: str) -> list[str]:
    """What every node logged of the lockstep (timeouts, start handshake), for a failure."""
    return [line for line in text.splitlines() if 'lockstep' in line or 'handshake' in line]


# One worker at a time: each `make demo` runs `make setup` (pip, colcon) in this tree.
@pytest.mark.xdist_group('make_demo')
@pytest.mark.parametrize('backend', ['sim', 'can'])
def test_make_demo_runs_records_reports_and_leaves_nothing(tmp_path, backend, make_demo):
    # Short holds keep the suite's CI budget; both backends run in lockstep as fast as the
    # computer allows (the same run, only sooner; with the CAN backend the emulator's valve
    # advances on the simulation clock).
    goals = demo_goals(hold_s=1.5)
    text = make_demo(f'BACKEND={backend}',
                     demo_args=f'--out {tmp_path} --hold 1.5 --as-fast-as-possible')
    (tmp_path / 'demo_output.txt').write_text(text)  # kept with the run: every node's log
    assert 'the suite is up' in text
    assert f'moving the piston to {max(_setpoints_mm(goals))} mm' in text
    assert 'stopped:' in text

    # The report, with its plots.
    report = tmp_path / 'report' / 'report.md'
    assert report.exists(), text[-3000:]
    assert (tmp_path / 'report' / 'overview.png').stat().st_size > 10_000
    assert '## Position steps' in report.read_text()
    summary = json.loads((tmp_path / 'report' / 'report.json').read_text())
    assert summary['backend'] == backend
    assert summary['real_time_factor'] > 0.0
    for step in summary['steps']:
        assert {'setpoint_mm', 'final_mm', 'overshoot_mm', 'settling_s', 'steady_error_mm',
                'settled'} <= set(step)
    # Lockstep: every step is there (no pre-roll row) whatever the computer's load.
    assert [round(s['setpoint_mm']) for s in summary['steps']] == _setpoints_mm(goals)
    assert summary['goals'] == [{'position_mm': g * 1e3, 'hold_s': h} for g, h in goals]
    assert summary['clock'] == 'simulation (lockstep)'
    assert summary['lockstep_timeouts'] == 0, (summary.get('last_lockstep_timeout'),
                                               _lockstep_lines(text))
    # valve/state at the configured rate (1 kHz of simulation time), through the driver
    # with the CAN backend
    assert summary['valve_state']['rate_hz'] == pytest.approx(1000.0, rel=0.01)
    assert summary['valve']['backend'] == ('CAN driver' if backend == 'can' else 'simulator')
    assert {t['topic'] for t in summary['topics']} >= {'/valve/state', '/cylinder/joint_states'}

    # The bag, opened with the rosbags reader: every valve state the backend published
    # between the first and the last recorded one is there (sequence continuity).
    bags = list(tmp_path.glob(f'bag_{backend}_*'))
    assert len(bags) == 1
    with AnyReader([bags[0]]) as reader:
        state_conns = [c for c in reader.connections if c.topic == '/valve/state']
        seq = np.array([reader.deserialize(raw, c.msgtype).sequence
                        for c, _, raw in reader.messages(connections=state_conns)])
        topics = {c.topic for c in reader.connections}
    assert seq.size > 5000
    assert seq.size == seq[-1] - seq[0] + 1, 'valve/state messages lost in the recording'
    assert np.all(np.diff(seq) == 1)
    assert {'/valve/duty_command', '/valve/flow_command', '/cylinder/joint_states',
            '/valve/output_pressure'} <= topics


@pytest.mark.xdist_group('make_demo')
def test_make_demo_double_cylinder_moves_both_valves(tmp_path, make_demo):
    """`make demo CYLINDER=double`: two valve namespaces, one flow_to_duty each, one
    controller commanding both; short (CI budget): the quick goals held 1 s each."""
    text = make_demo('CYLINDER=double',
                     demo_args=f'--out {tmp_path} --quick --hold 1 --as-fast-as-possible',
                     timeout_s=600.0)
    assert 'flow_to_duty_cap exit 0' in text and 'flow_to_duty_rod exit 0' in text
    summary = json.loads((tmp_path / 'report' / 'report.json').read_text())
    assert summary['cylinder'] == 'double'
    assert summary['lockstep_timeouts'] == 0, (summary.get('last_lockstep_timeout'),
                                               _lockstep_lines(text))
    assert [round(s['setpoint_mm']) for s in summary['steps']] == \
        _setpoints_mm(demo_goals(quick=True))
    for step in summary['steps']:
        assert step['settled'], step
        assert abs(step['steady_error_mm']) <= 0.5, step
    bags = list(tmp_path.glob('bag_sim_*'))
    with AnyReader(bags) as reader:
        topics = {c.topic for c in reader.connections}
    for ns in ('cap', 'rod'):
        assert {f'/{ns}/valve/state', f'/{ns}/valve/flow_command',
                f'/{ns}/valve/duty_command', f'/{ns}/valve/output_pressure'} <= topics
