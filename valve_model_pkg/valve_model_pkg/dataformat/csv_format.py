"""Read and write files of the measured-data format, every kind, with one set of rules.

The rules (from the measured-data format document, ``shared/measured-data-format.md`` of
the steering repository) as this module applies them to every kind:

* UTF-8 text (a byte-order mark is accepted), comma separated, ``.`` as decimal point.
* Leading metadata lines ``# key: value``; a key given twice is refused. A leading ``#``
  line without ``key: value`` is a free comment. Blank lines before the header are
  skipped. Unknown keys are kept.
* One header row; duplicate column names are refused; the kind (metadata
  ``experiment``) decides the required columns; unknown columns are kept out of the
  record and listed in its notes.
* One row per sample (per operating point in a ``flow_map``). Every row has as many
  fields as the header. A ``#`` line or an empty line followed by more rows inside the
  data is refused; empty lines at the end are not.
* Every field is a finite number in SI units. Only *measured* signals may lack a value
  (empty, ``nan``, ``na`` or ``null``): it is kept as ``nan``, counted, and named in the
  notes. Nothing is dropped.
* ``t`` starts at or after 0 and increases strictly; ``duty`` lies in [0, 1].
* Numeric metadata must be finite numbers; ``sample_rate_hz``, ``pwm_frequency_hz``,
  ``supply_voltage_v`` and ``supply_temperature_k`` must be positive, pressures (gauge)
  not below vacuum. A time axis that disagrees with ``sample_rate_hz`` by more than 5 %
  is noted (the time axis is used), as are gaps longer than 1.5 sample periods; a median
  time step off ``1/sample_rate_hz`` by more than a factor of 2 (time in ms) is refused,
  naming the line, the step found and the step expected.
* ``current`` beyond +-50 A (:data:`MAX_ABS_CURRENT_A`, the plausible range of a bench
  current sensor) is refused naming the line, as is ``coil_voltage_mean`` beyond
  +-1000 V (:data:`MAX_ABS_COIL_VOLTAGE_V`).
* Bounded resources: the file is streamed line by line and only the columns of the
  record are kept (float64). Refused at once: a file above :data:`MAX_FILE_BYTES`
  (512 MiB, before reading), a NUL byte in the first 64 KiB (binary), a line longer than
  :data:`MAX_LINE_CHARS`, a header with more than :data:`MAX_COLUMNS` columns, more than
  :data:`MAX_ROWS` data rows, bytes that are not UTF-8 (naming the line).

Every refusal is a :class:`DataFormatError` whose message names the file, the line (when
the problem has one), and the key or column and the value.
"""
from __future__ import annotations

import math
import os
from array import array
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..model.constants import ATMOSPHERIC_PRESSURE_PA
from ..errors import DataFormatError

__all__ = [
    'EXPERIMENTS', 'FORMAT_NAME', 'MAX_FILE_BYTES', 'MAX_ROWS', 'MAX_LINE_CHARS',
    'MAX_COLUMNS', 'MAX_ABS_CURRENT_A', 'DataFormatError', 'TraceRecord', 'OperationRecord',
    'FlowMapRecord', 'check_time_axis', 'read_record', 'read_trace', 'read_operation',
    'read_flow_map', 'write_table', 'write_record',
]

#: How documents and messages refer to the format (never by a path on some machine).
FORMAT_NAME = 'the measured-data format'

#: Values of the ``experiment`` metadata key.
EXPERIMENTS = ('step', 'pwm', 'operation', 'flow_map')

# --- column and metadata tables of the format --------------------------------------------
#: Columns of a time trace of the bench (step, pwm), required first.
_TRACE_REQUIRED = ('t', 'voltage', 'current')
_TRACE_OPTIONAL = ('coil_voltage', 'position', 'mass_flow', 'duty')
#: Columns of an operational record.
_OPERATION_REQUIRED = ('t', 'duty', 'pwm_frequency_hz', 'current')
_OPERATION_OPTIONAL = ('supply_pressure', 'output_pressure', 'coil_voltage_mean')
#: Columns of a flow map (``duty`` plus exactly one value column).
_FLOW_VALUE_COLUMNS = ('mass_flow', 'flow_fraction')
#: Measured signals: the only columns that may lack a value in a row.
_MAY_BE_MISSING = frozenset({'current', 'coil_voltage', 'position', 'mass_flow',
                             'supply_pressure', 'output_pressure', 'coil_voltage_mean'})

_NUMERIC_METADATA = ('supply_pressure_pa', 'output_pressure_pa', 'supply_temperature_k',
                     'pwm_frequency_hz', 'sample_rate_hz', 'supply_voltage_v')
_POSITIVE_METADATA = ('supply_temperature_k', 'pwm_frequency_hz', 'sample_rate_hz',
                      'supply_voltage_v')
_PRESSURE_METADATA = ('supply_pressure_pa', 'output_pressure_pa')
_CURRENT_AVERAGING = ('instantaneous', 'interval_mean')
_MISSING_TOKENS = ('', 'nan', 'na', 'null')

#: A step of the time axis longer than this many nominal periods counts as missing rows.
_GAP_FACTOR = 1.5
#: Largest relative difference of the time axis from ``sample_rate_hz`` taken as agreement.
_RATE_TOLERANCE = 0.05
_VACUUM_GAUGE_PA = -ATMOSPHERIC_PRESSURE_PA

