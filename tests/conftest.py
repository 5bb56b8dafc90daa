"""Shared pytest set-up: every test process gets its own ROS domain, traffic stays local."""
from __future__ import annotations

import os
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]

# Each pytest process talks DDS on a domain of its own (derived from its pid) and only on
# this machine, so parallel runs and a user's running suite never see each other.
# The same Fast DDS profile as ros2_ws/env.bash (loopback only, no multicast; LOCALHOST
# would make rmw_fastrtps add a transport bound beyond loopback): docs/safety.md, "Network".
os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(REPO_ROOT / 'ros2_ws' / 'fastdds_localhost.xml')
os.environ['FASTDDS_DEFAULT_PROFILES_FILE'] = os.environ['FASTRTPS_DEFAULT_PROFILES_FILE']
os.environ['SKIP_DEFAULT_XML_FILE'] = '1'
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'SYSTEM_DEFAULT'
# Domains 0..101 keep the DDS ports below Linux's ephemeral range.
os.environ['ROS_DOMAIN_ID'] = str(1 + os.getpid() % 100)

# The ROS-free cores are importable straight from the source tree, even without the
# colcon overlay (it is a symlink install, so both are the same files).
for pkg in ('valve_model_pkg', 'valve_driver_pkg', 'valve_bringup'):
    path = str(REPO_ROOT / pkg)
    if path not in sys.path:
        sys.path.insert(0, path)


def pytest_collection_modifyitems(config, items):  # noqa: ANN001 - pytest hook
    """Node and end-to-end tests may run once more after a failure (pytest-rerunfailures).

    They start real processes on a shared 2-core machine; a few of them still judge rates
    and windows of wall time (a known limit, see the README's notes), so a loaded machine
    can fail a run that a second run passes. A real fault fails every run. Unit tests are
    not rerun.
    """
    import pytest
    for item in items:
        if item.get_closest_marker('node') or item.get_closest_marker('e2e'):
            item.add_marker(pytest.mark.flaky(reruns=1, reruns_delay=2))
