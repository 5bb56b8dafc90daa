"""Errors of the static duty map package (a small tree; leaves also inherit ValueError)."""
from __future__ import annotations

__all__ = ['MapError', 'MapFormatError', 'MapParameterMismatchError', 'FlowMapFormatError',
           'MapGenerationError']


class MapError(Exception):
    """Base class of the map package's errors."""


class MapFormatError(MapError, ValueError):
    """A map file that is missing, unreadable, malformed or of an unknown format version.

    The message names the file and the reason.
    """

    def __init__(self, path: str, reason: str) -> None:
        super().__init__(f'{path}: {reason}')
        self.path = path
        self.reason = reason


class MapParameterMismatchError(MapError, ValueError):
    """A map made for another valve parameter set than the one in force.

    The message names the file, both parameter hashes and the first fields that differ.
    """

    def __init__(self, path: str, reason: str) -> None:
        super().__init__(f'{path}: {reason}')
        self.path = path
        self.reason = reason


class FlowMapFormatError(MapError, ValueError):
    """A measured ``flow_map`` CSV file that breaks the shared format (file, line, problem)."""

    def __init__(self, path: str, line: int | None, reason: str) -> None:
        where = f'{path}:{line}' if line is not None else str(path)
        super().__init__(f'{where}: {reason}')
        self.path = path
        self.line = line
        self.reason = reason


class MapGenerationError(MapError, RuntimeError):
    """The map could not be generated (model failure, bad grid)."""