# --- resource limits: what a file may hold before it is refused -----------------------------
#: Largest file read [bytes]; a larger one is refused before a byte is read.
MAX_FILE_BYTES = 512 << 20
#: Largest number of data rows (10 M: 200 s at 50 kHz); with at most 8 numeric columns of
#: 8 bytes the parsed record stays below 0.7 GB.
MAX_ROWS = 10_000_000
#: Longest line [characters]; the format's lines are a few dozen.
MAX_LINE_CHARS = 1 << 16
#: Most columns in the header.
MAX_COLUMNS = 1000
#: Bytes at the start of the file checked for binary content (NUL bytes).
_SNIFF_BYTES = 1 << 16
#: Plausible coil current range of a bench current sensor: |i| above this is refused [A].
MAX_ABS_CURRENT_A = 50.0
#: Plausible mean coil voltage range of a valve drive: |u| above this is refused [V].
MAX_ABS_COIL_VOLTAGE_V = 1000.0
#: A median time step off ``1/sample_rate_hz`` by more than this factor is refused (time
#: in ms, a wrong rate); smaller differences are noted and the time axis is used.
_RATE_REFUSE_FACTOR = 2.0


# --- records --------------------------------------------------------------------------------
@dataclass(frozen=True)
class TraceRecord:
    """A ``step`` or ``pwm`` record: the bench's time trace.

    Attributes
    ----------
    path : str
    experiment : str
        ``step``, ``pwm`` or ``unknown`` (no ``experiment`` key).
    t_s : numpy.ndarray, shape (n,)
        Sample times [s], strictly increasing from at or after 0.
    voltage_v : numpy.ndarray, shape (n,)
        ``step``: voltage at the coil terminals; ``pwm``: the main PWM input voltage [V].
    current_a : numpy.ndarray, shape (n,)
        Coil current [A]; ``nan`` where the file has no value.
    coil_voltage_v, position_m, mass_flow_kg_s, duty : numpy.ndarray or None, shape (n,)
        Optional columns [V], [m], [kg/s], [1]; ``None`` when the file lacks them.
    metadata : dict of str to str
        Every ``# key: value`` line, unknown keys included.
    supply_pressure_pa : float or None
        Gauge [Pa], from the metadata.
    output_pressure_pa : float
        Gauge [Pa] (0 when the file does not say).
    nominal_sample_rate_hz : float or None
        ``sample_rate_hz`` of the metadata.
    line_numbers : numpy.ndarray of int, shape (n,)
        File line of each row.
    notes : tuple of str
        What the reader noticed and kept (missing values, gaps, rate, unknown columns).
    n_missing_values : int
        Rows whose current is missing.
    n_gaps : int
        Steps of the time axis longer than 1.5 nominal periods.
    """

    path: str
    experiment: str
    t_s: np.ndarray
    voltage_v: np.ndarray
    current_a: np.ndarray
    coil_voltage_v: np.ndarray | None = None
    position_m: np.ndarray | None = None
    mass_flow_kg_s: np.ndarray | None = None
    duty: np.ndarray | None = None
    metadata: dict[str, str] = field(default_factory=dict)
    supply_pressure_pa: float | None = None
    output_pressure_pa: float = 0.0
    nominal_sample_rate_hz: float | None = None
    line_numbers: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    notes: tuple[str, ...] = ()
    n_missing_values: int = 0
    n_gaps: int = 0

    kind = 'trace'

    def columns(self) -> dict[str, np.ndarray]:
        """The record's columns by their names in the format (present ones only)."""
        cols = {'t': self.t_s, 'voltage': self.voltage_v, 'current': self.current_a}
        for name, values in (('coil_voltage', self.coil_voltage_v),
                             ('position', self.position_m),
                             ('mass_flow', self.mass_flow_kg_s), ('duty', self.duty)):
            if values is not None:
                cols[name] = values
        return cols


@dataclass(frozen=True)
class OperationRecord:
    """An ``operation`` record: what a valve in service reports.

    Attributes
    ----------
    path : str
    t_s : numpy.ndarray, shape (n,)
        Sample times [s], strictly increasing from at or after 0.
    duty : numpy.ndarray, shape (n,)
        Main PWM duty in force at each sample [1].
    pwm_frequency_hz : numpy.ndarray, shape (n,)
        Main PWM frequency in force at each sample [Hz].
    current_a : numpy.ndarray, shape (n,)
        Coil current [A] (interval means with ``current_averaging: interval_mean``);
        ``nan`` where missing.
    supply_pressure_pa, output_pressure_pa : numpy.ndarray or None, shape (n,)
        Gauge pressures per sample [Pa]: the column, else the metadata value repeated,
        else ``None`` (supply) or zeros (output).
    supply_voltage_v : float or None
        Drive supply voltage [V] from the metadata.
    current_averaging : str
        ``instantaneous`` or ``interval_mean``.
    starts_at_rest : bool
        Whether the record begins with duty 0 for at least one PWM period (the reader's
        assumption is also stated in :attr:`notes`).
    pressure_columns : tuple of str
        Which of ``supply_pressure`` and ``output_pressure`` the file has as columns.
    coil_voltage_mean_v : numpy.ndarray or None, shape (n,)
        Mean voltage across the coil terminals over the same interval as the current [V]
        (``nan`` where missing); ``None`` without the column.
    n_missing_voltage : int
        Samples without a ``coil_voltage_mean`` value.
    metadata, nominal_sample_rate_hz, line_numbers, notes, n_missing_values, n_gaps
        As in :class:`TraceRecord`.
    """

    path: str
    t_s: np.ndarray
    duty: np.ndarray
    pwm_frequency_hz: np.ndarray
    current_a: np.ndarray
    supply_pressure_pa: np.ndarray | None = None
    output_pressure_pa: np.ndarray | None = None
    supply_voltage_v: float | None = None
    current_averaging: str = 'instantaneous'
    starts_at_rest: bool = False
    pressure_columns: tuple[str, ...] = ()
    metadata: dict[str, str] = field(default_factory=dict)
    nominal_sample_rate_hz: float | None = None
    line_numbers: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    notes: tuple[str, ...] = ()
    n_missing_values: int = 0
    n_gaps: int = 0
    coil_voltage_mean_v: np.ndarray | None = None
    n_missing_voltage: int = 0

    kind = 'operation'
    experiment = 'operation'

    def columns(self) -> dict[str, np.ndarray]:
        """The record's columns by their names in the format."""
        cols = {'t': self.t_s, 'duty': self.duty, 'pwm_frequency_hz': self.pwm_frequency_hz,
                'current': self.current_a}
        for name, values in (('supply_pressure', self.supply_pressure_pa),
                             ('output_pressure', self.output_pressure_pa)):
            if name in self.pressure_columns and values is not None:
                cols[name] = values
        if self.coil_voltage_mean_v is not None:
            cols['coil_voltage_mean'] = self.coil_voltage_mean_v
        return cols


