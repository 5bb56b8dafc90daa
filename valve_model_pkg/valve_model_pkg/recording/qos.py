"""QoS profiles as rosbag2 records them, built from plain values (no ROS import).

The recorder node reads each publisher's offered QoS from the ROS graph and converts it
with :func:`make_qos`; rclpy's policy enums have the same integer values as rosbags'.
Durations are nanoseconds; rclpy's "infinite" (2**63 - 1 ns) is stored as
``sec: 9223372036, nsec: 854775807``, as rosbag2 on Jazzy stores it.
"""
from __future__ import annotations

from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness,
                                QosReliability, QosTime)

__all__ = ['make_qos', 'reliable_qos', 'qos_summary']

_INFINITE_NS = 2**63 - 1


def _time(ns: int) -> QosTime:
    ns = min(int(ns), _INFINITE_NS)
    return QosTime(ns // 1_000_000_000, ns % 1_000_000_000)


def make_qos(history: int, depth: int, reliability: int, durability: int, *,
             deadline_ns: int = _INFINITE_NS, lifespan_ns: int = _INFINITE_NS,
             liveliness: int = 1, liveliness_lease_duration_ns: int = _INFINITE_NS,
             avoid_ros_namespace_conventions: bool = False) -> Qos:
    """A rosbags :class:`~rosbags.interfaces.Qos` from rmw policy values.

    Parameters
    ----------
    history, reliability, durability, liveliness : int
        rmw enum values (``rclpy.qos.*Policy`` values): history 1 keep-last, 2 keep-all,
        3 unknown; reliability 1 reliable, 2 best effort; durability 1 transient local,
        2 volatile; liveliness 1 automatic.
    depth : int
        History depth.
    deadline_ns, lifespan_ns, liveliness_lease_duration_ns : int
        Durations [ns]; ``2**63 - 1`` is infinite.
    avoid_ros_namespace_conventions : bool
        As in rmw.

    Raises
    ------
    ValueError
        A policy value rosbags does not know.
    """
    try:
        return Qos(QosHistory(int(history)), int(depth), QosReliability(int(reliability)),
                   QosDurability(int(durability)), _time(deadline_ns), _time(lifespan_ns),
                   QosLiveliness(int(liveliness)), _time(liveliness_lease_duration_ns),
                   bool(avoid_ros_namespace_conventions))
    except ValueError as err:
        raise ValueError(f'QoS policy value not known to rosbags: {err}') from err


def reliable_qos(depth: int) -> Qos:
    """Reliable, volatile, keep-last ``depth``: the suite's publishers (valve/state: 1000)."""
    return make_qos(QosHistory.KEEP_LAST.value, depth, QosReliability.RELIABLE.value,
                    QosDurability.VOLATILE.value)


def qos_summary(profiles: list[Qos]) -> str:
    """``reliable/volatile`` style text of a topic's offered profiles (for logs, info)."""
    if not profiles:
        return 'unknown'
    kinds = sorted({f'{q.reliability.name.lower()}/{q.durability.name.lower()}'
                    for q in profiles})
    return ', '.join(kinds)
