"""The tests' one way to wait: poll a condition until a deadline.

A test never sleeps for a time it hopes is long enough; it waits for the condition it
needs, and fails naming that condition once the deadline is over. Deadlines only end a
test that would otherwise hang: they are the configured timeouts the condition depends on
plus :data:`SCHEDULING_ALLOWANCE_S` for a loaded machine, never a pass criterion.
"""
from __future__ import annotations

import time
from collections.abc import Callable

__all__ = ['wait_until', 'SCHEDULING_ALLOWANCE_S', 'POLL_STEP_S', 'TEST_READER_DEPTH']

#: What a loaded 2-core machine may add to any wait (processes descheduled, the first call
#: of compiled code loading it) [s].
SCHEDULING_ALLOWANCE_S = 20.0
#: Depth of a test's own reader of a fast stream (20 s of 1 kHz states): a test process
#: held up by a loaded machine keeps its whole window instead of losing the oldest
#: messages, so a gap it counts is the node's, not its own.
TEST_READER_DEPTH = 20_000
#: The pause between two polls when the caller gives no step of its own [s].
POLL_STEP_S = 0.005


def wait_until(predicate: Callable[[], object], timeout_s: float = SCHEDULING_ALLOWANCE_S,
               what: str = 'the condition', step: Callable[[], None] | None = None) -> None:
    """Poll ``predicate()`` until it is true; AssertionError naming ``what`` after
    ``timeout_s``.

    ``step`` runs between two polls (e.g. spinning ROS, handling the emulator's frames);
    without one the poll pauses :data:`POLL_STEP_S`.
    """
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f'timed out after {timeout_s:g} s waiting for {what}')
        if step is not None:
            step()
        else:
            time.sleep(POLL_STEP_S)
