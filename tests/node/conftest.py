"""Fixtures for node tests: real node processes, and an rclpy context in the test process."""
from __future__ import annotations

import os
import signal
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

rclpy = pytest.importorskip('rclpy')


def wait_for(predicate: Callable[[], bool], timeout_s: float, spin: Callable[[], None],
              what: str) -> None:
    """Spin until ``predicate()`` holds; fail naming ``what`` after ``timeout_s``."""
    end = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > end:
            raise AssertionError(f'timed out after {timeout_s:g} s waiting for {what}')
        spin()


class NodeProcess:
    """A node started as its own process, its output captured to a log file."""

    def __init__(self, argv: list[str], log_path: Path, env: dict[str, str]) -> None:
        self.argv = argv
        self.log_path = log_path
        self._log = open(log_path, 'w')
        self.proc = subprocess.Popen(argv, stdout=self._log, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL, env=env,
                                     start_new_session=True)

    @property
    def output(self) -> str:
        self._log.flush()
        return self.log_path.read_text(errors='replace')

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, timeout_s: float = 10.0) -> int:
        """SIGINT, then SIGKILL if it does not end; returns the exit code."""
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGINT)
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        self._log.close()
        return self.proc.returncode


@pytest.fixture
def start_node(tmp_path: Path) -> Iterator[Callable[..., NodeProcess]]:
    """Start node processes on the test's ROS domain; all are stopped after the test."""
    started: list[NodeProcess] = []

    def _start(*argv: str, env: dict[str, str] | None = None) -> NodeProcess:
        full_env = dict(os.environ)
        full_env['PYTHONUNBUFFERED'] = '1'
        full_env.update(env or {})
        name = Path(argv[0]).name
        proc = NodeProcess(list(argv), tmp_path / f'{name}-{len(started)}.log', full_env)
        started.append(proc)
        return proc

    yield _start
    for proc in reversed(started):
        proc.stop()


class RosHarness:
    """rclpy in the test process: add nodes, spin them, wait for conditions."""

    def __init__(self) -> None:
        from rclpy.executors import SingleThreadedExecutor
        rclpy.init()
        self.executor = SingleThreadedExecutor()
        self.nodes: list = []

    def add(self, node):  # noqa: ANN001, ANN201 - any rclpy Node
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def spin(self, timeout_s: float = 0.05) -> None:
        self.executor.spin_once(timeout_sec=timeout_s)

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.spin(min(0.05, max(0.0, end - time.monotonic())))

    def wait_for(self, predicate: Callable[[], bool], timeout_s: float, what: str) -> None:
        wait_for(predicate, timeout_s, self.spin, what)

    def close(self) -> None:
        self.executor.shutdown()
        for node in self.nodes:
            node.destroy_node()
        rclpy.try_shutdown()


@pytest.fixture
def ros() -> Iterator[RosHarness]:
    """rclpy initialised in the test process (on the test's own ROS_DOMAIN_ID)."""
    harness = RosHarness()
    yield harness
    harness.close()
