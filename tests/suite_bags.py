"""Small bags of the suite's messages for unit tests: one writer loop and one header
builder for the tests that build a bag message by message (rosbags, MCAP, the suite's
typestore)."""
from __future__ import annotations

from pathlib import Path
from typing import Iterable


def header(types: dict, ns: int, frame: str = '') -> object:
    """A std_msgs/Header stamped ``ns`` [ns]."""
    return types['std_msgs/msg/Header'](
        stamp=types['builtin_interfaces/msg/Time'](sec=ns // 10**9, nanosec=ns % 10**9),
        frame_id=frame)


def write_bag(path: Path, store: object,
              messages: Iterable[tuple[str, str, int, object]]) -> None:
    """Write ``messages`` = (topic, message type, log time [ns], message) in the order given,
    one connection per topic (reliable, keep last 1000, as the recorder offers them)."""
    from valve_model_pkg.recording import BagWriter, reliable_qos
    with BagWriter(path, store) as w:
        conns = {}
        for topic, msgtype, log_ns, msg in messages:
            if topic not in conns:
                conns[topic] = w.add_topic(topic, msgtype, [reliable_qos(1000)])
            w.write(conns[topic], log_ns, bytes(store.serialize_cdr(msg, msgtype)))
