"""What the tests that start real processes share: processes, rclpy, waits, diagnostics.

tests/conftest.py turns these into the fixtures ``start_node`` and ``ros``; tests import
the helpers from here (a module of its own: ``conftest`` names are ambiguous). rclpy is
imported only when a harness is built, so the ROS-free unit tests never load it.

Every wait polls a condition against a deadline and fails naming what it waited for; none
sleeps a fixed time.
"""
from __future__ import annotations

import os
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from suite_waits import SCHEDULING_ALLOWANCE_S, wait_until

#: At most this many waiting callbacks are handled in one spin of the test's executor.
_DRAIN_MAX = 10_000


def wait_for(predicate: Callable[[], bool], timeout_s: float, spin: Callable[[], None],
             what: str) -> None:
    """Call ``spin`` until ``predicate()`` holds; fail naming ``what`` after ``timeout_s``."""
    wait_until(predicate, timeout_s, what, step=spin)


def poll_until(predicate: Callable[[], bool], timeout_s: float, what: str) -> None:
    """Poll ``predicate`` (no ROS executor to serve) until it holds, at most ``timeout_s``."""
    wait_until(predicate, timeout_s, what)


class NodeProcess:
    """A node (or any command) started as its own process, its output captured to a file."""

    def __init__(self, argv: list[str], log_path: Path, env: dict[str, str],
                 name: str | None = None) -> None:
        self.argv = argv
        self.name = name or Path(argv[0]).name
        self.log_path = log_path
        self._log = open(log_path, 'w')
        self.proc = subprocess.Popen(argv, stdout=self._log, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL, env=env,
                                     start_new_session=True)

    @property
    def output(self) -> str:
        """Everything the process printed so far (also after :meth:`stop`)."""
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors='replace')

    def alive(self) -> bool:
        return self.proc.poll() is None

    def signal(self, sig: int) -> None:
        """Send ``sig`` to the process group, as a terminal's Ctrl-C does."""
        os.killpg(self.proc.pid, sig)

    def wait_ready(self, marker: str, timeout_s: float = SCHEDULING_ALLOWANCE_S) -> None:
        """Wait until ``marker`` is in the output; fail with the output if it ends first."""
        wait_until(lambda: marker in self.output or not self.alive(), timeout_s,
                   f'{self.name}: {marker!r}')
        assert self.alive(), self.output

    def wait_exit(self, timeout_s: float = SCHEDULING_ALLOWANCE_S) -> int:
        """Wait until the process has ended; its exit code."""
        wait_until(lambda: not self.alive(), timeout_s, f'{self.name} to end')
        return self.proc.returncode

    def kill(self) -> float:
        """SIGKILL the process group; the monotonic time of the kill."""
        t = time.monotonic()
        if self.proc.poll() is None:
            self.signal(signal.SIGKILL)
            self.proc.wait()
        return t

    def stop(self, timeout_s: float = 10.0) -> int:
        """SIGINT, then SIGKILL if it does not end; returns the exit code."""
        if self.proc.poll() is None:
            self.signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.signal(signal.SIGKILL)
                self.proc.wait()
        if not self._log.closed:
            self._log.close()
        return self.proc.returncode


class NodeStarter:
    """Starts processes on the test's ROS domain; :meth:`stop_all` ends them, newest first."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = log_dir
        self.started: list[NodeProcess] = []

    def __call__(self, *argv: str, env: dict[str, str] | None = None,
                 name: str | None = None) -> NodeProcess:
        """Start ``argv``; ``env`` adds to (or replaces values of) the test's environment."""
        full_env = dict(os.environ)
        full_env['PYTHONUNBUFFERED'] = '1'
        full_env.update(env or {})
        label = name or Path(argv[0]).name
        proc = NodeProcess(list(argv), self.log_dir / f'{label}-{len(self.started)}.log',
                           full_env, name=label)
        self.started.append(proc)
        return proc

    def stop_all(self) -> None:
        for proc in reversed(self.started):
            proc.stop()