@dataclass(frozen=True)
class FlowMapRecord:
    """A ``flow_map`` record: steady flow against duty, one row per operating point.

    Attributes
    ----------
    path : str
    duty : numpy.ndarray, shape (n,)
        Duties [1] in [0, 1], strictly ascending.
    mass_flow_kg_s, flow_fraction : numpy.ndarray or None, shape (n,)
        Exactly one is given: measured mass flow [kg/s] or flow over the flow at 100 %
        duty [1]; both non-negative.
    metadata : dict of str to str
    supply_pressure_pa, pwm_frequency_hz, supply_temperature_k : float or None
        From the metadata (gauge [Pa], [Hz], [K]); ``None`` where absent.
    output_pressure_pa : float
        Gauge [Pa] (0 when the file does not say).
    line_numbers : numpy.ndarray of int, shape (n,)
    notes : tuple of str
    """

    path: str
    duty: np.ndarray
    mass_flow_kg_s: np.ndarray | None
    flow_fraction: np.ndarray | None
    metadata: dict[str, str] = field(default_factory=dict)
    supply_pressure_pa: float | None = None
    output_pressure_pa: float = 0.0
    pwm_frequency_hz: float | None = None
    supply_temperature_k: float | None = None
    line_numbers: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    notes: tuple[str, ...] = ()

    kind = 'flow_map'
    experiment = 'flow_map'

    def columns(self) -> dict[str, np.ndarray]:
        """The record's columns by their names in the format."""
        if self.mass_flow_kg_s is not None:
            return {'duty': self.duty, 'mass_flow': self.mass_flow_kg_s}
        return {'duty': self.duty, 'flow_fraction': self.flow_fraction}


Record = TraceRecord | OperationRecord | FlowMapRecord


# --- the common layer: lines, metadata, header, fields -------------------------------------
@dataclass
class _Table:
    """A file's metadata and header; the rows are parsed by :func:`_columns` (streamed)."""

    path: str
    metadata: dict[str, str]
    meta_lines: dict[str, int]
    header: list[str]
    header_line: int
    numeric: dict[str, float] = field(default_factory=dict)
    #: File line of each data row; set by :func:`_columns`.
    linenos: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def error(self, line: int | None, reason: str, **kw: str | None) -> DataFormatError:
        return DataFormatError(self.path, line, reason, **kw)

    @property
    def experiment(self) -> str | None:
        return self.metadata.get('experiment')


def _lines(path: str | os.PathLike[str], skip: int = 0) -> Iterator[tuple[int, str]]:
    """(line number, text without end of line) of a file, streamed, limits applied.

    Reads one line at a time (never the whole file): a file above :data:`MAX_FILE_BYTES`
    is refused before reading, a binary file at its first bytes, a line longer than
    :data:`MAX_LINE_CHARS` at that line; non-UTF-8 bytes are refused naming their line.
    ``skip`` lines are passed over (already read).
    """
    spath = str(path)
    try:
        fh = open(path, 'rb')
    except OSError as err:
        raise DataFormatError(spath, None, f'cannot be read: {err.strerror}') from err
    with fh:
        try:
            size = os.fstat(fh.fileno()).st_size
        except OSError as err:
            raise DataFormatError(spath, None, f'cannot be read: {err.strerror}') from err
        if size > MAX_FILE_BYTES:
            raise DataFormatError(spath, None, f'is {size} bytes; files of {FORMAT_NAME} are '
                                  f'read up to {MAX_FILE_BYTES} bytes '
                                  f'({MAX_FILE_BYTES >> 20} MiB)')
        head = fh.read(_SNIFF_BYTES)
        nul = head.find(b'\x00')
        if nul >= 0:
            raise DataFormatError(spath, head[:nul].count(b'\n') + 1, f'is a binary file, not '
                                  f'text (NUL byte at offset {nul})')
        fh.seek(0)
        lineno = 0
        while True:
            raw = fh.readline(MAX_LINE_CHARS + 2)
            if not raw:
                return
            lineno += 1
            if lineno <= skip:
                continue
            if len(raw) == MAX_LINE_CHARS + 2 and not raw.endswith(b'\n'):
                raise DataFormatError(spath, lineno, f'is longer than {MAX_LINE_CHARS} '
                                      'characters (not a file of the format)')
            if b'\x00' in raw:
                raise DataFormatError(spath, lineno, 'has a NUL byte: a binary file, not text')
            try:
                text = raw.decode('utf-8-sig' if lineno == 1 else 'utf-8')
            except UnicodeDecodeError as err:
                raise DataFormatError(spath, lineno, f'is not UTF-8 text (byte '
                                      f'0x{raw[err.start]:02x} at column {err.start + 1})'
                                      ) from err
            yield lineno, text.rstrip('\r\n')


