"""Shared by the node robustness tests: hypothesis strategies of messages, and waits.

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


def wait_counts(ros: Any, predicate: Callable[[], bool], what: str,
                timeout_s: float = 60.0) -> None:
    """Wait (generously: the machine is shared) until ``predicate`` holds."""
    ros.wait_for(predicate, timeout_s, what)
