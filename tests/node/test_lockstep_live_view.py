"""The live view: `valve_demo --live` (make demo LIVE=1) serves the suite's topics on a
Foxglove WebSocket on 127.0.0.1; the port answers a WebSocket handshake while the demo
runs."""
from __future__ import annotations

import base64
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from suite_waits import wait_until

pytest.importorskip('foxglove')

#: Pause between two handshake attempts while the demo starts [s].
HANDSHAKE_INTERVAL_S = 0.5


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(('127.0.0.1', 0))
        return sock.getsockname()[1]


def _handshake(port: int) -> str:
    """Send a WebSocket upgrade request (Foxglove's subprotocol); return the status line."""
    key = base64.b64encode(os.urandom(16)).decode()
    request = (f'GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n'
               f'Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n'
               'Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: foxglove.sdk.v1, '
               'foxglove.websocket.v1\r\n\r\n')
    with socket.create_connection(('127.0.0.1', port), timeout=2.0) as sock:
        sock.sendall(request.encode())
        return sock.recv(4096).decode(errors='replace').split('\r\n', 1)[0]


@pytest.mark.slow
def test_live_view_answers_a_websocket_handshake_while_the_demo_runs(tmp_path: Path) -> None:
    port = _free_port()
    log = open(tmp_path / 'demo.log', 'w')
    demo = subprocess.Popen([sys.executable, '-m', 'valve_bringup.demo', '--out',
                             str(tmp_path / 'run'), '--live', '--live-port', str(port),
                             '--quick', '--hold', '2.0'],
                            stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    status = {'line': ''}

    def answered_or_ended() -> bool:
        if demo.poll() is not None:
            return True    # the assertion below shows the demo's output
        try:
            status['line'] = _handshake(port)
        except OSError:    # not listening yet
            return False
        return ' 101 ' in status['line']
    try:
        wait_until(answered_or_ended, 120.0, 'the live view\'s WebSocket handshake',
                   step=lambda: time.sleep(HANDSHAKE_INTERVAL_S))
        assert ' 101 ' in status['line'], (status, (tmp_path / 'demo.log').read_text()[-3000:])
        assert demo.wait(timeout=300) == 0, (tmp_path / 'demo.log').read_text()[-3000:]
    finally:
        if demo.poll() is None:
            os.killpg(demo.pid, 2)
            demo.wait(timeout=30)
        log.close()
    # Nothing listens beyond loopback: the server bound 127.0.0.1.
    text = (tmp_path / 'demo.log').read_text()
    assert f'ws://127.0.0.1:{port}' in text
