"""StateProbe: a small rclpy node that commands a valve and summarises its state stream.

Used by the demo and by the node tests: it publishes duty commands (numbered by their
``sequence``, ``header.frame_id`` = its own name), counts state messages, checks their
sequence for gaps and keeps windowed statistics.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from rclpy.node import Node
from valve_msgs.msg import DutyCommand, ValveState

from valve_model_pkg.interface.ros import state_reader_qos
from valve_model_pkg.nodes.common import COMMAND_QOS, STATE_QOS, TOPIC_DUTY_COMMAND, TOPIC_STATE


@dataclass(frozen=True)
class Window:
    """Statistics of the state messages received since the last reset."""

    count: int
    rate_hz: float
    position_avg_pct: float
    current_mean_a: float
    current_max_a: float
    mass_flow_kg_s: float
    last: ValveState | None


class StateProbe(Node):
    """Subscribe to ``valve/state``, publish ``valve/duty_command``."""

    def __init__(self, name: str = 'valve_probe', queue_depth: int | None = None) -> None:
        """``queue_depth``: states the subscription holds while the probe is busy (default
        :data:`STATE_QOS`'s); a reader that falls further behind loses the oldest, which
        the probe counts as gaps."""
        super().__init__(name)
        self._cmd_pub = self.create_publisher(DutyCommand, TOPIC_DUTY_COMMAND, COMMAND_QOS)
        qos = STATE_QOS if queue_depth is None else state_reader_qos(queue_depth)
        self.create_subscription(ValveState, TOPIC_STATE, self._on_state, qos)
        self.count = 0
        self.gaps = 0
        self.commands_sent = 0  # also the sequence of the next duty command
        self.messages: list[ValveState] = []
        self.keep_messages = False
        self._last_seq: int | None = None
        self._x_max_m = math.nan
        self.reset_window()

    def command(self, duty: float, pwm_frequency_hz: float) -> None:
        """Publish one duty command."""
        msg = DutyCommand()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = self.get_fully_qualified_name()
        msg.sequence = self.commands_sent
        msg.duty = float(duty)
        msg.pwm_frequency = float(pwm_frequency_hz)
        self._cmd_pub.publish(msg)
        self.commands_sent += 1

    def reset_window(self) -> None:
        """Start a new statistics window."""
        self._w_count = 0
        self._w_first_stamp: float | None = None
        self._w_last_stamp = 0.0
        self._w_pos_sum = 0.0
        self._w_i_sum = 0.0
        self._w_i_max = -math.inf
        self._w_flow_sum = 0.0
        self._w_last: ValveState | None = None

    def _on_state(self, msg: ValveState) -> None:
        self.count += 1
        if self._last_seq is not None and msg.sequence != self._last_seq + 1:
            self.gaps += 1
        self._last_seq = msg.sequence
        if self.keep_messages:
            self.messages.append(msg)
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        if self._w_first_stamp is None:
            self._w_first_stamp = stamp
        self._w_last_stamp = stamp
        self._w_count += 1
        self._w_pos_sum += msg.spool_position_avg
        self._w_i_sum += msg.coil_current
        self._w_i_max = max(self._w_i_max, msg.coil_current)
        self._w_flow_sum += msg.mass_flow
        self._x_max_m = max(self._x_max_m, msg.spool_position) \
            if math.isfinite(self._x_max_m) else msg.spool_position
        self._w_last = msg

    def window(self, x_max_m: float | None = None) -> Window:
        """Statistics since the last :meth:`reset_window`.

        ``position_avg_pct`` is the mean PWM-period average position in percent of
        ``x_max_m`` (default: the largest position seen so far, i.e. the open stop once
        the valve has opened).
        """
        n = self._w_count
        span = (self._w_last_stamp - self._w_first_stamp) if self._w_first_stamp else 0.0
        rate = (n - 1) / span if n > 1 and span > 0 else 0.0
        x_max = x_max_m if x_max_m is not None else self._x_max_m
        pos_pct = (100.0 * self._w_pos_sum / n / x_max
                   if n and x_max and math.isfinite(x_max) and x_max > 0 else 0.0)
        return Window(count=n, rate_hz=rate, position_avg_pct=pos_pct,
                      current_mean_a=self._w_i_sum / n if n else 0.0,
                      current_max_a=self._w_i_max if n else 0.0,
                      mass_flow_kg_s=self._w_flow_sum / n if n else 0.0, last=self._w_last)