class RosHarness:
    """rclpy in the test process: add nodes, spin them, wait for conditions."""

    def __init__(self) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        self._rclpy = rclpy
        rclpy.init()
        self.executor = SingleThreadedExecutor()
        self.nodes: list = []

    def add(self, node):  # noqa: ANN001, ANN201 - any rclpy Node
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def node(self, name: str):  # noqa: ANN201 - an rclpy Node
        """A plain rclpy node of the test, spun by this harness."""
        return self.add(self._rclpy.create_node(name))

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
        """Serve callbacks for ``seconds``: to let messages arrive, never as a wait."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.spin(min(0.05, max(0.0, end - time.monotonic())))

    def wait_for(self, predicate: Callable[[], bool], timeout_s: float, what: str) -> None:
        wait_for(predicate, timeout_s, self.spin, what)

    def wait_matched(self, publishers: list[Any], what: str, count: int = 1,
                     timeout_s: float = 60.0) -> None:
        """Until every publisher has ``count`` matched subscriptions (DDS-level)."""
        self.wait_for(lambda: all(p.get_subscription_count() >= count for p in publishers),
                      timeout_s, f'{what} to subscribe')

    def call(self, request: Callable[[], Any], what: str, timeout_s: float = 30.0,
             attempt_s: float = 5.0) -> Any:
        """Send ``request()`` (a service call's future) until one is answered; its result.

        A service may drop its answer to a client it has just discovered: the server's
        response writer waits only briefly for the client's response reader to match, and
        on a loaded machine the match can take longer (ROS 2 service discovery). A request
        that gets no answer within ``attempt_s`` is sent again; services that the tests
        call this way are idempotent.
        """
        end = time.monotonic() + timeout_s
        while True:
            future = request()
            attempt_end = min(end, time.monotonic() + attempt_s)
            while not future.done() and time.monotonic() < attempt_end:
                self.spin()
            if future.done():
                return future.result()
            future.cancel()
            if time.monotonic() >= end:
                raise AssertionError(f'timed out after {timeout_s:g} s waiting for {what}')

    def parameter_client(self, node_name: str, timeout_s: float = 30.0):  # noqa: ANN201
        """An ``AsyncParameterClient`` of ``node_name`` whose services are discovered."""
        from rclpy.parameter_client import AsyncParameterClient
        client = AsyncParameterClient(self.node(f'param_client_{len(self.nodes)}'), node_name)
        self.wait_for(client.services_are_ready, timeout_s,
                      f'the parameter services of {node_name}')
        return client

    def set_parameters(self, node_name: str, values: dict[str, Any],
                       timeout_s: float = 30.0) -> list:
        """Set parameters of a running node; its ``SetParametersResult`` per parameter."""
        from rclpy.parameter import Parameter
        client = self.parameter_client(node_name, timeout_s)
        result = self.call(
            lambda: client.set_parameters([Parameter(k, value=v) for k, v in values.items()]),
            f'{node_name} to answer {values}', timeout_s)
        return list(result.results)

    def wait_spinning(self, node_name: str, timeout_s: float = 60.0) -> None:
        """Until ``node_name`` answers a parameter request: its executor is spinning."""
        client = self.parameter_client(node_name, timeout_s)
        self.call(client.list_parameters, f'{node_name} to answer a parameter request',
                  timeout_s)

    def close(self) -> None:
        self.executor.shutdown()
        for node in self.nodes:
            node.destroy_node()
        self._rclpy.try_shutdown()


class Diagnostics:
    """The latest key/values of the /diagnostics status whose name contains ``name_part``."""

    def __init__(self, node: Any, name_part: str) -> None:
        from diagnostic_msgs.msg import DiagnosticArray

        from valve_model_pkg.interface import TOPIC_DIAGNOSTICS
        self.name_part = name_part
        self.values: dict[str, str] = {}
        self.count = 0
        node.create_subscription(DiagnosticArray, TOPIC_DIAGNOSTICS, self.on_message, 50)

    def on_message(self, msg: Any) -> None:
        for status in msg.status:
            if self.name_part in status.name:
                self.values = {kv.key: kv.value for kv in status.values}
                self.count += 1

    def int(self, key: str, absent: int = -1) -> int:
        """An integer value, ``absent`` while the key has not been reported."""
        return int(self.values.get(key, absent))

    def rejected(self, input_name: str, kinds: tuple[str, ...] | None = None) -> int:
        """Sum of ``rejected_<input>_<kind>`` (all kinds, or those in ``kinds``)."""
        prefix = f'rejected_{input_name}_'
        return sum(int(v) for k, v in self.values.items() if k.startswith(prefix)
                   and (kinds is None or k[len(prefix):] in kinds))


class DutyCommander:
    """Publishes numbered ``valve/duty_command`` messages from a node of the test."""

    def __init__(self, node: Any, topic: str | None = None) -> None:
        from valve_msgs.msg import DutyCommand

        from valve_model_pkg.interface import TOPIC_DUTY_COMMAND
        from valve_model_pkg.interface.ros import COMMAND_QOS
        self._type = DutyCommand
        self.node = node
        self.publisher = node.create_publisher(DutyCommand, topic or TOPIC_DUTY_COMMAND,
                                               COMMAND_QOS)
        self.sent: list[float] = []

    def matched(self) -> int:
        """Subscriptions this publisher is matched with (DDS-level)."""
        return self.publisher.get_subscription_count()

    def send(self, duty: float, pwm_frequency_hz: float = 50.0) -> None:
        msg = self._type(duty=float(duty), pwm_frequency=float(pwm_frequency_hz),
                         sequence=len(self.sent))
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.header.frame_id = self.node.get_fully_qualified_name()
        self.publisher.publish(msg)
        self.sent.append(float(duty))
