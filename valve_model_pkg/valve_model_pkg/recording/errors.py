"""Errors of the recording package.

A small tree: everything the package raises on purpose is a :class:`RecordingError`; each
leaf also inherits the built-in a caller would catch without knowing this package.
"""
from __future__ import annotations

__all__ = ['RecordingError', 'BagWriteError', 'BagFormatError', 'UnknownMessageTypeError']


class RecordingError(Exception):
    """Base of the errors raised by :mod:`valve_model_pkg.recording`."""


class BagWriteError(RecordingError, OSError):
    """A bag cannot be created or written (path exists, disk full, writer thread died)."""


class BagFormatError(RecordingError, ValueError):
    """A bag or MCAP file cannot be read: not a bag, corrupt beyond recovery, no messages."""


class UnknownMessageTypeError(RecordingError, LookupError):
    """A message type has no definition in the typestore nor in any ament prefix."""
