"""``tcp_loopback``: a CAN bus between processes of one machine, over a 127.0.0.1 TCP hub.

Why: python-can's ``virtual`` bus connects buses inside one process only; there is no vcan
here, and ``udp_multicast`` needs multicast. ``socketcand`` needs a daemon and a real
SocketCAN device behind it. This module is the smallest thing that works across
processes: a hub (:class:`TcpLoopbackHub`) accepts clients on a loopback port and
forwards every frame a client sends to every other client, like a CAN bus without
arbitration; :class:`TcpLoopbackBus` is a ``can.BusABC`` client of it.

Loopback only: the hub binds 127.0.0.1 (or ::1) and refuses any other address; the
client refuses to connect anywhere else.

Wire format (both directions, after a 5-byte hello ``b'VCAN1'`` from each side): one
record per frame, ``struct '<BdIBB'`` = magic 0xA5, timestamp [s] (float64), arbitration
id (uint32), flags (bit 0 extended id, 1 error frame, 2 remote, 3 FD, 4 BRS, 5 ESI),
data length (0..64), then the data bytes.

Channel syntax: ``'PORT'``, ``'HOST:PORT'`` or ``'tcp://HOST:PORT'`` with HOST a loopback
address (default 127.0.0.1).
"""
from __future__ import annotations

import collections
import ipaddress
import logging
import select
import selectors
import socket
import struct
import threading
import time

import can

__all__ = ['TcpLoopbackBus', 'TcpLoopbackHub', 'parse_channel', 'DEFAULT_PORT']

logger = logging.getLogger(__name__)

DEFAULT_PORT = 29536
_HELLO = b'VCAN1'
_HEADER = struct.Struct('<BdIBB')
_MAGIC = 0xA5
_MAX_DATA = 64
#: A client whose unsent data exceeds this is too slow for the bus and is dropped [bytes].
_MAX_BACKLOG = 4 * 1024 * 1024

_F_EXT, _F_ERR, _F_RTR, _F_FD, _F_BRS, _F_ESI = 1, 2, 4, 8, 16, 32


def parse_channel(channel: object) -> tuple[str, int]:
    """``(host, port)`` from a channel spec; raises ``ValueError`` if not loopback.

    Parameters
    ----------
    channel : str | int | None
        ``PORT``, ``HOST:PORT``, ``tcp://HOST:PORT`` or ``None`` (default port).
    """
    text = '' if channel is None else str(channel).strip()
    if text.startswith('tcp://'):
        text = text[len('tcp://'):]
    host, port_text = '127.0.0.1', text
    if ':' in text:
        host, _, port_text = text.rpartition(':')
        host = host.strip('[]') or '127.0.0.1'
    try:
        port = int(port_text) if port_text else DEFAULT_PORT
    except ValueError as err:
        raise ValueError(f'tcp_loopback channel {channel!r}: port {port_text!r} is not a '
                         'number') from err
    if not 0 <= port <= 65535:
        raise ValueError(f'tcp_loopback channel {channel!r}: port {port} outside 0..65535')
    if host == 'localhost':
        host = '127.0.0.1'
    try:
        loopback = ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = False
    if not loopback:
        raise ValueError(f'tcp_loopback channel {channel!r}: host {host!r} is not a loopback '
                         'address; this bus never leaves the machine')
    return host, port


def _encode(msg: can.Message) -> bytes:
    data = bytes(msg.data)[:_MAX_DATA]
    flags = ((_F_EXT if msg.is_extended_id else 0) | (_F_ERR if msg.is_error_frame else 0)
             | (_F_RTR if msg.is_remote_frame else 0) | (_F_FD if msg.is_fd else 0)
             | (_F_BRS if msg.bitrate_switch else 0)
             | (_F_ESI if msg.error_state_indicator else 0))
    timestamp = msg.timestamp or time.time()
    return _HEADER.pack(_MAGIC, timestamp, msg.arbitration_id & 0x1FFFFFFF, flags,
                        len(data)) + data


def _split_records(buffer: bytearray) -> list[bytes]:
    """Remove and return the complete records at the front of ``buffer``."""
    records = []
    offset = 0
    size = len(buffer)
    while size - offset >= _HEADER.size:
        magic = buffer[offset]
        length = buffer[offset + _HEADER.size - 1]
        if magic != _MAGIC or length > _MAX_DATA:
            raise ValueError(f'corrupt tcp_loopback stream (magic 0x{magic:02X}, '
                             f'length {length})')
        end = offset + _HEADER.size + length
        if end > size:
            break
        records.append(bytes(buffer[offset:end]))
        offset = end
    del buffer[:offset]
    return records


