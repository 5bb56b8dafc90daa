"""Exceptions of the identification package.

One small tree: every error the package raises on purpose derives from
:class:`IdentificationError`; leaf classes also inherit the matching built-in so callers
that only know ``ValueError`` still catch them.
"""
from __future__ import annotations

__all__ = ['IdentificationError', 'MeasurementFormatError', 'ModelAdapterError']


class IdentificationError(Exception):
    """Base class of the identification package's errors."""


class MeasurementFormatError(IdentificationError, ValueError):
    """A measurement file is malformed.

    Parameters
    ----------
    path : str
        The file that was refused.
    line : int or None
        1-based line number of the offending line, ``None`` when the problem concerns the
        whole file (e.g. a missing column) or a bag message without a line.
    reason : str
        What is wrong, in words a person can act on.
    """

    def __init__(self, path: str, line: int | None, reason: str) -> None:
        self.path = str(path)
        self.line = line
        self.reason = reason
        where = f'{self.path}:{line}' if line is not None else self.path
        super().__init__(f'{where}: {reason}')


class ModelAdapterError(IdentificationError, RuntimeError):
    """The valve model does not offer what the identification needs."""