def _split(path: str | os.PathLike[str]) -> _Table:
    """Metadata and header of a file, with the layout rules applied (rows not yet read)."""
    spath = str(path)
    metadata: dict[str, str] = {}
    meta_lines: dict[str, int] = {}
    header: list[str] | None = None
    header_line = 0
    for lineno, line in _lines(path):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith('#'):
            body = stripped[1:].strip()
            if ':' in body:
                key, _, value = body.partition(':')
                key = key.strip()
                if key in metadata:
                    raise DataFormatError(
                        spath, lineno, f'metadata key {key!r} given twice (first on line '
                        f'{meta_lines[key]}, again as {value.strip()!r})', key=key,
                        value=value.strip())
                metadata[key] = value.strip()
                meta_lines[key] = lineno
            # A '#' line without 'key: value' is a free comment, not data.
            continue
        header = [c.strip() for c in stripped.split(',')]
        header_line = lineno
        break
    if header is None:
        raise DataFormatError(spath, None, 'has no header row and no data')
    if len(header) > MAX_COLUMNS:
        raise DataFormatError(spath, header_line, f'header has {len(header)} columns; the '
                              f'format has a few, at most {MAX_COLUMNS} are read')
    table = _Table(spath, metadata, meta_lines, header, header_line)
    _check_metadata(table)
    if len(set(header)) != len(header):
        dup = sorted({c for c in header if header.count(c) > 1})
        raise table.error(header_line, f'duplicate columns {dup}', key=dup[0])
    return table


def _parse_float(path: str, lineno: int | None, column: str, text: str, *,
                 allow_missing: bool, what: str = 'column') -> float:
    """One field (or metadata value); a missing value is ``nan`` where that is allowed."""
    token = text.strip()
    if token.lower() in _MISSING_TOKENS:
        if allow_missing:
            return math.nan
        if token == '':
            raise DataFormatError(path, lineno, f'{what} {column!r} has no value', key=column,
                                  value=token)
        raise DataFormatError(path, lineno, f'{what} {column!r}: {token!r} is not finite '
                              '(no value is allowed only in measured signals)', key=column,
                              value=token)
    try:
        value = float(token)
    except ValueError:
        raise DataFormatError(path, lineno, f'{what} {column!r}: {token!r} is not a number',
                              key=column, value=token) from None
    if not math.isfinite(value):
        raise DataFormatError(path, lineno, f'{what} {column!r}: {token!r} is not finite',
                              key=column, value=token)
    return value


def _check_metadata(table: _Table) -> None:
    """Numbers, ranges and enumerations of the metadata keys the format defines."""
    meta, lines = table.metadata, table.meta_lines
    experiment = meta.get('experiment')
    if experiment is not None and experiment not in EXPERIMENTS:
        raise table.error(lines['experiment'], f"metadata 'experiment': {experiment!r} is not "
                          f'one of {", ".join(EXPERIMENTS)}', key='experiment',
                          value=experiment)
    for key in _NUMERIC_METADATA:
        if key not in meta:
            continue
        value = _parse_float(table.path, lines[key], key, meta[key], allow_missing=False,
                             what='metadata')
        if key in _POSITIVE_METADATA and value <= 0.0:
            raise table.error(lines[key], f'metadata {key!r}: {meta[key]!r} must be positive',
                              key=key, value=meta[key])
        if key in _PRESSURE_METADATA and value < _VACUUM_GAUGE_PA:
            raise table.error(lines[key], f'metadata {key!r}: {meta[key]!r} Pa is below vacuum '
                              '(pressures are gauge)', key=key, value=meta[key])
        table.numeric[key] = value
    averaging = meta.get('current_averaging')
    if averaging is not None and averaging not in _CURRENT_AVERAGING:
        raise table.error(lines['current_averaging'], f"metadata 'current_averaging': "
                          f'{averaging!r} is not one of {", ".join(_CURRENT_AVERAGING)}',
                          key='current_averaging', value=averaging)


def _require_columns(table: _Table, required: Sequence[str], kind: str) -> None:
    missing = [c for c in required if c not in table.header]
    if missing:
        raise table.error(table.header_line, f'header lacks required column(s) {missing} '
                          f'of a {kind} record; found {table.header}', key=missing[0])


