"""What every node of the suite shares: parameter declaration, diagnostics, the main.

The topic names, QoS profiles and constants are defined in :mod:`valve_model_pkg.interface`
(re-exported here for the nodes' convenience, not redefined).
"""
from __future__ import annotations

import contextlib
import math
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from typing import Any, NoReturn

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType)
import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from valve_model_pkg.interface import (ATMOSPHERIC_PRESSURE_PA, TOPIC_DIAGNOSTICS,
                                       TOPIC_DUTY_COMMAND, TOPIC_FLOW_COMMAND,
                                       TOPIC_FLOW_STATUS, TOPIC_OUTPUT_PRESSURE, TOPIC_STATE,
                                       TOPIC_SUPPLY_PRESSURE, absolute_from_gauge,
                                       gauge_from_absolute)
from valve_model_pkg.interface.ros import COMMAND_QOS, PRESSURE_QOS, STATE_QOS
from valve_model_pkg.errors import StartupRefused

__all__ = [
    'ATMOSPHERIC_PRESSURE_PA', 'TOPIC_STATE', 'TOPIC_DUTY_COMMAND', 'TOPIC_FLOW_COMMAND',
    'TOPIC_SUPPLY_PRESSURE', 'TOPIC_OUTPUT_PRESSURE', 'TOPIC_FLOW_STATUS', 'TOPIC_DIAGNOSTICS',
    'STATE_QOS', 'COMMAND_QOS', 'PRESSURE_QOS', 'declare_float', 'declare_int', 'declare_bool',
    'declare_string', 'gauge_from_absolute', 'absolute_from_gauge', 'key_values',
    'DiagnosticLevel', 'run_node', 'help_requested', 'print_node_help', 'parameter_help',
    'recorded_declarations', 'refuse_start', 'init_with_signal_handling',
    'spin_until_stopped', 'STARTUP_ERRORS', 'StartupRefused', 'EXIT_OK',
    'EXIT_FAILURE', 'EXIT_REFUSED',
]


class DiagnosticLevel:
    """diagnostic_msgs/DiagnosticStatus levels as bytes (the message field is a byte)."""

    OK = DiagnosticStatus.OK
    WARN = DiagnosticStatus.WARN
    ERROR = DiagnosticStatus.ERROR
    STALE = DiagnosticStatus.STALE


def declare_float(node: Node, name: str, default: float, description: str,
                  low: float = -math.inf, high: float = math.inf) -> float:
    """Declare a double parameter with its description and range; return its value.

    The range shows in ``ros2 param describe`` and is enforced by rcl when set at run
    time. Infinite bounds are left open (rcl needs finite bounds, so only finite ones are
    attached to the descriptor).
    """
    descriptor = ParameterDescriptor(description=description, type=ParameterType.PARAMETER_DOUBLE)
    if math.isfinite(low) and math.isfinite(high):
        descriptor.floating_point_range = [FloatingPointRange(from_value=float(low),
                                                              to_value=float(high), step=0.0)]
    else:
        descriptor.additional_constraints = f'range [{low}, {high}]'
    value = float(node.declare_parameter(name, float(default), descriptor).value)
    if not (low <= value <= high) or math.isnan(value):
        raise ValueError(f'parameter {name!r} = {value!r} is outside [{low}, {high}]')
    return value


def declare_int(node: Node, name: str, default: int, description: str,
                low: int, high: int) -> int:
    """Declare an integer parameter with its description and range; return its value."""
    descriptor = ParameterDescriptor(description=description,
                                     type=ParameterType.PARAMETER_INTEGER,
                                     integer_range=[IntegerRange(from_value=int(low),
                                                                 to_value=int(high), step=1)])
    value = int(node.declare_parameter(name, int(default), descriptor).value)
    if not low <= value <= high:
        raise ValueError(f'parameter {name!r} = {value!r} is outside [{low}, {high}]')
    return value


def declare_bool(node: Node, name: str, default: bool, description: str) -> bool:
    """Declare a boolean parameter with its description; return its value."""
    descriptor = ParameterDescriptor(description=description, type=ParameterType.PARAMETER_BOOL)
    return bool(node.declare_parameter(name, bool(default), descriptor).value)


def declare_string(node: Node, name: str, default: str, description: str) -> str:
    """Declare a string parameter with its description; return its value."""
    descriptor = ParameterDescriptor(description=description,
                                     type=ParameterType.PARAMETER_STRING)
    return str(node.declare_parameter(name, str(default), descriptor).value)


def key_values(**values: object) -> list[KeyValue]:
    """Diagnostic key/value pairs from keyword arguments (values formatted as text)."""
    out = []
    for key, value in values.items():
        text = f'{value:.6g}' if isinstance(value, float) else str(value)
        out.append(KeyValue(key=key, value=text))
    return out


#: Exit codes of every node and command of the suite (README, "Commands: one rule").
EXIT_OK = 0        # normal end, also after Ctrl-C (SIGINT) or SIGTERM
EXIT_FAILURE = 1   # a failure inside
EXIT_REFUSED = 2   # refused start-up input: a bad parameter, a bad parameter or map file


