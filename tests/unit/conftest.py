"""Fixtures the unit tests share: each module builds its own (module scope), from one
definition here."""
from __future__ import annotations

import pytest


@pytest.fixture(scope='module')
def store():
    """The suite's rosbags typestore (ROS 2 Jazzy and the valve_msgs types)."""
    from valve_model_pkg.recording import build_typestore
    return build_typestore()


@pytest.fixture(scope='module')
def shipped():
    """The static duty map shipped with valve_model_pkg."""
    from valve_model_pkg.maps import load_map
    return load_map()
