"""DDS stays on the machine: every socket of a running node is bound to loopback.

ros2_ws/env.bash points Fast DDS at ros2_ws/fastdds_localhost.xml (UDP on 127.0.0.1 and
shared memory, no multicast); ``VALVE_SUITE_MULTI_MACHINE=1`` opts out (docs/safety.md,
"Network"). These tests source env.bash as a user does, start real node processes with that
environment, and read the sockets each process holds from /proc: nothing may be bound to
0.0.0.0 or to an address of a network interface. A talker and a listener in two processes
must still find each other (discovery by unicast on 127.0.0.1, no multicast).
"""
from __future__ import annotations

import ipaddress
import os
import socket
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from node_harness import poll_until
from suite_paths import REPO_ROOT

pytest.importorskip('rclpy')

ENV_BASH = REPO_ROOT / 'ros2_ws' / 'env.bash'
PROFILE = REPO_ROOT / 'ros2_ws' / 'fastdds_localhost.xml'
FASTDDS_NS = '{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}'

#: Ends the process on SIGINT like a node does (Jazzy: ExternalShutdownException).
_SPIN = '''
try:
    rclpy.spin(node)
except (KeyboardInterrupt, ExternalShutdownException):
    pass
finally:
    node.destroy_node()
    rclpy.try_shutdown()
'''
TALKER = '''
import rclpy
from rclpy.executors import ExternalShutdownException
from std_msgs.msg import String
rclpy.init()
node = rclpy.create_node('network_probe_talker')
pub = node.create_publisher(String, 'network_probe/chatter', 10)
node.create_timer(0.1, lambda: pub.publish(String(data='hello')))
''' + _SPIN
#: Prints one line per kind of message on its first arrival: the talker's chatter and the
#: simulator's valve/state (best effort subscription: matches any publisher reliability).
LISTENER = '''
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.qos import qos_profile_sensor_data
from std_msgs.msg import String
from valve_msgs.msg import ValveState
rclpy.init()
node = rclpy.create_node('network_probe_listener')
seen = set()
def saw(what):
    if what not in seen:
        seen.add(what)
        print('received', what, flush=True)
node.create_subscription(String, 'network_probe/chatter', lambda m: saw('chatter'), 10)
node.create_subscription(ValveState, 'valve/state', lambda m: saw('state'),
                         qos_profile_sensor_data)
''' + _SPIN

#: /proc/<pid>/net tables that hold IP sockets (per network namespace; the process's own
#: sockets are picked out by inode).
_INET_TABLES = ('udp', 'udp6', 'tcp', 'tcp6', 'udplite', 'udplite6', 'raw', 'raw6')


def suite_env(**overrides: str | None) -> dict[str, str]:
    """The environment a shell has after ``source ros2_ws/env.bash``.

    ``overrides`` are set (or removed, with None) before sourcing. The caller's
    ROS_DOMAIN_ID (the test process's own, from tests/conftest.py) is kept by env.bash.
    """
    env = dict(os.environ)
    env.pop('VALVE_SUITE_MULTI_MACHINE', None)
    for key, value in overrides.items():
        if value is None:
            env.pop(key, None)
        else:
            env[key] = value
    out = subprocess.run(['bash', '-c', f'source "{ENV_BASH}" >&2 && env -0'], env=env,
                         capture_output=True, timeout=120)
    assert out.returncode == 0, out.stderr.decode(errors='replace')
    pairs = (item.split('=', 1) for item in out.stdout.decode().split('\0') if '=' in item)
    result = dict(pairs)
    result['PYTHONUNBUFFERED'] = '1'
    return result


def _decode_address(hex_address: str) -> str:
    """IP address of a /proc/net/{udp,tcp,...}[6] entry (hex words in host byte order)."""
    raw = bytes.fromhex(hex_address)
    if sys.byteorder == 'little':
        raw = b''.join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4))
    return socket.inet_ntop(socket.AF_INET if len(raw) == 4 else socket.AF_INET6, raw)


def inet_sockets(pid: int) -> list[tuple[str, str, int]]:
    """IP sockets the process holds: (table, bound local address, local port)."""
    inodes = set()
    fd_dir = Path(f'/proc/{pid}/fd')
    for fd in fd_dir.iterdir():
        try:
            target = os.readlink(fd)
        except OSError:  # closed meanwhile
            continue
        if target.startswith('socket:['):
            inodes.add(target[len('socket:['):-1])
    found = []
    for table in _INET_TABLES:
        path = Path(f'/proc/{pid}/net/{table}')
        if not path.exists():
            continue
        for line in path.read_text().splitlines()[1:]:
            fields = line.split()
            if fields[9] in inodes:
                address, port = fields[1].rsplit(':', 1)
                found.append((table, _decode_address(address), int(port, 16)))
    return found


