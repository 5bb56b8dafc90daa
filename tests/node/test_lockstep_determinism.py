"""Simulation time in lockstep (issue 14, items 1-2): the same demo twice gives the same
step metrics, because the simulation waits for the controller at every control tick and
the demo sends each goal while the simulation is held. Asserts the determinism (two short
runs as fast as possible, same metrics), not a timing."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest


def _demo(out: Path) -> dict:
    env = dict(os.environ)
    proc = subprocess.run([sys.executable, '-m', 'valve_bringup.demo', '--out', str(out),
                           '--as-fast-as-possible', '--quick', '--hold', '1.5'],
                          env=env, capture_output=True, text=True, timeout=600)
    text = proc.stdout + proc.stderr
    assert proc.returncode == 0, text[-4000:]
    return json.loads((out / 'report' / 'report.json').read_text())


@pytest.mark.slow   # two demo runs: 40-70 s
# serial: the simulation is deterministic, but the run report places the controller's
# setpoint (std_msgs/Float64, no header) at the last joint state the recorder RECEIVED
# before it; with a CPU-bound test beside it the recorder's joint states lag and a step
# start moved by 22 ms (0.499 vs 0.477 s, CI 2026-11-24 on 2 xdist workers). Known
# limit of that placement (README), not of the lockstep.
@pytest.mark.serial
def test_two_lockstep_runs_give_the_same_step_metrics(tmp_path: Path) -> None:
    first, second = _demo(tmp_path / 'a'), _demo(tmp_path / 'b')
    for run in (first, second):
        assert run['clock'] == 'simulation (lockstep)'
        assert run['lockstep_timeouts'] == 0, run.get('last_lockstep_timeout')
        assert run['real_time_factor'] > 0.0
        assert len(run['steps']) == 3   # no pre-roll row
    for a, b in zip(first['steps'], second['steps']):
        assert a['setpoint_mm'] == b['setpoint_mm']
        assert a['start_s'] == pytest.approx(b['start_s'], abs=0.010)
        for key in ('final_mm', 'overshoot_mm', 'steady_error_mm'):
            assert a[key] == pytest.approx(b[key], abs=0.1), (key, a, b)
        assert a['settled'] == b['settled']
        if a['settled']:
            assert a['settling_s'] == pytest.approx(b['settling_s'], abs=0.010), (a, b)
