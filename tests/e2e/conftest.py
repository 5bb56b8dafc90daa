"""Fixtures of the end-to-end tests: `make demo` as a user runs it, and what it leaves."""
from __future__ import annotations

import os
import subprocess
import uuid
from collections.abc import Callable
from pathlib import Path

import pytest

from suite_waits import wait_until
from suite_paths import REPO_ROOT

#: How long the demo's processes may take to end after `make demo` returned [s].
PROCESSES_END_S = 20.0


def processes_with(token: str) -> list[int]:
    """Pids of live processes whose environment carries ``token``."""
    pids = []
    for proc in Path('/proc').iterdir():
        if not proc.name.isdigit() or int(proc.name) == os.getpid():
            continue
        try:
            if token.encode() in (proc / 'environ').read_bytes():
                if (proc / 'stat').read_text().split()[2] != 'Z':
                    pids.append(int(proc.name))
        except (OSError, IndexError):
            continue
    return pids


@pytest.fixture(scope='session')
def make_demo() -> Callable[..., str]:
    """Run ``make demo VAR=... DEMO_ARGS=...`` from the repository root; return its output.

    Asserts what every run must give: exit 0, no traceback, and no process of the run
    alive afterwards (each run's processes carry a token in their environment).
    """
    def run(*make_vars: str, demo_args: str, timeout_s: float = 900.0) -> str:
        token = f'VALVE_DEMO_TEST_{uuid.uuid4().hex}'
        env = dict(os.environ, VALVE_TEST_TOKEN=token)
        env.pop('MAKEFLAGS', None)
        out = subprocess.run(['make', '-C', str(REPO_ROOT), 'demo', *make_vars,
                              f'DEMO_ARGS={demo_args}'],
                             env=env, capture_output=True, text=True, timeout=timeout_s)
        text = out.stdout + out.stderr
        assert out.returncode == 0, text[-4000:]
        assert 'Traceback' not in text, 'a process ended with a traceback: ' + text[-4000:]
        wait_until(lambda: not processes_with(token), PROCESSES_END_S,
                   'the demo\'s processes to end')
        return text
    return run
