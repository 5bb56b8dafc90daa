"""The suite's ROS objects, built once from :mod:`valve_model_pkg.interface`.

QoS profiles, the conversion of a :class:`~valve_model_pkg.model.sample.ValveSample`
into ``valve_msgs/ValveState``, and the handler that forwards the ROS-free cores'
:mod:`logging` records to a node's logger (and so to ``/rosout``).
"""
from __future__ import annotations

import logging

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from valve_msgs.msg import ValveState

from valve_model_pkg.interface import (COMMAND_QUEUE_DEPTH, DIAGNOSTICS_QUEUE_DEPTH,
                                       JOINT_STATES_QUEUE_DEPTH, STATE_QUEUE_DEPTH)
from valve_model_pkg.model.sample import ValveSample

__all__ = ['STATE_QOS', 'STATE_DURABLE_QOS', 'COMMAND_QOS', 'PRESSURE_QOS', 'JOINT_STATES_QOS',
           'DIAGNOSTICS_QOS',
           'CLOCK_QOS', 'RELAY_QOS', 'PROBE_QOS',
           'state_message', 'state_reader_qos', 'RosLogHandler', 'forward_logging']

# State at 1 kHz: reliable so that a recorder loses nothing, a deep queue so a slow
# subscriber does not stall the publisher for a burst.
STATE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=STATE_QUEUE_DEPTH,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)


def state_reader_qos(depth: int) -> QoSProfile:
    """:data:`STATE_QOS` with a reader queue of ``depth`` states: a reader that must keep a
    longer backlog while it is held up (a test's probe on a loaded machine)."""
    return QoSProfile(history=STATE_QOS.history, depth=depth,
                      reliability=STATE_QOS.reliability, durability=STATE_QOS.durability)


#: valve/state of a backend stepped one state at a time (the CAN driver, in lockstep with
#: the emulator on /clock): the writer keeps its last states for a reader that matches it
#: late, and the simulation's external-valve reader asks for them, so a state published
#: before the writer's side of the match is not lost (the start handshake's one t = 0
#: state). Readers with STATE_QOS (volatile) match this writer and get no history.
STATE_DURABLE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=STATE_QUEUE_DEPTH,
                               reliability=ReliabilityPolicy.RELIABLE,
                               durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Commands: reliable; only the latest matters but a few are kept for a recorder.
COMMAND_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=COMMAND_QUEUE_DEPTH,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
PRESSURE_QOS = COMMAND_QOS
#: cylinder/joint_states (200 Hz) and /diagnostics: rclpy's default policies, own depths.
JOINT_STATES_QOS = QoSProfile(depth=JOINT_STATES_QUEUE_DEPTH)
DIAGNOSTICS_QOS = QoSProfile(depth=DIAGNOSTICS_QUEUE_DEPTH)
#: /clock: only the newest simulation time matters.
CLOCK_QOS = QoSProfile(depth=1)
#: The live view's relay subscriptions (any suite topic, rclpy's default policies).
RELAY_QOS = QoSProfile(depth=100)
# A probe that only asks whether anything publishes: best effort matches reliable and
# best-effort writers alike.
PROBE_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)


def state_message(sample: ValveSample, stamp, frame_id: str, sequence: int,
                  source: int) -> ValveState:
    """The ``valve_msgs/ValveState`` for one sample.

    Parameters
    ----------
    sample : ValveSample
        SI units, gauge pressures.
    stamp : builtin_interfaces.msg.Time
        Time the state refers to.
    frame_id : str
        The valve's name.
    sequence : int
        Per-publisher counter (+1 per message).
    source : int
        ``ValveState.SOURCE_SIMULATOR`` or ``ValveState.SOURCE_CAN``.
    """
    msg = ValveState()
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.sequence = int(sequence)
    msg.coil_voltage = float(sample.coil_voltage_v)
    msg.coil_current = float(sample.coil_current_a)
    msg.coil_current_mean = float(sample.coil_current_mean_a)
    msg.coil_voltage_mean = float(sample.coil_voltage_mean_v)
    msg.spool_position = float(sample.spool_position_m)
    msg.spool_velocity = float(sample.spool_velocity_m_s)
    msg.spool_position_avg = float(sample.position_avg_m)
    msg.mass_flow = float(sample.mass_flow_kg_s)
    msg.duty = float(sample.duty)
    msg.pwm_frequency = float(sample.pwm_frequency_hz)
    msg.supply_pressure = float(sample.supply_pressure_pa)
    msg.output_pressure = float(sample.output_pressure_pa)
    msg.source = int(source)
    msg.position_measured = bool(sample.position_measured)
    return msg


class RosLogHandler(logging.Handler):
    """Forward :mod:`logging` records of a ROS-free core to a node's logger.

    The cores log with ``logging.getLogger(__name__)`` (they must not import rclpy); without
    this handler those records never reach the console of a launched node nor ``/rosout``.
    """

    def __init__(self, node: Node, level: int = logging.INFO) -> None:
        super().__init__(level)
        self._logger = node.get_logger()

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = f'[{record.name}] {record.getMessage()}'
            if record.levelno >= logging.CRITICAL:
                self._logger.fatal(text)
            elif record.levelno >= logging.ERROR:
                self._logger.error(text)
            elif record.levelno >= logging.WARNING:
                self._logger.warning(text)
            elif record.levelno >= logging.INFO:
                self._logger.info(text)
            else:
                self._logger.debug(text)
        except Exception:  # noqa: BLE001 - a log handler must never raise into the core
            self.handleError(record)


def forward_logging(node: Node, *logger_names: str,
                    level: int = logging.INFO) -> RosLogHandler:
    """Attach a :class:`RosLogHandler` for ``node`` to the named core loggers.

    Returns the handler so the node can remove it on shutdown
    (``logging.getLogger(name).removeHandler(handler)``).
    """
    handler = RosLogHandler(node, level)
    for name in logger_names:
        core_logger = logging.getLogger(name)
        core_logger.addHandler(handler)
        if core_logger.level == logging.NOTSET or core_logger.level > level:
            core_logger.setLevel(level)
        # the records go to ROS; do not print them a second time through the root logger
        core_logger.propagate = False
    return handler
