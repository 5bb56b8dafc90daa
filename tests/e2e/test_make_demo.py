"""`make demo`, as the README tells a user to run it: it runs, reports, exits, leaves nothing."""
from __future__ import annotations

import os
import subprocess
import time
import uuid
from pathlib import Path

import pytest

from suite_paths import REPO_ROOT

pytestmark = pytest.mark.e2e


def _processes_with(token: str) -> list[int]:
    """Pids of live processes whose environment carries ``token``."""
    pids = []
    for proc in Path('/proc').iterdir():
        if not proc.name.isdigit() or int(proc.name) == os.getpid():
            continue
        try:
            if token.encode() in (proc / 'environ').read_bytes():
                stat = (proc / 'stat').read_text().split()
                if stat[2] != 'Z':
                    pids.append(int(proc.name))
        except (OSError, IndexError):
            continue
    return pids


@pytest.mark.parametrize('backend', ['sim'])
def test_make_demo_runs_and_leaves_no_process_behind(tmp_path, backend):
    token = f'VALVE_DEMO_TEST_{uuid.uuid4().hex}'
    env = dict(os.environ, VALVE_TEST_TOKEN=token)
    env.pop('MAKEFLAGS', None)
    out = subprocess.run(['make', '-C', str(REPO_ROOT), 'demo', f'BACKEND={backend}',
                          f'DEMO_ARGS=--out {tmp_path}'],
                         env=env, capture_output=True, text=True, timeout=900)
    text = out.stdout + out.stderr
    assert out.returncode == 0, text[-4000:]
    assert 'valve/state is arriving' in text
    assert 'started valve_simulator' in text or 'started valve_can_driver' in text
    assert 'stopped:' in text
    time.sleep(1.0)
    assert _processes_with(token) == [], 'demo left processes running'
