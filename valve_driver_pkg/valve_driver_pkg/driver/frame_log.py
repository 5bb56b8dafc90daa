"""Raw bus traffic to a candump ``.log`` file (python-can's logger), beside the bag.

Every frame the driver receives and sends is written as one candump line
``(timestamp) channel id#data R|T`` through python-can's
:class:`can.io.CanutilsLogWriter`; ``candump -l``, ``canplayer``, ``python -m can.player``
and ``valve_can_replay`` read it back. The file is flushed at least every
``flush_period_s`` (as the suite's recorder flushes its bag), so a driver that is killed
loses at most that much of the log. The channel column is the driver's channel with
characters that candump cannot carry (spaces, ``:``) replaced, so the line stays one token.
"""
from __future__ import annotations

import re
import threading
import time
from pathlib import Path

import can

__all__ = ['FrameLog']


class FrameLog:
    """A thread-safe candump log writer; :meth:`close` is idempotent.

    Parameters
    ----------
    path : str | Path
        The ``.log`` file (created; its folder too).
    channel : str
        The channel name written in each line.
    flush_period_s : float
        The file is flushed when a frame comes this long after the last flush [s]
        (0: after every frame).
    """

    def __init__(self, path: str | Path, channel: str = 'can0',
                 flush_period_s: float = 1.0) -> None:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self.channel = re.sub(r'[^A-Za-z0-9_]', '_', channel) or 'can0'
        self._writer = can.io.CanutilsLogWriter(str(path), channel=self.channel)
        self._lock = threading.Lock()
        self._flush_period_s = flush_period_s
        self._last_flush = time.monotonic()
        self.frames = 0

    def write(self, msg: can.Message, received: bool) -> None:
        """Log one frame (``received``: from the bus, else sent by the driver)."""
        copy = can.Message(timestamp=msg.timestamp or time.time(),
                           arbitration_id=msg.arbitration_id,
                           is_extended_id=msg.is_extended_id,
                           is_error_frame=msg.is_error_frame,
                           is_remote_frame=msg.is_remote_frame, dlc=msg.dlc,
                           data=bytes(msg.data), channel=self.channel, is_rx=received,
                           check=False)
        with self._lock:
            if self._writer is None:
                return
            self._writer.on_message_received(copy)
            self.frames += 1
            now = time.monotonic()
            if now - self._last_flush >= self._flush_period_s:
                self._writer.file.flush()
                self._last_flush = now

    def close(self) -> None:
        """Flush and close the file; safe to call more than once."""
        with self._lock:
            writer, self._writer = self._writer, None
        if writer is not None:
            writer.stop()
