"""valve_demo beside another suite on the same ROS domain: refused before it starts anything."""
from __future__ import annotations

import pytest

from valve_model_pkg.nodes.probe import StateProbe

pytestmark = pytest.mark.node


def test_a_second_demo_on_a_busy_domain_is_refused_in_one_line(start_node, ros, tmp_path):
    sim = start_node('valve_simulator', '--ros-args', '-p', 'publish_rate_hz:=200.0')
    probe = ros.add(StateProbe('test_probe'))
    ros.wait_for(lambda: probe.count > 0, 30.0, 'the simulator\'s valve/state')
    run_dir = tmp_path / 'second'
    # A long discovery allowance: the probe returns at its first find, so a loaded machine
    # only makes the refusal later, never missing.
    demo = start_node('valve_demo', '--out', str(run_dir), '--domain-check', '30')
    assert demo.wait_exit(60.0) == 2, demo.output
    lines = [ln for ln in demo.output.splitlines() if ln.strip()]
    assert len(lines) == 1, demo.output
    assert lines[0].startswith('valve_demo: error: ROS_DOMAIN_ID ')
    assert 'valve state of another suite (/valve/state)' in lines[0]
    assert 'own ROS_DOMAIN_ID' in lines[0]
    assert not run_dir.exists()   # nothing started, nothing written
    assert sim.alive()            # the running suite is left alone


def test_a_killed_suite_does_not_hold_the_domain(start_node, ros) -> None:
    # A SIGKILLed node stays in discovery until its lease ends; it sends nothing.
    from valve_bringup.watcher import suite_topics_in_use
    sim = start_node('valve_simulator', '--ros-args', '-p', 'publish_rate_hz:=200.0')
    probe = ros.add(StateProbe('test_probe'))
    ros.wait_for(lambda: probe.count > 0, 30.0, 'the simulator\'s valve/state')
    assert suite_topics_in_use(30.0) == ['/valve/state']
    sim.kill()
    assert suite_topics_in_use(1.5) == []
    assert suite_topics_in_use(0.0) == []
