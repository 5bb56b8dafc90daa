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
