"""Every error that :mod:`valve_model_pkg` raises on purpose, in one tree.

One root, :class:`ValveModelError`, so a caller can catch everything the package refuses
with one ``except``; beneath it one base per subsystem (parameters, data files, maps,
recording, identification, fleet, node start-up); each leaf also inherits the built-in a
caller would catch without knowing this package (``ValueError`` for bad input, ``OSError``
for a file that cannot be written, ...), as python-can's ``can.exceptions`` does.

::

    ValveModelError
    +-- ParameterError (ValueError)             model parameters and simulation inputs
    +-- DataFormatError (ValueError)            the measured-data CSV format
    +-- InstrumentFormatError (ValueError)      instrument exports (oscilloscopes, DAQ)
    +-- MapError                                static duty maps
    |   +-- MapFormatError (ValueError)
    |   +-- MapParameterMismatchError (ValueError)
    |   +-- FlowMapFormatError (ValueError)
    |   +-- MapGenerationError (RuntimeError)
    |   +-- FlowIdentificationError (ValueError)
    +-- RecordingError                          bags
    |   +-- BagWriteError (OSError)
    |   +-- BagFormatError (ValueError)
    |   +-- UnknownMessageTypeError (LookupError)
    +-- IdentificationError                     identification
    |   +-- MeasurementFormatError (ValueError)
    |   +-- ModelAdapterError (RuntimeError)
    +-- FleetError                              fleet runs
    |   +-- ManifestError (ValueError)
    |   +-- SchedulerError (ConnectionError)
    |   +-- StoreBusyError (RuntimeError)
    +-- RunAnalysisError (ValueError)           a suite run's bag that cannot be analysed
    +-- StartupRefused                          a node refuses its start-up input
"""
from __future__ import annotations

import os

__all__ = [
    'ValveModelError',
    'ParameterError',
    'KernelInputError',
    'DataFormatError',
    'InstrumentFormatError',
    'MapError', 'MapFormatError', 'MapParameterMismatchError', 'FlowMapFormatError',
    'MapGenerationError', 'FlowIdentificationError',
    'RecordingError', 'BagWriteError', 'BagFormatError', 'UnknownMessageTypeError',
    'IdentificationError', 'MeasurementFormatError', 'ModelAdapterError',
    'FleetError', 'ManifestError', 'SchedulerError', 'StoreBusyError',
    'RunAnalysisError',
    'StartupRefused',
]


class ValveModelError(Exception):
    """Root of every error raised on purpose by :mod:`valve_model_pkg`."""


def _where(path: str, line: int | None) -> str:
    return f'{path}:{line}' if line is not None else path


# --- parameters ------------------------------------------------------------------------
class ParameterError(ValveModelError, ValueError):
    """An invalid, missing or unknown model parameter (message names field and value).

    Parameters
    ----------
    message : str
        One line naming the field and the value.
    key : str, optional
        The parameter (or YAML key) concerned, when there is one; lets
        :func:`~valve_model_pkg.model.load_parameters` name the line of the file.
    """

    def __init__(self, message: str, *, key: str | None = None) -> None:
        super().__init__(message)
        self.key = key


class KernelInputError(ValveModelError, ValueError):
    """Rows handed to the model's compiled kernel that it cannot integrate: an input
    interval or PWM period of zero length, sample times that do not increase (the message
    names the array, the index and the value)."""


# --- measured-data files ---------------------------------------------------------------
class DataFormatError(ValveModelError, ValueError):
    """A file that breaks the measured-data format.

    Parameters
    ----------
    path : str
        The file that was refused.
    line : int or None
        1-based line of the problem; ``None`` when it concerns the whole file.
    reason : str
        What is wrong, naming the key or column and the value.
    key : str, optional
        The metadata key or column concerned.
    value : str, optional
        The offending text as found in the file.
    """

    def __init__(self, path: str | os.PathLike[str], line: int | None, reason: str, *,
                 key: str | None = None, value: str | None = None) -> None:
        self.path = str(path)
        self.line = line
        self.reason = reason
        self.key = key
        self.value = value
        super().__init__(f'{_where(self.path, line)}: {reason}')


class InstrumentFormatError(ValveModelError, ValueError):
    """An instrument export (oscilloscope or DAQ file) that cannot be imported.

    Parameters
    ----------
    path : str
        The file that was refused.
    line : int or None
        1-based row (text files) of the problem; ``None`` when it concerns the whole file
        or a binary file (the reason then names the variable or channel).
    reason : str
        What was found and what was expected there.
    """

    def __init__(self, path: str | os.PathLike[str], line: int | None, reason: str) -> None:
        self.path = str(path)
        self.line = line
        self.reason = reason
        super().__init__(f'{_where(self.path, line)}: {reason}')


# --- maps ------------------------------------------------------------------------------
class MapError(ValveModelError):
    """Base of the static duty map's errors."""


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
        super().__init__(f'{_where(str(path), line)}: {reason}')
        self.path = path
        self.line = line
        self.reason = reason


class MapGenerationError(MapError, RuntimeError):
    """The map could not be generated (model failure, bad grid)."""


class FlowIdentificationError(MapError, ValueError):
    """The data cannot identify the orifice constant (one line saying why)."""


# --- recording -------------------------------------------------------------------------
class RecordingError(ValveModelError):
    """Base of the errors raised by :mod:`valve_model_pkg.recording`."""


class BagWriteError(RecordingError, OSError):
    """A bag cannot be created or written (path exists, disk full, writer thread died)."""


class BagFormatError(RecordingError, ValueError):
    """A bag or MCAP file cannot be read: not a bag, corrupt beyond recovery, no messages."""


class UnknownMessageTypeError(RecordingError, LookupError):
    """A message type has no definition in the typestore nor in any ament prefix."""


# --- identification --------------------------------------------------------------------
class IdentificationError(ValveModelError):
    """Base of the identification's errors."""


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
        super().__init__(f'{_where(self.path, line)}: {reason}')


class ModelAdapterError(IdentificationError, RuntimeError):
    """The valve model does not offer what the identification needs."""


# --- fleet -----------------------------------------------------------------------------
class FleetError(ValveModelError):
    """Base of the fleet runner's errors."""


class ManifestError(FleetError, ValueError):
    """A refused manifest: one line naming the file, the line and key, and the value.

    Parameters
    ----------
    path : str
        The manifest.
    line : int or None
        1-based line of the manifest, ``None`` when unknown or about the whole file.
    key : str or None
        The column or key at fault.
    reason : str
        What is wrong, with the value.
    """

    def __init__(self, path: str | os.PathLike[str], line: int | None, key: str | None,
                 reason: str) -> None:
        self.path, self.line, self.key, self.reason = str(path), line, key, reason
        super().__init__(f'{_where(self.path, line)}: ' + (f'{key}: ' if key else '')
                         + reason)


class SchedulerError(FleetError, ConnectionError):
    """The Dask scheduler cannot be reached (bad or dead address)."""


class StoreBusyError(FleetError, RuntimeError):
    """Another run holds the output folder."""


# --- analysis of suite runs ------------------------------------------------------------
class RunAnalysisError(ValveModelError, ValueError):
    """A suite run's bag that cannot be analysed (one line naming the bag and the lack: a
    topic missing, goals other than the schedule's, too few flow windows)."""


# --- nodes -----------------------------------------------------------------------------
class StartupRefused(ValveModelError):
    """A node refuses its start-up input (its message names it): the node exits 2."""