def _is_loopback(address: str) -> bool:
    ip = ipaddress.ip_address(address)
    mapped = getattr(ip, 'ipv4_mapped', None)
    return (mapped or ip).is_loopback


def test_profile_confines_fast_dds_to_loopback_without_multicast() -> None:
    root = ET.parse(PROFILE).getroot()
    ns = FASTDDS_NS
    descriptors = {d.findtext(f'{ns}transport_id'): d
                   for d in root.iter(f'{ns}transport_descriptor')}
    udp = [d for d in descriptors.values() if d.findtext(f'{ns}type') == 'UDPv4']
    assert len(udp) == 1
    assert [a.text for a in udp[0].iter(f'{ns}address')] == ['127.0.0.1']
    assert {d.findtext(f'{ns}type') for d in descriptors.values()} == {'UDPv4', 'SHM'}

    (participant,) = root.iter(f'{ns}participant')
    assert participant.get('is_default_profile') == 'true'
    rtps = participant.find(f'{ns}rtps')
    assert rtps.findtext(f'{ns}useBuiltinTransports') == 'false'
    used = [t.text for t in rtps.iter(f'{ns}transport_id')]
    assert sorted(used) == sorted(descriptors)
    for name in ('metatrafficMulticastLocatorList', 'defaultMulticastLocatorList'):
        assert not list(root.iter(f'{ns}{name}')), name
    for name in ('metatrafficUnicastLocatorList', 'initialPeersList'):
        (locators,) = root.iter(f'{ns}{name}')
        assert [a.text for a in locators.iter(f'{ns}address')] == ['127.0.0.1'], name


def test_env_bash_sets_the_profile_and_the_switch_opts_out() -> None:
    local = suite_env()
    assert local['FASTRTPS_DEFAULT_PROFILES_FILE'] == str(PROFILE)
    assert local['FASTDDS_DEFAULT_PROFILES_FILE'] == str(PROFILE)
    assert local['SKIP_DEFAULT_XML_FILE'] == '1'
    # LOCALHOST would make rmw_fastrtps add an UDP transport bound beyond loopback.
    assert local['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SYSTEM_DEFAULT'
    # The tests themselves run with the same profile (tests/conftest.py).
    assert os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] == str(PROFILE)
    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SYSTEM_DEFAULT'

    # Opting in to multi-machine use, also from a shell that had sourced env.bash before.
    multi = suite_env(VALVE_SUITE_MULTI_MACHINE='1', FASTRTPS_DEFAULT_PROFILES_FILE=str(PROFILE),
                      FASTDDS_DEFAULT_PROFILES_FILE=str(PROFILE), SKIP_DEFAULT_XML_FILE='1')
    for key in ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE',
                'SKIP_DEFAULT_XML_FILE'):
        assert key not in multi, key
    assert multi['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SUBNET'


@pytest.mark.node
def test_running_nodes_bind_no_socket_beyond_loopback_and_still_talk(start_node):
    env = suite_env()
    python = env['VIRTUAL_ENV'] + '/bin/python'
    listener = start_node(python, '-c', LISTENER, env=env, name='listener')
    talker = start_node(python, '-c', TALKER, env=env, name='talker')
    simulator = start_node('valve_simulator', '--ros-args', '-p', 'publish_rate_hz:=200.0',
                           env=env)
    processes = (listener, talker, simulator)

    def heard_both() -> bool:
        dead = [p.name for p in processes if not p.alive()]
        assert not dead, f'{dead} ended early:\n' + '\n'.join(
            f'--- {p.name}\n{p.output[-2000:]}' for p in processes)
        return all(f'received {what}' in listener.output for what in ('chatter', 'state'))

    # Discovery by unicast on 127.0.0.1 only: the listener hears both other processes.
    poll_until(heard_both, 60.0, 'the listener to hear the talker and the simulator')

    for process in processes:
        sockets = inet_sockets(process.proc.pid)
        # DDS sockets must be there (else this check would pass vacuously).
        assert any(table == 'udp' for table, _, _ in sockets), (process.name, sockets)
        beyond = [s for s in sockets if not _is_loopback(s[1])]
        assert not beyond, f'{process.name} binds beyond loopback: {beyond} (all: {sockets})'
        # A wrong profile shows up as Fast DDS errors (e.g. "[XMLPARSER Error]").
        assert ' Error]' not in process.output, process.output[-2000:]
