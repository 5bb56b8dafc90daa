"""What readers share: the file's head for detection, the loaded samples, the reader protocol.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from .capture import CaptureHeader, ChannelInfo, TimeAxis

__all__ = ['Head', 'Loaded', 'Reader']


@dataclass(frozen=True)
class Head:
    """The start of a file, as detection looks at it.

    Attributes
    ----------
    path : str
    raw : bytes
        The first 64 KiB.
    lines : tuple of str
        Its first lines decoded as UTF-8 (empty for a binary file), at most 80.
    """

    path: str
    raw: bytes
    lines: tuple[str, ...] = ()

    @property
    def is_text(self) -> bool:
        return bool(self.lines)


@dataclass(frozen=True)
class Loaded:
    """Samples a reader loaded for some channels.

    Attributes
    ----------
    time : TimeAxis
    values : dict of str to numpy.ndarray, shape (n,)
        By channel name, in the file's units times the channel's factor.
    over_range : dict of str to int
    first_row : int or None
        File row of the first sample (text files).
    notes : list of str
    """

    time: TimeAxis
    values: dict[str, np.ndarray]
    over_range: dict[str, int] = field(default_factory=dict)
    first_row: int | None = None
    notes: list[str] = field(default_factory=list)


class Reader(Protocol):
    """One format family: detection from the content, the header, the samples."""

    #: Format key, used in the record's header (``tektronix-tds``).
    key: str
    #: How documents name the format.
    title: str

    def sniff(self, head: Head) -> bool:
        """True when the content is this format (never from the file name)."""

    def open(self, head: Head) -> CaptureHeader:
        """Read the header: instrument, channels, stated time base."""

    def load(self, header: CaptureHeader, channels: list[ChannelInfo],
             time_channel: ChannelInfo | None = None) -> Loaded:
        """Read the samples of ``channels`` (and the time axis)."""
