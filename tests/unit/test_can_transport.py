"""tcp_loopback (the cross-process bus for driver + emulator) and the bus factory."""
from __future__ import annotations

import time

import can
import pytest
from suite_waits import SCHEDULING_ALLOWANCE_S, wait_until

from valve_driver_pkg.canbus import TcpLoopbackBus, TcpLoopbackHub, open_bus, parse_channel
from valve_driver_pkg.errors import BusOpenError


@pytest.fixture
def hub():
    with TcpLoopbackHub('127.0.0.1:0') as h:
        yield h


@pytest.fixture
def no_open_virtual_channels():
    """Fails the test if it leaves a python-can virtual channel open."""
    yield
    from can.interfaces import virtual
    assert not virtual.channels, f'virtual channels left open: {list(virtual.channels)}'


def _wait_clients(h: TcpLoopbackHub, n: int) -> None:
    wait_until(lambda: h.client_count >= n, what=f'{n} clients registered with the hub')


@pytest.mark.parametrize('channel, expected', [
    ('29536', ('127.0.0.1', 29536)), ('127.0.0.1:1234', ('127.0.0.1', 1234)),
    ('tcp://localhost:80', ('127.0.0.1', 80)), ('[::1]:99', ('::1', 99)),
    (None, ('127.0.0.1', 29536)), (4321, ('127.0.0.1', 4321)),
])
def test_channel_parsing(channel, expected) -> None:
    assert parse_channel(channel) == expected


@pytest.mark.parametrize('channel', ['192.168.1.10:29536', '10.0.0.1:1', 'example.com:1',
                                     '0.0.0.0:29536', '127.0.0.1:notaport', '127.0.0.1:70000'])
def test_non_loopback_or_bad_channels_are_refused(channel) -> None:
    with pytest.raises(ValueError):
        parse_channel(channel)


def test_hub_forwards_to_every_other_client_not_the_sender(hub) -> None:
    a, b, c = (TcpLoopbackBus(hub.channel) for _ in range(3))
    try:
        _wait_clients(hub, 3)
        a.send(can.Message(arbitration_id=0x140, data=b'\x01\x02', is_extended_id=False))
        for bus in (b, c):
            msg = bus.recv(1.0)
            assert msg is not None
            assert (msg.arbitration_id, bytes(msg.data), msg.is_extended_id) == (
                0x140, b'\x01\x02', False)
        assert a.recv(0.1) is None
    finally:
        for bus in (a, b, c):
            bus.shutdown()


def test_frame_flags_survive_the_hub(hub) -> None:
    with TcpLoopbackBus(hub.channel) as a, TcpLoopbackBus(hub.channel) as b:
        _wait_clients(hub, 2)
        frames = [
            can.Message(arbitration_id=0x40, is_error_frame=True, data=bytes(8)),
            can.Message(arbitration_id=0x1ABCDEF0, data=b'x' * 8, is_extended_id=True),
            can.Message(arbitration_id=0x7FF, is_remote_frame=True, dlc=0,
                        is_extended_id=False),
            can.Message(arbitration_id=0x123, is_fd=True, bitrate_switch=True,
                        data=bytes(range(64)), is_extended_id=False),
        ]
        for frame in frames:
            a.send(frame)
        for frame in frames:
            got = b.recv(1.0)
            assert got is not None
            assert got.equals(frame, timestamp_delta=None, check_channel=False,
                              check_direction=False)


def test_many_frames_keep_their_order(hub) -> None:
    with TcpLoopbackBus(hub.channel) as a, TcpLoopbackBus(hub.channel) as b:
        _wait_clients(hub, 2)
        for i in range(2000):
            a.send(can.Message(arbitration_id=0x100, data=i.to_bytes(2, 'little'),
                               is_extended_id=False))
        received = [int.from_bytes(b.recv(1.0).data, 'little') for _ in range(2000)]
        assert received == list(range(2000))


def test_client_sees_the_hub_going_away() -> None:
    h = TcpLoopbackHub('127.0.0.1:0').start()
    bus = TcpLoopbackBus(h.channel)
    _wait_clients(h, 1)
    h.close()
    with pytest.raises(can.CanOperationError, match='closed|failed'):
        bus.recv(1.0)
    bus.shutdown()
    bus.shutdown()   # idempotent
    h.close()        # idempotent


def test_no_hub_is_an_initialisation_error_after_the_timeout() -> None:
    with TcpLoopbackHub('127.0.0.1:0') as h:
        port = h.port
    start = time.monotonic()
    with pytest.raises(can.CanInitializationError, match='no tcp_loopback hub'):
        TcpLoopbackBus(f'127.0.0.1:{port}', connect_timeout=0.2)
    # retried for the timeout given, not for the default (5 s), nor forever
    assert 0.2 <= time.monotonic() - start < 0.2 + SCHEDULING_ALLOWANCE_S


def test_send_after_shutdown_is_an_operation_error(hub) -> None:
    bus = TcpLoopbackBus(hub.channel)
    bus.shutdown()
    with pytest.raises(can.CanOperationError):
        bus.send(can.Message(arbitration_id=1, is_extended_id=False))


def test_factory_opens_tcp_loopback_and_virtual(hub, no_open_virtual_channels) -> None:
    with open_bus('tcp_loopback', hub.channel) as bus:
        assert isinstance(bus, TcpLoopbackBus)
    with open_bus('virtual', 'transport_test') as bus:
        assert bus.channel_info


def test_factory_wraps_failures_with_interface_and_channel() -> None:
    with pytest.raises(BusOpenError, match='no_such_interface:x'):
        open_bus('no_such_interface', 'x')
    with pytest.raises(BusOpenError, match='tcp_loopback:10.0.0.1:1'):
        open_bus('tcp_loopback', '10.0.0.1:1')