def _columns(table: _Table, names: Sequence[str]) -> dict[str, np.ndarray]:
    """Stream the data rows and parse the named columns (field count checked on every row).

    Only the named columns are kept, as float64 (8 bytes a value): memory grows with the
    rows times the columns the record uses, never with the text.
    """
    ncol = len(table.header)
    index = [(c, table.header.index(c), c in _MAY_BE_MISSING) for c in names]
    data = {c: array('d') for c in names}
    linenos = array('q')
    blank_after_data: int | None = None
    spath = table.path
    for lineno, line in _lines(spath, skip=table.header_line):
        stripped = line.strip()
        if not stripped:
            if blank_after_data is None:
                blank_after_data = lineno
            continue
        if blank_after_data is not None:
            raise DataFormatError(spath, blank_after_data,
                                  'empty line inside the data (rows follow it)')
        if stripped.startswith('#'):
            raise DataFormatError(spath, lineno, 'metadata/comment line after the header; '
                                  'metadata must lead')
        fields = stripped.split(',')
        if len(fields) != ncol:
            raise table.error(lineno, f'has {len(fields)} fields, expected {ncol} fields '
                              f'({",".join(table.header)})')
        if len(linenos) >= MAX_ROWS:
            raise table.error(lineno, f'more than {MAX_ROWS} data rows; files of '
                              f'{FORMAT_NAME} are read up to {MAX_ROWS} rows')
        linenos.append(lineno)
        for c, i, may_miss in index:
            text = fields[i]
            try:
                value = float(text)
            except ValueError:
                value = math.nan
            if value - value != 0.0:  # not a finite number: the full rules and message
                value = _parse_float(spath, lineno, c, text, allow_missing=may_miss)
            data[c].append(value)
    table.linenos = _as_array(linenos, np.int64)
    return {c: _as_array(v, np.float64) for c, v in data.items()}


def _as_array(values: array, dtype: type) -> np.ndarray:
    """The array's buffer as numpy (no copy)."""
    if len(values) == 0:
        return np.zeros(0, dtype=dtype)
    return np.frombuffer(values, dtype=dtype)


def _cell(table: _Table, row: int, column: str) -> str:
    """The text of a field as the file has it (for messages; reads the file again)."""
    target = int(table.linenos[row])
    for lineno, line in _lines(table.path, skip=target - 1):
        return line.strip().split(',')[table.header.index(column)].strip()
    return ''


def _refuse_cell(table: _Table, row: int, column: str, problem: str) -> DataFormatError:
    text = _cell(table, row, column)
    return table.error(table.linenos[row], f'column {column!r}: {text!r} {problem}',
                       key=column, value=text)


def _check_duty(table: _Table, duty: np.ndarray) -> None:
    bad = np.flatnonzero((duty < 0.0) | (duty > 1.0))
    if bad.size:
        raise _refuse_cell(table, int(bad[0]), 'duty', 'outside [0, 1]')


def check_time_axis(path: str, t: np.ndarray, linenos: Sequence[int] | None) -> None:
    """Refuse a time axis that is not strictly increasing from at or after zero.

    Parameters
    ----------
    path : str
        Named in the error.
    t : numpy.ndarray, shape (n,)
        Sample times [s].
    linenos : sequence of int or None
        File line of each sample; ``None`` for sources without lines (bag messages: the
        message index is named instead).

    Raises
    ------
    DataFormatError
    """
    if t.size == 0:
        return
    has_lines = linenos is not None and len(linenos) > 0
    if t[0] < 0.0:
        raise DataFormatError(path, int(linenos[0]) if has_lines else None,
                              f't = {t[0]!r} s is negative', key='t', value=repr(t[0]))
    steps = np.diff(t)
    bad = np.flatnonzero(steps <= 0.0)
    if bad.size:
        i = int(bad[0]) + 1
        where = int(linenos[i]) if has_lines else None
        raise DataFormatError(
            path, where, f't = {t[i]!r} s does not increase (previous sample t = {t[i - 1]!r} '
            's)' + ('' if has_lines else f' at message {i}'), key='t', value=repr(t[i]))


def _check_rate(table: _Table, t: np.ndarray) -> None:
    """Refuse a time axis whose median step is far from ``1/sample_rate_hz`` (e.g. ms)."""
    nominal = table.numeric.get('sample_rate_hz')
    if nominal is None or t.size < 2:
        return
    dt = np.diff(t)
    expected = 1.0 / nominal
    median = float(np.median(dt))
    if expected / _RATE_REFUSE_FACTOR <= median <= expected * _RATE_REFUSE_FACTOR:
        return
    off = np.flatnonzero((dt < expected / _RATE_REFUSE_FACTOR)
                         | (dt > expected * _RATE_REFUSE_FACTOR))
    i = int(off[0]) + 1
    raise _refuse_cell(table, i, 't', f'is {dt[i - 1]:.6g} s after the previous row, but '
                       f'sample_rate_hz {nominal:g} Hz means {expected:.6g} s (median step '
                       f'{median:.6g} s: is t in seconds?)')


def _check_current(table: _Table, current: np.ndarray) -> None:
    """Refuse a current beyond the sensor's plausible range (:data:`MAX_ABS_CURRENT_A`)."""
    with np.errstate(invalid='ignore'):
        bad = np.flatnonzero(np.abs(current) > MAX_ABS_CURRENT_A)
    if bad.size:
        raise _refuse_cell(table, int(bad[0]), 'current', f'A is beyond the plausible '
                           f'current range (|i| <= {MAX_ABS_CURRENT_A:g} A)')


