"""What every node of the suite shares: parameter declaration, diagnostics, the main.

The topic names, QoS profiles and constants are defined in :mod:`valve_model_pkg.interface`
(re-exported here for the nodes' convenience, not redefined).
"""
from __future__ import annotations

import math
import sys
from collections.abc import Callable

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType)
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from valve_model_pkg.interface import (ATMOSPHERIC_PRESSURE_PA, TOPIC_DIAGNOSTICS,
                                       TOPIC_DUTY_COMMAND, TOPIC_FLOW_COMMAND,
                                       TOPIC_FLOW_STATUS, TOPIC_OUTPUT_PRESSURE, TOPIC_STATE,
                                       TOPIC_SUPPLY_PRESSURE, absolute_from_gauge,
                                       gauge_from_absolute)
from valve_model_pkg.interface.ros import COMMAND_QOS, PRESSURE_QOS, STATE_QOS

__all__ = [
    'ATMOSPHERIC_PRESSURE_PA', 'TOPIC_STATE', 'TOPIC_DUTY_COMMAND', 'TOPIC_FLOW_COMMAND',
    'TOPIC_SUPPLY_PRESSURE', 'TOPIC_OUTPUT_PRESSURE', 'TOPIC_FLOW_STATUS', 'TOPIC_DIAGNOSTICS',
    'STATE_QOS', 'COMMAND_QOS', 'PRESSURE_QOS', 'declare_float', 'declare_int', 'declare_bool',
    'declare_string', 'gauge_from_absolute', 'absolute_from_gauge', 'key_values',
    'DiagnosticLevel', 'run_node',
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


def run_node(make_node: Callable[[], Node], name: str, args: list[str] | None = None,
             startup_errors: tuple[type[BaseException], ...] = (ValueError, OSError)) -> None:
    """Spin a node until Ctrl-C or an external shutdown (the Jazzy main of every node).

    An error of ``startup_errors`` raised while the node is built (a bad parameter, a bad
    parameter or map file) is logged as fatal with its reason and ends the process with
    exit code 1: a node never runs on defaults it was not asked for.
    """
    rclpy.init(args=args)
    node = None
    try:
        node = make_node()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except startup_errors as err:
        if node is not None:
            raise
        rclpy.logging.get_logger(name).fatal(f'cannot start: {err}')
        sys.exit(1)
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