#: What a node refuses at start-up with one fatal line and EXIT_REFUSED: a value outside
#: its range (ours: ValueError; rcl's own range check: ParameterException), a file that
#: cannot be read (OSError), or a node's own StartupRefused.
STARTUP_ERRORS: tuple[type[BaseException], ...] = (ValueError, OSError, ParameterException,
                                                   StartupRefused)

_PARAMETER_TYPES = {
    ParameterType.PARAMETER_BOOL: 'bool', ParameterType.PARAMETER_INTEGER: 'int',
    ParameterType.PARAMETER_DOUBLE: 'double', ParameterType.PARAMETER_STRING: 'string',
    ParameterType.PARAMETER_BYTE_ARRAY: 'byte[]', ParameterType.PARAMETER_BOOL_ARRAY: 'bool[]',
    ParameterType.PARAMETER_INTEGER_ARRAY: 'int[]',
    ParameterType.PARAMETER_DOUBLE_ARRAY: 'double[]',
    ParameterType.PARAMETER_STRING_ARRAY: 'string[]',
}


def help_requested(args: list[str] | None = None) -> bool:
    """Whether ``-h``/``--help`` is among the node's own (non-ROS) arguments.

    ``args`` is the full argument vector as ``rclpy.init`` takes it (program name first);
    ``None`` means ``sys.argv``.
    """
    argv = list(sys.argv if args is None else args)
    return any(a in ('-h', '--help') for a in remove_ros_args(argv)[1:])


@contextlib.contextmanager
def recorded_declarations() -> Iterator[list[tuple[str, Any, ParameterDescriptor | None]]]:
    """Record every ``declare_parameter`` call (name, default, descriptor) while active.

    The node's own declarations are the one source of its parameters' names, types,
    defaults, ranges and descriptions; ``--help`` prints them from here, so the help text
    cannot drift from what the node declares.
    """
    declared: list[tuple[str, Any, ParameterDescriptor | None]] = []
    original = Node.declare_parameter

    def record(self: Node, name: str, value: Any = None,
               descriptor: ParameterDescriptor | None = None,
               ignore_override: bool = False) -> Any:
        declared.append((name, value, descriptor))
        return original(self, name, value, descriptor, ignore_override)

    Node.declare_parameter = record  # type: ignore[method-assign]
    try:
        yield declared
    finally:
        Node.declare_parameter = original  # type: ignore[method-assign]


def _range_text(descriptor: ParameterDescriptor | None) -> str:
    if descriptor is None:
        return ''
    if descriptor.floating_point_range:
        r = descriptor.floating_point_range[0]
        return f'[{r.from_value:g}, {r.to_value:g}]'
    if descriptor.integer_range:
        r = descriptor.integer_range[0]
        return f'[{r.from_value}, {r.to_value}]'
    return descriptor.additional_constraints or ''


def parameter_help(declared: list[tuple[str, Any, ParameterDescriptor | None]]) -> str:
    """The parameters as ``--help`` prints them: name, type, default, range, description."""
    lines = ['parameters (set with --ros-args -p NAME:=VALUE):']
    for name, default, descriptor in declared:
        if descriptor is not None and descriptor.type != ParameterType.PARAMETER_NOT_SET:
            type_name = _PARAMETER_TYPES.get(descriptor.type, str(descriptor.type))
        else:
            type_name = type(default).__name__ if default is not None else 'any'
        range_text = _range_text(descriptor)
        lines.append(f'  {name}  ({type_name}, default {default!r}'
                     + (f', range {range_text}' if range_text else '') + ')')
        description = descriptor.description if descriptor is not None else ''
        if description:
            lines.append(f'      {description}')
    return '\n'.join(lines)


def print_node_help(make_node: Callable[[], Node], name: str, args: list[str] | None,
                    description: str | None = None, usage: str | None = None,
                    cleanup: Callable[[Node], None] | None = None) -> int:
    """``--help`` of a node: build it (never spun), print its parameters; return the code.

    The node is constructed with rclpy as it would be at start-up, but not spun, so no
    timer fires and a lifecycle node is never configured (the CAN driver opens no bus).
    No running ROS graph is needed. ``cleanup(node)`` runs before the node is destroyed.
    Returns :data:`EXIT_OK`, or :data:`EXIT_REFUSED` if the construction refused the given
    parameters (the parameters declared so far are shown).
    """
    argv = [a for a in (sys.argv if args is None else args) if a not in ('-h', '--help')]
    if description is None:
        module = sys.modules.get(getattr(make_node, '__module__', ''), None)
        description = (getattr(module, '__doc__', None) or name).strip().split('\n')[0]
    print(usage or f'usage: {name} [-h] [--ros-args -p NAME:=VALUE ...]')
    print(f'\n{description}\n')
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    # The node's start-up INFO lines would only interleave with the help text.
    rclpy.logging.set_logger_level(name, rclpy.logging.LoggingSeverity.WARN)
    node = None
    code = EXIT_OK
    try:
        with recorded_declarations() as declared:
            try:
                node = make_node()
            except STARTUP_ERRORS as err:
                print(f'(these parameters refused start-up: {err})')
                code = EXIT_REFUSED
        print(parameter_help(declared))
    finally:
        if node is not None:
            if cleanup is not None:
                cleanup(node)
            node.destroy_node()
        rclpy.try_shutdown()
    print(f'\nexit codes: {EXIT_OK} normal end (also on Ctrl-C/SIGINT and SIGTERM), '
          f'{EXIT_REFUSED} refused start-up input (one fatal line names it), '
          f'{EXIT_FAILURE} a failure inside')
    return code