def _check_coil_voltage(table: _Table, voltage: np.ndarray) -> None:
    """Refuse a mean coil voltage beyond a drive's plausible range
    (:data:`MAX_ABS_COIL_VOLTAGE_V`)."""
    with np.errstate(invalid='ignore'):
        bad = np.flatnonzero(np.abs(voltage) > MAX_ABS_COIL_VOLTAGE_V)
    if bad.size:
        raise _refuse_cell(table, int(bad[0]), 'coil_voltage_mean', f'V is beyond the '
                           f'plausible coil voltage range (|u| <= {MAX_ABS_COIL_VOLTAGE_V:g} V)')


def _time_notes(t: np.ndarray, nominal: float | None) -> tuple[int, list[str]]:
    """Rate agreement and gaps of a time axis; returns (number of gaps, notes)."""
    notes: list[str] = []
    if t.size < 2:
        return 0, notes
    dt = np.diff(t)
    if nominal is not None:
        actual = 1.0 / float(np.median(dt))
        if abs(actual / nominal - 1.0) > _RATE_TOLERANCE:
            notes.append(f'sample_rate_hz says {nominal:g} Hz but the time axis has '
                         f'{actual:.6g} Hz; the time axis is used')
            nominal = None
    period = 1.0 / nominal if nominal else float(np.median(dt))
    long_steps = np.flatnonzero(dt > _GAP_FACTOR * period)
    if long_steps.size == 0:
        return 0, notes
    lost = int(np.sum(np.round(dt[long_steps] / period) - 1))
    first = ', '.join(f'{t[i]:.6g} s' for i in long_steps[:5])
    more = '' if long_steps.size <= 5 else f' (and {long_steps.size - 5} more)'
    notes.append(f'{long_steps.size} gaps in the time axis (about {lost} missing samples) '
                 f'after t = {first}{more}; kept')
    return int(long_steps.size), notes


def _missing_note(table: _Table, column: str, values: np.ndarray) -> tuple[int, list[str]]:
    missing = np.flatnonzero(~np.isfinite(values))
    if missing.size == 0:
        return 0, []
    first = [int(table.linenos[i]) for i in missing[:5]]
    return int(missing.size), [
        f'{missing.size} samples without a {column} value (lines {first}'
        f'{"..." if missing.size > 5 else ""}); kept as nan']


def _unknown_note(table: _Table, known: Sequence[str]) -> list[str]:
    unknown = [c for c in table.header if c not in known]
    return [f'columns {unknown} are not part of the format; ignored'] if unknown else []


# --- the kinds ------------------------------------------------------------------------------
def _kind(table: _Table) -> str:
    """``trace``, ``operation`` or ``flow_map``, from ``experiment`` or else the header."""
    experiment = table.experiment
    if experiment == 'flow_map' or (experiment is None and 't' not in table.header
                                    and 'duty' in table.header):
        return 'flow_map'
    if experiment == 'operation':
        return 'operation'
    return 'trace'


def _trace(table: _Table) -> TraceRecord:
    _require_columns(table, _TRACE_REQUIRED, 'step/pwm')
    present = [c for c in _TRACE_REQUIRED + _TRACE_OPTIONAL if c in table.header]
    cols = _columns(table, present)
    t = cols['t']
    check_time_axis(table.path, t, table.linenos)
    _check_rate(table, t)
    _check_current(table, cols['current'])
    if 'duty' in cols:
        _check_duty(table, cols['duty'])
    n_missing, notes = _missing_note(table, 'current', cols['current'])
    for name in ('coil_voltage', 'position', 'mass_flow'):
        if name in cols:
            notes += _missing_note(table, name, cols[name])[1]
    nominal = table.numeric.get('sample_rate_hz')
    n_gaps, time_notes = _time_notes(t, nominal)
    notes += time_notes + _unknown_note(table, _TRACE_REQUIRED + _TRACE_OPTIONAL)
    return TraceRecord(
        path=table.path, experiment=table.experiment or 'unknown', t_s=t,
        voltage_v=cols['voltage'], current_a=cols['current'],
        coil_voltage_v=cols.get('coil_voltage'), position_m=cols.get('position'),
        mass_flow_kg_s=cols.get('mass_flow'), duty=cols.get('duty'),
        metadata=table.metadata, supply_pressure_pa=table.numeric.get('supply_pressure_pa'),
        output_pressure_pa=table.numeric.get('output_pressure_pa', 0.0),
        nominal_sample_rate_hz=nominal, line_numbers=np.asarray(table.linenos, dtype=int),
        notes=tuple(notes), n_missing_values=n_missing, n_gaps=n_gaps)


def _pressure(table: _Table, cols: dict[str, np.ndarray], column: str, key: str,
              default: float | None) -> np.ndarray | None:
    """A per-sample gauge pressure: the column, else the metadata value, else ``default``."""
    if column in cols:
        values = cols[column]
        bad = np.flatnonzero(values < _VACUUM_GAUGE_PA)
        if bad.size:
            raise _refuse_cell(table, int(bad[0]), column,
                               'Pa is below vacuum (pressures are gauge)')
        return values
    value = table.numeric.get(key, default)
    return None if value is None else np.full(table.linenos.size, float(value))


