"""Waiting in tests: poll a condition against a deadline, never sleep a fixed time (a module
of its own: ``conftest`` names are ambiguous)."""
from __future__ import annotations

import time
from collections.abc import Callable

#: Pause between two polls of a condition [s].
POLL_INTERVAL_S = 0.05


def poll_until(predicate: Callable[[], bool], timeout_s: float, what: str,
               interval_s: float = POLL_INTERVAL_S) -> None:
    """Poll ``predicate`` until it holds; fail naming ``what`` after ``timeout_s`` [s]."""
    end = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > end:
            raise AssertionError(f'timed out after {timeout_s:g} s waiting for {what}')
        time.sleep(interval_s)
