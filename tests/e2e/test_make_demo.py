"""`make demo`, as the README tells a user to run it: it runs the suite through position steps,
records a bag that loses nothing, writes a report, exits, and leaves no process behind."""
from __future__ import annotations

import json
import os
import subprocess
import time
import uuid
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from suite_paths import REPO_ROOT

pytestmark = pytest.mark.e2e


def _processes_with(token: str) -> list[int]:
    """Pids of live processes whose environment carries ``token``."""
    pids = []
    for proc in Path('/proc').iterdir():
        if not proc.name.isdigit() or int(proc.name) == os.getpid():
            continue
        try:
            if token.encode() in (proc / 'environ').read_bytes():
                if (proc / 'stat').read_text().split()[2] != 'Z':
                    pids.append(int(proc.name))
        except (OSError, IndexError):
            continue
    return pids


# One worker at a time: each `make demo` runs `make setup` (pip, colcon) in this tree.
@pytest.mark.xdist_group('make_demo')
@pytest.mark.parametrize('backend', ['sim', 'can'])
def test_make_demo_runs_records_reports_and_leaves_nothing(tmp_path, backend):
    token = f'VALVE_DEMO_TEST_{uuid.uuid4().hex}'
    env = dict(os.environ, VALVE_TEST_TOKEN=token)
    env.pop('MAKEFLAGS', None)
    # Short holds keep the suite's CI budget; both backends run in lockstep as fast as the
    # computer allows (the same run, only sooner; with the CAN backend the emulator's valve
    # advances on the simulation clock).
    fast = ' --as-fast-as-possible'
    out = subprocess.run(['make', '-C', str(REPO_ROOT), 'demo', f'BACKEND={backend}',
                          f'DEMO_ARGS=--out {tmp_path} --hold 1.5{fast}'],
                         env=env, capture_output=True, text=True, timeout=900)
    text = out.stdout + out.stderr
    assert out.returncode == 0, text[-4000:]
    assert 'the suite is up' in text
    assert 'moving the piston to 80 mm' in text
    assert 'stopped:' in text
    assert 'Traceback' not in text, 'a process ended with a traceback: ' + text[-4000:]
    time.sleep(1.0)
    assert _processes_with(token) == [], 'the demo left processes running'

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
    assert [round(s['setpoint_mm']) for s in summary['steps']] == [20, 60, 40, 80, 30]
    assert summary['clock'] == 'simulation (lockstep)'
    assert summary['lockstep_timeouts'] == 0
    # valve/state at the configured rate (1 kHz of simulation time), through the driver
    # with the CAN backend
    assert summary['valve_state']['rate_hz'] == pytest.approx(1000.0, rel=0.01)

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
def test_make_demo_double_cylinder_moves_both_valves(tmp_path):
    """`make demo CYLINDER=double`: two valve namespaces, one flow_to_duty each, one
    controller commanding both; short (CI budget): three goals held 1 s each."""
    token = f'VALVE_DEMO_TEST_{uuid.uuid4().hex}'
    env = dict(os.environ, VALVE_TEST_TOKEN=token)
    env.pop('MAKEFLAGS', None)
    out = subprocess.run(['make', '-C', str(REPO_ROOT), 'demo', 'CYLINDER=double',
                          f'DEMO_ARGS=--out {tmp_path} --quick --hold 1 '
                          '--as-fast-as-possible'],
                         env=env, capture_output=True, text=True, timeout=600)
    text = out.stdout + out.stderr
    assert out.returncode == 0, text[-4000:]
    assert 'Traceback' not in text, text[-4000:]
    assert 'flow_to_duty_cap exit 0' in text and 'flow_to_duty_rod exit 0' in text
    time.sleep(1.0)
    assert _processes_with(token) == [], 'the demo left processes running'
    summary = json.loads((tmp_path / 'report' / 'report.json').read_text())
    assert summary['cylinder'] == 'double'
    assert summary['lockstep_timeouts'] == 0
    assert [round(s['setpoint_mm']) for s in summary['steps']] == [20, 60, 40]
    for step in summary['steps']:
        assert step['settled'], step
        assert abs(step['steady_error_mm']) <= 0.5, step
    bags = list(tmp_path.glob('bag_sim_*'))
    with AnyReader(bags) as reader:
        topics = {c.topic for c in reader.connections}
    for ns in ('cap', 'rod'):
        assert {f'/{ns}/valve/state', f'/{ns}/valve/flow_command',
                f'/{ns}/valve/duty_command', f'/{ns}/valve/output_pressure'} <= topics
