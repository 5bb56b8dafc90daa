"""Message definitions for bags: valve_msgs from .msg files, hashes as rosidl computes them."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from suite_paths import REPO_ROOT
from valve_model_pkg.recording import (DEFAULT_TOPICS, SUITE_TOPICS, UnknownMessageTypeError,
                                       build_typestore, ensure_type, msgdef_and_hash,
                                       parse_topic_spec)

VALVE_TYPES = ['valve_msgs/msg/ValveState', 'valve_msgs/msg/DutyCommand',
               'valve_msgs/msg/FlowCommand', 'valve_msgs/msg/FlowToDutyStatus']
ROSIDL_JSON_DIR = REPO_ROOT / 'ros2_ws' / 'install' / 'valve_msgs' / 'share' / 'valve_msgs' / 'msg'


def test_the_suites_types_and_the_topics_types_are_known(store) -> None:
    for msgtype in VALVE_TYPES + sorted(set(SUITE_TOPICS.values())):
        assert msgtype in store.fielddefs, msgtype


def test_valve_msgs_are_read_from_the_source_tree_without_ros(monkeypatch) -> None:
    monkeypatch.setenv('AMENT_PREFIX_PATH', '')
    store = build_typestore()
    fields = [name for name, _ in store.fielddefs['valve_msgs/msg/ValveState'][1]]
    assert fields[:3] == ['header', 'sequence', 'coil_voltage']
    assert fields[-1] == 'position_measured'


@pytest.mark.parametrize('msgtype', VALVE_TYPES)
def test_type_hash_equals_the_one_rosidl_generated(store, msgtype: str) -> None:
    path = ROSIDL_JSON_DIR / f'{msgtype.rsplit("/", 1)[1]}.json'
    if not path.is_file():
        pytest.skip(f'{path} not built (make setup)')
    hashes = {h['type_name']: h['hash_string']
              for h in json.loads(path.read_text())['type_hashes']}
    _, type_hash = msgdef_and_hash(store, msgtype)
    assert type_hash == hashes[msgtype]


@pytest.mark.parametrize('msgtype', VALVE_TYPES + ['sensor_msgs/msg/JointState'])
def test_embedded_definition_parses_back_to_the_same_hash(store, msgtype: str) -> None:
    """What AnyReader does with the MCAP schema must give the hash in metadata.yaml."""
    msgdef, type_hash = msgdef_and_hash(store, msgtype)
    assert '=' * 80 + '\nMSG: std_msgs/Header' in msgdef
    fresh = get_typestore(Stores.EMPTY)
    fresh.register(get_types_from_msg(msgdef, msgtype))
    assert fresh.hash_rihs01(msgtype) == type_hash


def test_unknown_type_is_refused_naming_it(store) -> None:
    with pytest.raises(UnknownMessageTypeError, match='no_such_pkg/msg/Thing'):
        ensure_type(store, 'no_such_pkg/msg/Thing')


def test_other_packages_are_registered_with_their_dependencies(tmp_path) -> None:
    pkg = tmp_path / 'my_pkg' / 'msg'
    pkg.mkdir(parents=True)
    (pkg / 'Outer.msg').write_text('std_msgs/Header header\nmy_pkg/Inner[] inner\n')
    (pkg / 'Inner.msg').write_text('float64 x  # [m]\nstring name\n')
    store = build_typestore(['my_pkg/msg/Outer'], extra_dirs=[tmp_path])
    assert 'my_pkg/msg/Inner' in store.fielddefs
    _, type_hash = msgdef_and_hash(store, 'my_pkg/msg/Outer')
    assert type_hash.startswith('RIHS01_')
    (pkg / 'Broken.msg').write_text('my_pkg/Missing m\n')
    with pytest.raises(UnknownMessageTypeError, match='my_pkg/msg/Missing.*needed by'):
        ensure_type(store, 'my_pkg/msg/Broken', [tmp_path])


@pytest.mark.parametrize('spec, expected', [
    ('valve/state', ('valve/state', 'valve_msgs/msg/ValveState')),
    ('/valve/state', ('/valve/state', 'valve_msgs/msg/ValveState')),
    ('/diagnostics', ('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray')),
    ('diagnostics', ('diagnostics', 'diagnostic_msgs/msg/DiagnosticArray')),
    ('cylinder/joint_states', ('cylinder/joint_states', 'sensor_msgs/msg/JointState')),
    ('other/topic', ('other/topic', None)),
    ('a/b:std_msgs/msg/Float64', ('a/b', 'std_msgs/msg/Float64')),
    (' a/b : std_msgs/Float64 ', ('a/b', 'std_msgs/msg/Float64')),
])
def test_topic_specs(spec: str, expected: tuple) -> None:
    assert parse_topic_spec(spec) == expected


@pytest.mark.parametrize('spec', ['', ':std_msgs/msg/Float64', 'a:Float64', 'a:x/y/z/w',
                                  'a:pkg/srv/X'])
def test_bad_topic_specs_are_refused(spec: str) -> None:
    with pytest.raises(ValueError, match='topic entry'):
        parse_topic_spec(spec)


def test_default_topics_are_the_suites() -> None:
    assert set(DEFAULT_TOPICS) == set(SUITE_TOPICS)
    assert 'valve/state' in DEFAULT_TOPICS and 'cylinder/position_setpoint' in DEFAULT_TOPICS


def test_recording_package_loads_no_ros_module() -> None:
    code = (
        'import sys, importlib, pkgutil\n'
        f'sys.path.insert(0, {str(REPO_ROOT / "valve_model_pkg")!r})\n'
        'import valve_model_pkg.recording as r\n'
        'for info in pkgutil.walk_packages(r.__path__, "valve_model_pkg.recording."):\n'
        '    importlib.import_module(info.name)\n'
        'ros = ("rclpy", "rcl_interfaces", "std_msgs", "sensor_msgs", "diagnostic_msgs",\n'
        '       "valve_msgs", "builtin_interfaces")\n'
        'print(",".join(sorted(n for n in sys.modules if n.split(".")[0] in ros)))\n'
    )
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == '', f'ROS modules loaded by recording: {out.stdout}'
