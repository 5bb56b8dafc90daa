"""Simulation time in lockstep: the same demo twice gives the same step metrics, because the
simulation waits for the controller at every control tick and the demo sends each goal
while the simulation is held. The second run spins the chain on the Python executor
(``VALVE_EXECUTOR=single``), the first on the EventsExecutor: the executor sets the pace,
not the run. Asserts the determinism (two short runs as fast as possible, the same
metrics to the last digit), not a timing."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from valve_bringup.demo import demo_goals


def _demo(out: Path, executor: str) -> dict:
    env = dict(os.environ)
    env.pop('VALVE_EXECUTOR', None)
    if executor == 'single':
        env['VALVE_EXECUTOR'] = 'single'
    proc = subprocess.run([sys.executable, '-m', 'valve_bringup.demo', '--out', str(out),
                           '--as-fast-as-possible', '--quick', '--hold', '1.5'],
                          env=env, capture_output=True, text=True, timeout=600)
    text = proc.stdout + proc.stderr
    assert proc.returncode == 0, text[-4000:]
    for node in ('valve_lockstep_sim', 'flow_to_duty', 'position_controller'):
        assert any(node in line and f'executor: {executor}' in line
                   for line in text.splitlines()), (node, executor, text[-4000:])
    return json.loads((out / 'report' / 'report.json').read_text())


@pytest.mark.slow   # two demo runs
def test_two_lockstep_runs_give_the_same_step_metrics(tmp_path: Path) -> None:
    first, second = _demo(tmp_path / 'a', 'events'), _demo(tmp_path / 'b', 'single')
    for run in (first, second):
        assert run['clock'] == 'simulation (lockstep)'
        assert run['lockstep_timeouts'] == 0, run.get('last_lockstep_timeout')
        assert run['real_time_factor'] > 0.0
        # every quick goal, no pre-roll row, each starting when the demo says it took effect
        assert [round(st['setpoint_mm']) for st in run['steps']] == \
            [round(g * 1e3) for g, _ in demo_goals(quick=True)]
        # the steps lie as far apart as the simulation times the demo held for the goals
        goal_s, start_s = run['goal_times_s'], [st['start_s'] for st in run['steps']]
        assert [b - a for a, b in zip(start_s, start_s[1:])] == \
            pytest.approx([b - a for a, b in zip(goal_s, goal_s[1:])], abs=2e-6)
    for a, b in zip(first['steps'], second['steps']):
        assert a['setpoint_mm'] == b['setpoint_mm']
        assert a['start_s'] == pytest.approx(b['start_s'], abs=0.010)
        for key in ('final_mm', 'overshoot_mm', 'steady_error_mm'):
            assert a[key] == b[key], (key, a, b)
        assert a['settled'] == b['settled']
        if a['settled']:
            assert a['settling_s'] == b['settling_s'], (a, b)