def refuse_start(name: str, err: BaseException) -> NoReturn:
    """Log one fatal line naming what was refused and exit with :data:`EXIT_REFUSED`."""
    rclpy.logging.get_logger(name).fatal(f'cannot start: {err}')
    rclpy.try_shutdown()
    sys.exit(EXIT_REFUSED)


def _interrupt(signum: int, _frame: object) -> None:
    raise KeyboardInterrupt(signal.Signals(signum).name)


def init_with_signal_handling(args: list[str] | None) -> threading.Event:
    """``rclpy.init`` with the suite's own SIGINT/SIGTERM handling; returns the stop flag.

    rclpy's handlers shut the context down at once, under a running executor and a node
    still being built or destroyed: a callback or a lifecycle transition then fails with
    "context is invalid" and the process ends with a traceback and exit 1. Instead, until
    :func:`spin_until_stopped` starts, SIGINT and SIGTERM raise ``KeyboardInterrupt`` (so a
    long start-up, e.g. compiling the model's kernel, stops at once); while spinning they
    only set the returned flag, the spin loop ends, and the node is destroyed while the
    context is still valid (the CAN driver still commands duty 0).
    """
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, _interrupt)
    return stop


def make_executor(node: Node, events: bool = False):
    """The executor that spins ``node``, and its kind (``'events'`` or ``'single'``).

    ``events=True`` asks for rclpy's EventsExecutor (``rclpy.experimental``, C++): a
    1 kHz node pays about half the CPU per tick of the SingleThreadedExecutor, which
    rebuilds its wait set in Python every time (benchmarks/bench_bank.py measures both).
    It is used on the wall clock, and whatever ``events`` says for a node whose
    ``message_driven`` attribute is true: the lockstep chain's nodes, whose work runs in
    message callbacks (a round trip through every one of them per simulated millisecond)
    and whose timers on the simulated clock only publish diagnostics; a node that ticks on
    a simulated-clock timer keeps the Python executor. It is used only where the rclpy
    build has it; otherwise the SingleThreadedExecutor, as every other node.
    ``VALVE_EXECUTOR=single`` forces the latter (a fallback, should the experimental
    executor misbehave somewhere).
    """
    on_sim_time = bool(node.get_parameter('use_sim_time').value)
    wanted = (events and not on_sim_time) or bool(getattr(node, 'message_driven', False))
    if wanted and os.environ.get('VALVE_EXECUTOR', '') != 'single':
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:   # an rclpy without it: the Python executor
            pass
        else:
            return EventsExecutor(context=node.context), 'events'
    return SingleThreadedExecutor(context=node.context), 'single'


def spin_until_stopped(node: Node, stop: threading.Event, events: bool = False) -> None:
    """Spin ``node`` until SIGINT/SIGTERM set ``stop`` or the context is shut down.

    ``events``: see :func:`make_executor`.
    """
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    executor, kind = make_executor(node, events)
    if events or getattr(node, 'message_driven', False):
        node.get_logger().info(f'executor: {kind}')
    executor.add_node(node)
    try:
        # The signal handler runs when a wait returns: the timeout bounds the stop latency.
        while not stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    finally:
        executor.remove_node(node)
        executor.shutdown()


def run_node(make_node: Callable[[], Node], name: str, args: list[str] | None = None,
             startup_errors: tuple[type[BaseException], ...] = STARTUP_ERRORS,
             events_executor: bool = False) -> None:
    """Spin a node until Ctrl-C, SIGTERM or an external shutdown (the main of every node).

    ``-h``/``--help`` prints the node's parameters (:func:`print_node_help`) and exits 0.
    An error of ``startup_errors`` raised while the node is built (a bad parameter, a bad
    parameter or map file) is logged as one fatal line with its reason and ends the process
    with :data:`EXIT_REFUSED` (2): a node never runs on defaults it was not asked for. A
    failure while running propagates (exit 1). SIGINT and SIGTERM end it with exit 0 and no
    traceback (:func:`init_with_signal_handling`). ``events_executor``: spin with rclpy's
    EventsExecutor where :func:`make_executor` allows it (the 1 kHz simulators).
    """
    if help_requested(args):
        sys.exit(print_node_help(make_node, name, args))
    stop = init_with_signal_handling(args)
    node = None
    try:
        try:
            node = make_node()
        except startup_errors as err:
            refuse_start(name, err)
        # The ROS-free cores log through `logging`; their records go to this node's
        # logger and /rosout (docs/architecture.md).
        from valve_model_pkg.interface.ros import forward_logging
        forward_logging(node, 'valve_model_pkg', 'valve_driver_pkg')
        spin_until_stopped(node, stop, events_executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
