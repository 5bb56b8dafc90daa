"""The time base of a suite bag: every message on the clock the run was driven by.

A message with a header carries its stamp (simulation time in lockstep). A message
without one (``cylinder/position_goal``, ``cylinder/position_setpoint``:
``std_msgs/Float64``) has only the recorder's receive time, which on simulation time is
another time base (wall clock); it gets the stamp of the last joint state received before
it, the control tick it belongs to (in lockstep the controller publishes while the
simulation waits for its answer).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..interface import TOPIC_JOINT_STATES
from ..recording import TopicData

__all__ = ['RunTimeBase', 'run_time_base', 'own_times_s']

#: Receive time and header stamp of the first joint state further apart than this [ns]:
#: the bag is on simulation time (on wall-clock time both agree within milliseconds).
_SIMULATION_TIME_GAP_NS = 3_600 * 10**9


def own_times_s(topic: TopicData, origin_ns: int) -> np.ndarray:
    """The topic's own times [s from ``origin_ns``]: header stamps, else receive times.

    Parameters
    ----------
    topic : TopicData
        One topic of :func:`valve_model_pkg.recording.load_bag`.
    origin_ns : int
        Time zero [ns, the bag's stamp clock].

    Returns
    -------
    numpy.ndarray, shape (n,)
        Seconds from ``origin_ns``, formed from integer nanoseconds.
    """
    ns = topic.stamp_ns if topic.stamp_ns is not None else topic.log_time_ns
    return (ns - origin_ns) * 1e-9


@dataclass(frozen=True)
class RunTimeBase:
    """The clock of a suite run and the map of receive times onto it.

    Attributes
    ----------
    origin_ns : int
        Time zero [ns on the stamp clock].
    joint_log_ns, joint_stamp_ns : numpy.ndarray of int64, shape (m,), or None
        Receive times (ascending) of the joint states and their stamps (running maximum),
        on simulation time; ``None`` for a bag on wall-clock time.
    """

    origin_ns: int
    joint_log_ns: np.ndarray | None = None
    joint_stamp_ns: np.ndarray | None = None

    @property
    def simulation_time(self) -> bool:
        """Whether the bag's stamps are simulation time (not its receive times' clock)."""
        return self.joint_log_ns is not None

    def times_s(self, topic: TopicData) -> np.ndarray:
        """Times [s from the origin] of the messages of ``topic`` on the run's clock.

        Header stamps where the type has them. Without a header: on simulation time, the
        stamp of the last joint state received before each message; on wall-clock time,
        the receive times.
        """
        if topic.stamp_ns is not None or self.joint_log_ns is None:
            return own_times_s(topic, self.origin_ns)
        i = np.searchsorted(self.joint_log_ns, np.asarray(topic.log_time_ns, dtype=np.int64),
                            'right') - 1
        return (self.joint_stamp_ns[np.clip(i, 0, None)] - self.origin_ns) * 1e-9


def run_time_base(data: Mapping[str, TopicData], origin_ns: int) -> RunTimeBase:
    """The run's time base from the bag's ``cylinder/joint_states``.

    Parameters
    ----------
    data : mapping of str to TopicData
        :func:`valve_model_pkg.recording.load_bag` of the run (``/cylinder/joint_states``
        at least, for a bag on simulation time).
    origin_ns : int
        Time zero [ns on the stamp clock].

    Returns
    -------
    RunTimeBase
        On wall-clock time (stamps and receive times agree, or fewer than two stamped
        joint states) without a receive-time map.
    """
    joints = data.get('/' + TOPIC_JOINT_STATES)
    if joints is None or len(joints) < 2 or joints.stamp_ns is None:
        return RunTimeBase(origin_ns)
    if abs(int(joints.log_time_ns[0]) - int(joints.stamp_ns[0])) < _SIMULATION_TIME_GAP_NS:
        return RunTimeBase(origin_ns)
    log = np.asarray(joints.log_time_ns, dtype=np.int64)
    stamp = np.asarray(joints.stamp_ns, dtype=np.int64)
    order = np.argsort(log, kind='stable')
    return RunTimeBase(origin_ns, log[order], np.maximum.accumulate(stamp[order]))