def _operation(table: _Table) -> OperationRecord:
    _require_columns(table, _OPERATION_REQUIRED, 'operation')
    present = [c for c in _OPERATION_REQUIRED + _OPERATION_OPTIONAL if c in table.header]
    cols = _columns(table, present)
    t, duty, freq = cols['t'], cols['duty'], cols['pwm_frequency_hz']
    check_time_axis(table.path, t, table.linenos)
    _check_rate(table, t)
    _check_current(table, cols['current'])
    _check_duty(table, duty)
    bad = np.flatnonzero(freq <= 0.0)
    if bad.size:
        raise _refuse_cell(table, int(bad[0]), 'pwm_frequency_hz', 'must be positive')
    n_missing, notes = _missing_note(table, 'current', cols['current'])
    supply = _pressure(table, cols, 'supply_pressure', 'supply_pressure_pa', None)
    output = _pressure(table, cols, 'output_pressure', 'output_pressure_pa', 0.0)
    for name in ('supply_pressure', 'output_pressure'):
        if name in cols:
            notes += _missing_note(table, name, cols[name])[1]
    v_mean = cols.get('coil_voltage_mean')
    n_missing_v = 0
    if v_mean is not None:
        _check_coil_voltage(table, v_mean)
        n_missing_v, v_notes = _missing_note(table, 'coil_voltage_mean', v_mean)
        notes += v_notes
    nominal = table.numeric.get('sample_rate_hz')
    n_gaps, time_notes = _time_notes(t, nominal)
    notes += time_notes + _unknown_note(table, _OPERATION_REQUIRED + _OPERATION_OPTIONAL)
    # At rest: duty 0 from the first sample for at least one period of the PWM in force.
    moving = np.flatnonzero(duty > 0.0)
    rest_until = t[moving[0]] if moving.size else t[-1]
    at_rest = bool(t.size and rest_until - t[0] >= 1.0 / freq[0])
    notes.append(f'assumed to start at rest (duty 0 for the first {rest_until - t[0]:.6g} s)'
                 if at_rest else 'assumed to start in motion (duty 0 for less than one PWM '
                 'period at the start)')
    return OperationRecord(
        path=table.path, t_s=t, duty=duty, pwm_frequency_hz=freq, current_a=cols['current'],
        supply_pressure_pa=supply, output_pressure_pa=output,
        supply_voltage_v=table.numeric.get('supply_voltage_v'),
        current_averaging=table.metadata.get('current_averaging', 'instantaneous'),
        starts_at_rest=at_rest,
        pressure_columns=tuple(c for c in _OPERATION_OPTIONAL if c in cols),
        metadata=table.metadata, nominal_sample_rate_hz=nominal,
        line_numbers=np.asarray(table.linenos, dtype=int), notes=tuple(notes),
        n_missing_values=n_missing, n_gaps=n_gaps, coil_voltage_mean_v=v_mean,
        n_missing_voltage=n_missing_v)


def _flow_map(table: _Table) -> FlowMapRecord:
    header, hl = table.header, table.header_line
    if 'duty' not in header:
        raise table.error(hl, f'no "duty" column (columns {header})', key='duty')
    if 't' in header:
        raise table.error(hl, 'a flow_map file has no "t" column', key='t')
    given = [c for c in _FLOW_VALUE_COLUMNS if c in header]
    if not given:
        raise table.error(hl, f'needs a "mass_flow" or "flow_fraction" column (columns '
                          f'{header})', key='mass_flow')
    if len(given) > 1:
        raise table.error(hl, 'has both "mass_flow" and "flow_fraction"; give one',
                          key='flow_fraction')
    value_col = given[0]
    cols = _columns(table, ['duty', value_col])
    duty, value = cols['duty'], cols[value_col]
    # A flow map has no measured signal that may be missing: every point is a number.
    for name, values in (('duty', duty), (value_col, value)):
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise _refuse_cell(table, int(bad[0]), name,
                               'is not finite (a flow map has no missing values)')
    _check_duty(table, duty)
    for i in range(1, duty.size):
        if duty[i] <= duty[i - 1]:
            raise _refuse_cell(table, i, 'duty', f'not above the previous row\'s '
                               f'{_cell(table, i - 1, "duty")!r} (rows must ascend)')
    bad = np.flatnonzero(value < 0.0)
    if bad.size:
        raise _refuse_cell(table, int(bad[0]), value_col, 'is negative')
    if duty.size < 2:
        raise table.error(None, f'needs at least 2 rows, has {duty.size}')
    return FlowMapRecord(
        path=table.path, duty=duty,
        mass_flow_kg_s=value if value_col == 'mass_flow' else None,
        flow_fraction=value if value_col == 'flow_fraction' else None,
        metadata=table.metadata, supply_pressure_pa=table.numeric.get('supply_pressure_pa'),
        output_pressure_pa=table.numeric.get('output_pressure_pa', 0.0),
        pwm_frequency_hz=table.numeric.get('pwm_frequency_hz'),
        supply_temperature_k=table.numeric.get('supply_temperature_k'),
        line_numbers=np.asarray(table.linenos, dtype=int),
        notes=tuple(_unknown_note(table, ('duty',) + _FLOW_VALUE_COLUMNS)))


_READERS = {'trace': _trace, 'operation': _operation, 'flow_map': _flow_map}


def read_record(path: str | os.PathLike[str]) -> Record:
    """Read a file of any kind of the measured-data format.

    Parameters
    ----------
    path : path-like

    Returns
    -------
    TraceRecord, OperationRecord or FlowMapRecord
        By the ``experiment`` key; without it, a file with ``duty`` and no ``t`` is a
        flow map and anything else a trace.

    Raises
    ------
    DataFormatError
        Naming the file, the line, the key or column and the value.
    """
    table = _split(path)
    return _READERS[_kind(table)](table)


