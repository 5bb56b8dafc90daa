"""What readers share: the file's head for detection, the loaded samples, the reader protocol.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from .capture import CaptureHeader, ChannelInfo, TimeAxis
from .text import Columns

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

    @classmethod
    def from_columns(cls, time: TimeAxis, channels: list[ChannelInfo], cols: Columns,
                     notes: list[str] | None = None) -> 'Loaded':
        """The samples of ``channels`` from parsed rows whose first column is the time.

        Parameters
        ----------
        time : TimeAxis
        channels : list of ChannelInfo
            In the order of ``cols.values[1:]``; each scaled by its ``factor``.
        cols : Columns
        notes : list of str, optional
        """
        values = {c.name: v * c.factor for c, v in zip(channels, cols.values[1:])}
        over = {c.name: n for c, n in zip(channels, cols.n_over_range[1:])}
        return cls(time=time, values=values, over_range=over, first_row=cols.first_row,
                   notes=list(notes or []))


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