def _decode(record: bytes, channel: str) -> can.Message:
    _, timestamp, arbitration_id, flags, length = _HEADER.unpack_from(record)
    data = record[_HEADER.size:_HEADER.size + length]
    is_fd = bool(flags & _F_FD)
    return can.Message(timestamp=timestamp, arbitration_id=arbitration_id,
                       is_extended_id=bool(flags & _F_EXT),
                       is_error_frame=bool(flags & _F_ERR),
                       is_remote_frame=bool(flags & _F_RTR), is_fd=is_fd,
                       bitrate_switch=bool(flags & _F_BRS),
                       error_state_indicator=bool(flags & _F_ESI),
                       dlc=length, data=data, channel=channel, is_rx=True,
                       check=False)


class TcpLoopbackBus(can.BusABC):
    """python-can bus that is a client of a :class:`TcpLoopbackHub`.

    Parameters
    ----------
    channel : str | int
        Hub address, see :func:`parse_channel`.
    connect_timeout : float
        Keep retrying a refused connection this long [s] (the hub may still be starting).
    receive_own_messages : bool
        Also deliver the frames this bus sends (the hub never echoes them).

    Raises
    ------
    can.CanInitializationError
        No hub answered within ``connect_timeout`` or the hello did not match.
    ValueError
        The channel is not a loopback address.
    """

    def __init__(self, channel: object = None, connect_timeout: float = 5.0,
                 receive_own_messages: bool = False, **kwargs: object) -> None:
        self._host, self._port = parse_channel(channel)
        self.channel_info = f'tcp_loopback hub at {self._host}:{self._port}'
        self._receive_own = receive_own_messages
        self._sock = self._connect(float(connect_timeout))
        self._rx_buffer = bytearray()
        self._pending: collections.deque[can.Message] = collections.deque()
        self._send_lock = threading.Lock()
        self._closed = False
        kwargs.pop('bitrate', None)   # the hub has no bit timing
        super().__init__(channel=f'{self._host}:{self._port}', **kwargs)

    def _connect(self, timeout: float) -> socket.socket:
        deadline = time.monotonic() + timeout
        family = socket.AF_INET6 if ':' in self._host else socket.AF_INET
        while True:
            sock = socket.socket(family, socket.SOCK_STREAM)
            try:
                sock.settimeout(max(0.1, min(1.0, deadline - time.monotonic())))
                sock.connect((self._host, self._port))
                sock.sendall(_HELLO)
                hello = b''
                while len(hello) < len(_HELLO):
                    chunk = sock.recv(len(_HELLO) - len(hello))
                    if not chunk:
                        raise ConnectionError('hub closed the connection during the hello')
                    hello += chunk
                if hello != _HELLO:
                    sock.close()
                    raise can.CanInitializationError(
                        f'{self._host}:{self._port} is not a tcp_loopback hub '
                        f'(hello {hello!r})')
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                sock.settimeout(None)
                return sock
            except (ConnectionError, socket.timeout, OSError) as err:
                sock.close()
                if isinstance(err, can.CanInitializationError):
                    raise
                if time.monotonic() >= deadline:
                    raise can.CanInitializationError(
                        f'no tcp_loopback hub at {self._host}:{self._port}: {err}') from err
                time.sleep(0.05)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self._pending:
            return self._pending.popleft(), False
        if self._closed:
            raise can.CanOperationError('tcp_loopback bus is shut down')
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            remaining = None if deadline is None else max(0.0, deadline - time.monotonic())
            try:
                # select, not a socket timeout: the socket stays blocking for send().
                readable, _, _ = select.select([self._sock], [], [], remaining)
                if not readable:
                    return None, False
                chunk = self._sock.recv(65536)
            except (ValueError, OSError) as err:   # ValueError: socket closed meanwhile
                raise can.CanOperationError(f'tcp_loopback receive failed: {err}') from err
            if not chunk:
                raise can.CanOperationError(
                    f'tcp_loopback hub at {self._host}:{self._port} closed the connection')
            self._rx_buffer += chunk
            try:
                records = _split_records(self._rx_buffer)
            except ValueError as err:
                raise can.CanOperationError(str(err)) from err
            self._pending.extend(_decode(r, self.channel_info) for r in records)
            if self._pending:
                return self._pending.popleft(), False
            if deadline is not None and time.monotonic() >= deadline:
                return None, False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Send ``msg`` to every other client of the hub.

        Raises
        ------
        can.CanOperationError
            The hub is gone or the bus is shut down.
        """
        record = _encode(msg)
        with self._send_lock:
            if self._closed:
                raise can.CanOperationError('tcp_loopback bus is shut down')
            try:
                self._sock.sendall(record)
            except OSError as err:
                raise can.CanOperationError(f'tcp_loopback send failed: {err}') from err
        if self._receive_own:
            own = _decode(record, self.channel_info)
            own.is_rx = False
            self._pending.append(own)

    def shutdown(self) -> None:
        """Close the connection; safe to call more than once."""
        if self._closed:
            return
        self._closed = True
        try:
            self._sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self._sock.close()
        super().shutdown()

    @property
    def state(self) -> can.BusState:
        return can.BusState.ACTIVE


class TcpLoopbackHub:
    """The bus itself: forwards every frame from one client to all the others.

    Parameters
    ----------
    channel : str | int | None
        Address to listen on (loopback only); port 0 picks a free port, see ``port``.

    Use as a context manager or call :meth:`start` / :meth:`close`.
    """

    def __init__(self, channel: object = None) -> None:
        self._host, port = parse_channel(channel)
        family = socket.AF_INET6 if ':' in self._host else socket.AF_INET
        self._listener = socket.socket(family, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self._listener.bind((self._host, port))
        except OSError as err:
            self._listener.close()
            raise OSError(f'tcp_loopback hub cannot listen on {self._host}:{port}: '
                          f'{err}') from err
        self._listener.listen(16)
        self._listener.setblocking(False)
        self.port = self._listener.getsockname()[1]
        self._selector = selectors.DefaultSelector()
        self._clients: dict[socket.socket, dict] = {}
        self._wake_r, self._wake_w = socket.socketpair()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.frames_forwarded = 0

    @property
    def channel(self) -> str:
        """Channel string clients use to reach this hub."""
        return f'{self._host}:{self.port}'

    def start(self) -> TcpLoopbackHub:
        """Start serving in a daemon thread; returns self."""
        if self._thread is None:
            self._selector.register(self._listener, selectors.EVENT_READ, 'accept')
            self._selector.register(self._wake_r, selectors.EVENT_READ, 'wake')
            self._thread = threading.Thread(target=self._serve, name='tcp_loopback_hub',
                                            daemon=True)
            self._thread.start()
            logger.info('tcp_loopback hub listening on %s', self.channel)
        return self

    def __enter__(self) -> TcpLoopbackHub:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def client_count(self) -> int:
        return sum(1 for c in self._clients.values() if c['ready'])

    def close(self) -> None:
        """Stop serving and drop every client; safe to call more than once."""
        if self._stop.is_set():
            return
        self._stop.set()
        try:
            self._wake_w.send(b'x')
        except OSError:
            pass
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        for sock in list(self._clients):
            self._drop(sock, None)
        for sock in (self._listener, self._wake_r, self._wake_w):
            sock.close()
        self._selector.close()

    def _serve(self) -> None:
        while not self._stop.is_set():
            for key, events in self._selector.select(timeout=0.5):
                if key.data == 'accept':
                    self._accept()
                elif key.data == 'wake':
                    return
                else:
                    sock = key.fileobj
                    if events & selectors.EVENT_READ:
                        self._read(sock)
                    if events & selectors.EVENT_WRITE and sock in self._clients:
                        self._flush(sock)

    def _accept(self) -> None:
        try:
            sock, address = self._listener.accept()
        except OSError:
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._clients[sock] = {'ready': False, 'rx': bytearray(), 'tx': bytearray(),
                               'address': address}
        self._selector.register(sock, selectors.EVENT_READ, 'client')

    def _read(self, sock: socket.socket) -> None:
        client = self._clients.get(sock)
        if client is None:
            return
        try:
            chunk = sock.recv(65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as err:
            self._drop(sock, f'receive failed: {err}')
            return
        if not chunk:
            self._drop(sock, 'disconnected')
            return
        client['rx'] += chunk
        if not client['ready']:
            if len(client['rx']) < len(_HELLO):
                return
            if bytes(client['rx'][:len(_HELLO)]) != _HELLO:
                self._drop(sock, 'bad hello')
                return
            del client['rx'][:len(_HELLO)]
            client['ready'] = True
            self._queue(sock, _HELLO)
        try:
            records = _split_records(client['rx'])
        except ValueError as err:
            self._drop(sock, str(err))
            return
        if not records:
            return
        payload = b''.join(records)
        self.frames_forwarded += len(records)
        for other, state in list(self._clients.items()):
            if other is not sock and state['ready']:
                self._queue(other, payload)

    def _queue(self, sock: socket.socket, payload: bytes) -> None:
        client = self._clients[sock]
        was_empty = not client['tx']
        client['tx'] += payload
        if len(client['tx']) > _MAX_BACKLOG:
            self._drop(sock, 'too slow: backlog exceeded')
            return
        if was_empty:
            self._flush(sock)

    def _flush(self, sock: socket.socket) -> None:
        client = self._clients[sock]
        try:
            sent = sock.send(client['tx'])
        except (BlockingIOError, InterruptedError):
            sent = 0
        except OSError as err:
            self._drop(sock, f'send failed: {err}')
            return
        del client['tx'][:sent]
        events = selectors.EVENT_READ | (selectors.EVENT_WRITE if client['tx'] else 0)
        self._selector.modify(sock, events, 'client')

    def _drop(self, sock: socket.socket, reason: str | None) -> None:
        client = self._clients.pop(sock, None)
        if client is None:
            return
        if reason:
            logger.info('tcp_loopback hub: client %s dropped (%s)', client['address'], reason)
        try:
            self._selector.unregister(sock)
        except (KeyError, ValueError):
            pass
        sock.close()
