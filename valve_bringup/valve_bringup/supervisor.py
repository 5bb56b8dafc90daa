"""Run the suite's nodes as separate processes and stop every one of them cleanly.

This is what ``make demo`` uses where the ``launch`` package is not installed (the ROS 2
wheels do not ship it). Each child:

- runs in a session of its own, so a Ctrl-C in the terminal reaches the supervisor only and
  the supervisor shuts the children down in order (SIGINT, then SIGTERM, then SIGKILL);
- gets ``PR_SET_PDEATHSIG`` = SIGTERM on Linux, so even a supervisor killed with SIGKILL
  leaves no orphan behind;
- has its output prefixed with its name, so the terminal shows who says what.

ROS-free: it only starts programs.
"""
from __future__ import annotations

import ctypes
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import IO

__all__ = ['ProcessSpec', 'Supervisor', 'ChildExited']

_log = logging.getLogger(__name__)
_PR_SET_PDEATHSIG = 1


class ChildExited(RuntimeError):
    """A supervised process ended while the others were expected to keep running."""


@dataclass(frozen=True)
class ProcessSpec:
    """One program to supervise.

    Parameters
    ----------
    name
        Short name used to prefix the child's output.
    argv
        Program and arguments.
    env
        Extra environment variables (merged over the supervisor's environment).
    stop_last
        Stopped only after every other child has ended (e.g. the CAN emulator, which hosts
        the bus the driver is connected to: the driver then stops without a bus error).
    """

    name: str
    argv: Sequence[str]
    env: Mapping[str, str] = field(default_factory=dict)
    stop_last: bool = False


def _die_with_parent() -> None:  # runs in the child between fork and exec
    try:
        libc = ctypes.CDLL('libc.so.6', use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:  # not Linux: the supervisor's own clean-up still applies
        pass


class Supervisor:
    """Start, watch and stop a group of processes; a context manager that always stops.

    Parameters
    ----------
    out
        Where the children's prefixed output goes (default: stdout).
    stop_timeout_s
        How long each stage of the shutdown (SIGINT, SIGTERM) waits before the next [s].
    """

    def __init__(self, out: IO[str] | None = None, stop_timeout_s: float = 5.0) -> None:
        self._out = out or sys.stdout
        self._stop_timeout_s = stop_timeout_s
        self._children: list[tuple[ProcessSpec, subprocess.Popen[str]]] = []
        self._threads: list[threading.Thread] = []
        self._lock = threading.Lock()
        self._stopping = False

    def __enter__(self) -> Supervisor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def pids(self) -> dict[str, int]:
        """Name to process id of every started child."""
        return {spec.name: proc.pid for spec, proc in self._children}

    def start(self, spec: ProcessSpec) -> subprocess.Popen[str]:
        """Start one child; its output is forwarded line by line with its name in front."""
        env = dict(os.environ)
        env.update(spec.env)
        env.setdefault('PYTHONUNBUFFERED', '1')
        proc = subprocess.Popen(
            list(spec.argv), env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True, bufsize=1, start_new_session=True,
            preexec_fn=_die_with_parent if sys.platform.startswith('linux') else None)
        self._children.append((spec, proc))
        thread = threading.Thread(target=self._forward, args=(spec.name, proc), daemon=True)
        thread.start()
        self._threads.append(thread)
        self.say(f'started {spec.name} (pid {proc.pid}): {" ".join(spec.argv)}')
        return proc

    def say(self, text: str, name: str = 'demo') -> None:
        """Print one line with a name prefix, serialised with the children's output."""
        with self._lock:
            self._out.write(f'[{name:>18}] {text}\n')
            self._out.flush()

    def _forward(self, name: str, proc: subprocess.Popen[str]) -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            self.say(line.rstrip('\n'), name)

    def check_alive(self) -> None:
        """Raise :class:`ChildExited` if any child has ended."""
        for spec, proc in self._children:
            code = proc.poll()
            if code is not None and not self._stopping:
                raise ChildExited(f'{spec.name} (pid {proc.pid}) exited with code {code}')

    def table(self) -> str:
        """What is running: name, pid, state, command."""
        rows = []
        for spec, proc in self._children:
            code = proc.poll()
            state = 'running' if code is None else f'exited {code}'
            rows.append(f'  {spec.name:<28} pid {proc.pid:<8} {state:<10} {spec.argv[0]}')
        return '\n'.join(rows)

    def stop(self) -> dict[str, int | None]:
        """Stop every child (reverse start order): SIGINT, then SIGTERM, then SIGKILL.

        Idempotent. Returns each child's exit code.
        """
        self._stopping = True
        for last in (False, True):
            self._stop_wave(last)
        for thread in self._threads:
            thread.join(timeout=1.0)
        return {spec.name: proc.returncode for spec, proc in self._children}

    def _stop_wave(self, last: bool) -> None:
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            alive = [(s, p) for s, p in reversed(self._children)
                     if p.poll() is None and s.stop_last == last]
            if not alive:
                break
            for spec, proc in alive:
                try:
                    os.killpg(proc.pid, sig)  # the child's whole session (its own children)
                except ProcessLookupError:
                    pass
            deadline = time.monotonic() + self._stop_timeout_s
            for spec, proc in alive:
                try:
                    proc.wait(timeout=max(0.0, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    _log.warning('%s did not stop on %s', spec.name, signal.Signals(sig).name)