def read_trace(path: str | os.PathLike[str]) -> TraceRecord:
    """Read a ``step`` or ``pwm`` record; any other kind is refused (see :func:`read_record`).
    """
    table = _split(path)
    kind = _kind(table)
    if kind == 'flow_map':
        raise table.error(table.header_line, 'is a flow_map file (no time trace); a step or '
                          'pwm trace with columns t, voltage, current is needed',
                          key='experiment', value=table.experiment)
    if kind == 'operation':
        raise table.error(table.meta_lines.get('experiment'), 'is an operation record; a '
                          'step or pwm trace is needed', key='experiment', value='operation')
    return _trace(table)


def read_operation(path: str | os.PathLike[str]) -> OperationRecord:
    """Read an ``operation`` record; any other kind is refused."""
    table = _split(path)
    if table.experiment != 'operation':
        raise table.error(table.meta_lines.get('experiment'), f'experiment is '
                          f'{table.experiment!r}, expected \'operation\'', key='experiment',
                          value=table.experiment)
    return _operation(table)


def read_flow_map(path: str | os.PathLike[str]) -> FlowMapRecord:
    """Read a ``flow_map`` record; any other kind is refused."""
    table = _split(path)
    if table.experiment is not None and table.experiment != 'flow_map':
        raise table.error(table.meta_lines['experiment'], f'experiment is '
                          f'{table.experiment!r}, expected \'flow_map\'', key='experiment',
                          value=table.experiment)
    return _flow_map(table)


# --- writing --------------------------------------------------------------------------------
def _known_columns(experiment: str | None) -> tuple[tuple[str, ...], tuple[str, ...]]:
    if experiment == 'operation':
        return _OPERATION_REQUIRED, _OPERATION_OPTIONAL
    if experiment == 'flow_map':
        return ('duty',), _FLOW_VALUE_COLUMNS
    return _TRACE_REQUIRED, _TRACE_OPTIONAL


def _format_value(value: object) -> str:
    text = f'{value:.10g}' if isinstance(value, float) else str(value)
    if '\n' in text or '\r' in text:
        raise ValueError(f'metadata value {text!r} spans lines')
    return text


def write_table(path: str | os.PathLike[str], metadata: Mapping[str, object],
                columns: Mapping[str, Sequence[float] | np.ndarray], *,
                precision: int = 10) -> Path:
    """Write a file of the measured-data format.

    Parameters
    ----------
    path : path-like
        Destination file (parent directories are created).
    metadata : mapping
        Written as ``# key: value`` lines in the given order; floats with ``.10g``. Its
        ``experiment`` value decides which columns are required and allowed.
    columns : mapping of str to array, each shape (n,)
        Columns in the order to write, named as in the format, values in SI units. ``nan``
        is written as an empty field, allowed in measured signals only.
    precision : int
        Significant digits of every value.

    Returns
    -------
    pathlib.Path
        The written file.

    Raises
    ------
    ValueError
        A required column is missing, a column is not part of the kind, lengths differ, a
        value other than a measured signal is not finite, or a metadata key is malformed.
    """
    experiment = metadata.get('experiment')
    if experiment is not None and experiment not in EXPERIMENTS:
        raise ValueError(f"metadata 'experiment': {experiment!r} is not one of "
                         f'{", ".join(EXPERIMENTS)}')
    required, optional = _known_columns(None if experiment is None else str(experiment))
    names = list(columns)
    missing = [c for c in required if c not in names]
    unknown = [c for c in names if c not in required + optional]
    if missing or unknown:
        raise ValueError(f'a {experiment or "step/pwm"} record needs columns {list(required)} '
                         f'and may have {list(optional)}; missing {missing}, unknown {unknown}')
    if experiment == 'flow_map' and sum(c in names for c in _FLOW_VALUE_COLUMNS) != 1:
        raise ValueError('a flow_map record has exactly one of mass_flow and flow_fraction')
    data = [np.asarray(columns[c], dtype=float) for c in names]
    n = data[0].shape
    for c, values in zip(names, data):
        if values.ndim != 1 or values.shape != n:
            raise ValueError(f'column {c!r} has shape {values.shape}, expected {n}')
        if c not in _MAY_BE_MISSING and not np.all(np.isfinite(values)):
            raise ValueError(f'column {c!r} has non-finite values; only measured signals '
                             'may lack a value')
    for key in metadata:
        if not key or ':' in key or '\n' in key or key != key.strip():
            raise ValueError(f'metadata key {key!r} cannot be written as "# key: value"')
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fmt = f'%.{int(precision)}g'
    table = np.column_stack(data) if data else np.zeros((0, 0))
    with open(out, 'w', encoding='utf-8', newline='\n') as fh:
        for key, value in metadata.items():
            fh.write(f'# {key}: {_format_value(value)}\n')
        fh.write(','.join(names) + '\n')
        if np.all(np.isfinite(table)):
            np.savetxt(fh, table, fmt=fmt, delimiter=',')
        else:
            for row in table:
                fh.write(','.join(fmt % v if math.isfinite(v) else '' for v in row) + '\n')
    return out


def write_record(path: str | os.PathLike[str], record: Record, *, precision: int = 10) -> Path:
    """Write a record (as read by :func:`read_record`) back to a file.

    The metadata is written as read; for a record whose ``experiment`` was not stated the
    columns decide, as they did when reading.
    """
    return write_table(path, record.metadata, record.columns(), precision=precision)
