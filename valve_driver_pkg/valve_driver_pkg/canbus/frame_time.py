"""When a received frame was on the bus: its own timestamp, or the moment it was handled.

One home for the rule both drivers stamp their states by. A frame's own timestamp (the
interface's receive time; on ``tcp_loopback`` the sender's) says when its values were on
the bus; the moment the host's receive thread handles it comes later by the host's
scheduling, which on a loaded machine bunches frames sent 1 ms apart into one instant and
leaves gaps between the bunches. A current trace stamped so has its rise in the wrong
place by that jitter, which identification reads as dynamics.
"""
from __future__ import annotations

__all__ = ['CLOCK_APART_S', 'frame_time_s']

#: A frame timestamp this far from the wall clock belongs to another clock [s] (some
#: adapters count from their own start).
CLOCK_APART_S = 3600.0


def frame_time_s(timestamp_s: float, wall_s: float) -> float:
    """The wall time [s since the epoch] a received frame's values refer to.

    Parameters
    ----------
    timestamp_s : float
        The frame's timestamp [s]; 0 when the interface gives none.
    wall_s : float
        The wall clock when the frame was handled [s since the epoch].

    Returns
    -------
    float
        ``timestamp_s`` when it is this clock's (not 0, within :data:`CLOCK_APART_S` of
        ``wall_s`` either way: a sender's clock on ``tcp_loopback`` may run a little
        ahead), else ``wall_s``.
    """
    if timestamp_s > 0.0 and abs(wall_s - timestamp_s) < CLOCK_APART_S:
        return timestamp_s
    return wall_s
