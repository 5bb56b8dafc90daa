"""Fixtures for node tests: real node processes, and an rclpy context in the test process."""
from __future__ import annotations

import os
import signal
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from suite_waits import SCHEDULING_ALLOWANCE_S, wait_until

rclpy = pytest.importorskip('rclpy')

#: At most this many waiting callbacks are handled in one spin of the test's executor.
_DRAIN_MAX = 10_000


class NodeProcess:
    """A node (or any program) started as its own process, its output captured to a file."""

    def __init__(self, argv: list[str], log_path: Path, env: dict[str, str]) -> None:
        self.argv = argv
        self.log_path = log_path
        self._log = open(log_path, 'w')
        self.proc = subprocess.Popen(argv, stdout=self._log, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL, env=env,
                                     start_new_session=True)

    @property
    def output(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors='replace')

    def alive(self) -> bool:
        return self.proc.poll() is None

    def wait_ready(self, marker: str, timeout_s: float = SCHEDULING_ALLOWANCE_S) -> None:
        """Wait until ``marker`` is in the output; fail with the output if it ends first."""
        wait_until(lambda: marker in self.output or not self.alive(), timeout_s,
                   f'{self.argv[0]}: {marker!r}')
        assert self.alive(), self.output

    def wait_exit(self, timeout_s: float = SCHEDULING_ALLOWANCE_S) -> int:
        """Wait until the process has ended; its exit code."""
        wait_until(lambda: not self.alive(), timeout_s, f'{self.argv[0]} to end')
        return self.proc.returncode

    def kill(self) -> float:
        """SIGKILL the process group; the monotonic time of the kill."""
        t = time.monotonic()
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()
        return t

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


class _Starter:
    """Starts node processes on the test's ROS domain and stops them all at the end."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.started: list[NodeProcess] = []

    def __call__(self, *argv: str, env: dict[str, str] | None = None) -> NodeProcess:
        full_env = dict(os.environ)
        full_env['PYTHONUNBUFFERED'] = '1'
        full_env.update(env or {})
        name = Path(argv[0]).name
        proc = NodeProcess(list(argv), self.folder / f'{name}-{len(self.started)}.log',
                           full_env)
        self.started.append(proc)
        return proc

    def stop_all(self) -> None:
        for proc in reversed(self.started):
            proc.stop()


@pytest.fixture
def start_node(tmp_path: Path) -> Iterator[Callable[..., NodeProcess]]:
    """Start node processes on the test's ROS domain; all are stopped after the test."""
    starter = _Starter(tmp_path)
    yield starter
    starter.stop_all()


@pytest.fixture(scope='module')
def start_module_node(tmp_path_factory) -> Iterator[Callable[..., NodeProcess]]:
    """Start node processes shared by a module's tests; all are stopped after the module."""
    starter = _Starter(tmp_path_factory.mktemp('nodes'))
    yield starter
    starter.stop_all()


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
        """Handle a callback (waiting up to ``timeout_s`` for one), then every callback
        already waiting, so the test's view never lags behind its subscriptions' queues."""
        from rclpy.executors import ShutdownException, TimeoutException
        self.executor.spin_once(timeout_sec=timeout_s)
        for _ in range(_DRAIN_MAX):
            try:
                handler, _, _ = self.executor.wait_for_ready_callbacks(timeout_sec=0.0)
            except (TimeoutException, ShutdownException):
                return
            handler()
            if handler.exception() is not None:
                raise handler.exception()

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.spin(min(0.05, max(0.0, end - time.monotonic())))

    def wait_for(self, predicate: Callable[[], bool], timeout_s: float, what: str) -> None:
        """Spin until ``predicate()`` holds; fail naming ``what`` after ``timeout_s``."""
        wait_until(predicate, timeout_s, what, step=self.spin)

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


@pytest.fixture(scope='module')
def ros_module() -> Iterator[RosHarness]:
    """rclpy for a module whose tests share their node processes (and their discovery)."""
    harness = RosHarness()
    yield harness
    harness.close()
