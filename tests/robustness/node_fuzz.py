"""Shared by the node robustness tests: hypothesis strategies, diagnostics reading, bursts.

The validity rules the tests check the nodes against are written in each test, from
docs/safety.md ("Node inputs"), not imported from the nodes.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

#: Fixed number of examples per node and input mix; derandomized so CI is reproducible.
EXAMPLES = 80

EXTREMES = [math.nan, math.inf, -math.inf, 0.0, -0.0, 1e308, -1e308, 5e-324, -5e-324,
            1e-300, 1e300, -1.0, 1.0]
#: Any float64, the extremes weighted in.
any_float = st.one_of(st.sampled_from(EXTREMES), st.floats(allow_nan=True, allow_infinity=True))
#: header.frame_id: empty, ordinary, odd unicode (no NUL: not representable in a ROS string),
#: very long.
frame_ids = st.one_of(st.just(''),
                      st.text(st.characters(exclude_characters='\x00'), max_size=40),
                      st.just('x' * 10_000), st.just('/flow_to_duty'))
#: header.stamp (sec int32, nanosec uint32); nanosec >= 10^9 is malformed.
stamps = st.tuples(st.integers(-2**31, 2**31 - 1),
                   st.one_of(st.integers(0, 999_999_999), st.integers(0, 2**32 - 1),
                             st.sampled_from([10**9, 2**32 - 1])))
#: sequence (uint64).
sequences = st.one_of(st.integers(0, 100), st.integers(0, 2**64 - 1))


def collect(strategy: st.SearchStrategy, n: int = EXAMPLES) -> list[Any]:
    """``n`` examples of ``strategy``, drawn by hypothesis with a fixed seed."""
    out: list[Any] = []

    @settings(max_examples=n, derandomize=True, database=None, deadline=None,
              phases=[Phase.explicit, Phase.generate],
              suppress_health_check=list(HealthCheck))
    @given(strategy)
    def draw(value: Any) -> None:
        out.append(value)

    draw()
    return out


def set_header(msg: Any, frame_id: str, stamp: tuple[int, int]) -> Any:
    """Fill ``msg.header`` and return ``msg``."""
    msg.header.frame_id = frame_id
    msg.header.stamp.sec, msg.header.stamp.nanosec = stamp
    return msg


class Diagnostics:
    """The latest key/values of the /diagnostics status whose name contains ``name_part``."""

    def __init__(self, node: Any, name_part: str) -> None:
        from diagnostic_msgs.msg import DiagnosticArray

        from valve_model_pkg.nodes.common import TOPIC_DIAGNOSTICS
        self.name_part = name_part
        self.values: dict[str, str] = {}
        self.count = 0
        node.create_subscription(DiagnosticArray, TOPIC_DIAGNOSTICS, self._on, 50)

    def _on(self, msg: Any) -> None:
        for status in msg.status:
            if self.name_part in status.name:
                self.values = {kv.key: kv.value for kv in status.values}
                self.count += 1

    def int(self, key: str) -> int:
        """An integer value, -1 while absent."""
        return int(self.values.get(key, -1))

    def rejected(self, input_name: str, kinds: tuple[str, ...] | None = None) -> int:
        """Sum of ``rejected_<input>_<kind>`` (all kinds, or those in ``kinds``)."""
        prefix = f'rejected_{input_name}_'
        return sum(int(v) for k, v in self.values.items() if k.startswith(prefix)
                   and (kinds is None or k[len(prefix):] in kinds))


def wait_counts(ros: Any, predicate: Callable[[], bool], what: str,
                timeout_s: float = 60.0) -> None:
    """Wait (generously: the machine is shared) until ``predicate`` holds."""
    ros.wait_for(predicate, timeout_s, what)


def wait_matched(ros: Any, publishers: list[Any], what: str) -> None:
    """Wait until every publisher has a subscriber (a burst before that is lost)."""
    ros.wait_for(lambda: all(p.get_subscription_count() > 0 for p in publishers), 60.0,
                 f'{what} to subscribe')
