"""Text exports read with bounded memory: numbered header lines, data rows in blocks.

Header lines are read one at a time (at most :data:`MAX_LINE_CHARS` each); the data rows
are read in blocks of about 4 MiB and parsed by numpy's C parser, keeping only the
columns asked for. Every refusal names the file's row: a line too long, bytes that are not
UTF-8, a blank row inside the data, a field that is not a number, a row that is short.
"""
from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import InstrumentFormatError
from .capture import MAX_SAMPLES

__all__ = ['MAX_LINE_CHARS', 'TextFile', 'Columns', 'header_fields', 'is_number',
           'read_columns', 'split_fields']

#: Longest line read [bytes]; instrument exports have lines of a few dozen characters.
MAX_LINE_CHARS = 1 << 16
_BLOCK_BYTES = 4 << 20
_INFINITY = re.compile('[-+]?\u221e')


def split_fields(line: str, delimiter: str) -> list[str]:
    """Fields of a line, stripped (no quoting: instrument exports use none)."""
    return [f.strip().strip('"') for f in line.split(delimiter)]


def header_fields(line: str, delimiter: str) -> list[str]:
    """Fields of a header row without the empty ones at its end (a row ending in the
    delimiter, as Rigol and Keysight write them)."""
    fields = split_fields(line, delimiter)
    while fields and fields[-1] == '':
        fields.pop()
    return fields


def is_number(text: str) -> bool:
    """True when ``text`` reads as a float."""
    try:
        float(text)
    except ValueError:
        return False
    return True


def read_columns(path: str, skip: int, usecols: Sequence[int], *, delimiter: str,
                 n_fields: int, expected: str) -> 'Columns':
    """The data rows of a text export whose header is its first ``skip`` lines.

    Parameters
    ----------
    path : str
    skip : int
        Header lines before the first data row.
    usecols, delimiter, n_fields, expected
        As :meth:`TextFile.columns`.

    Raises
    ------
    InstrumentFormatError
        As :meth:`TextFile.columns`, naming the row.
    """
    with TextFile(path) as f:
        for _ in range(skip):
            f.readline()
        return f.columns(usecols, delimiter=delimiter, n_fields=n_fields, expected=expected)


@dataclass(frozen=True)
class Columns:
    """Parsed data rows: one float64 array per asked column, and where they came from.

    Attributes
    ----------
    values : list of numpy.ndarray, shape (n,)
        In the order the columns were asked.
    first_row : int
        File row of the first sample.
    n_over_range : list of int
        Infinity signs (PicoScope's over-range) per column, parsed as ``inf``.
    """

    values: list[np.ndarray]
    first_row: int
    n_over_range: list[int]


class TextFile:
    """A text export opened for reading: header lines first, then the data rows.

    Parameters
    ----------
    path : str
    """

    def __init__(self, path: str) -> None:
        self.path = path
        self._fh = open(path, 'rb')  # noqa: SIM115 - closed by close()/the context
        self.row = 0

    def __enter__(self) -> 'TextFile':
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._fh.close()

    def error(self, row: int | None, reason: str) -> InstrumentFormatError:
        return InstrumentFormatError(self.path, row, reason)

    def readline(self) -> str | None:
        """The next line without its end, or ``None`` at the end of the file."""
        raw = self._fh.readline(MAX_LINE_CHARS + 2)
        if not raw:
            return None
        self.row += 1
        too_long = len(raw) == MAX_LINE_CHARS + 2 or (
            len(raw) == MAX_LINE_CHARS + 1 and not raw.endswith(b'\n'))
        if too_long:
            raise self.error(self.row, f'line is longer than {MAX_LINE_CHARS} characters; '
                             'expected a line of an instrument export')
        return self._decode(raw, self.row).rstrip('\r\n')

    def _decode(self, raw: bytes, row: int) -> str:
        if b'\x00' in raw:
            raise self.error(row, 'has a NUL byte: binary data where text was expected')
        try:
            return raw.decode('utf-8-sig' if row == 1 else 'utf-8')
        except UnicodeDecodeError as err:
            raise self.error(row, f'is not UTF-8 text (byte 0x{raw[err.start]:02x} at column '
                             f'{err.start + 1})') from err

    def columns(self, usecols: Sequence[int], *, delimiter: str, n_fields: int,
                expected: str, max_rows: int | None = None) -> Columns:
        """Parse the remaining rows, keeping the fields ``usecols`` (0-based).

        Parameters
        ----------
        usecols : sequence of int
        delimiter : str
        n_fields : int
            Fewest fields a row must have (for the message of a short row).
        expected : str
            What a row should look like, for messages (``'time,CH1,CH2'``).
        max_rows : int, optional
            Stop after this many rows (a stated record length); rows after it are refused.

        Raises
        ------
        InstrumentFormatError
            Naming the row: a field that is not a number, a short row, a blank row before
            more data, a line too long, more than :data:`MAX_SAMPLES` rows.
        """
        first = self.row + 1
        parts: list[np.ndarray] = []
        over = [0] * len(usecols)
        rest = b''
        n_rows = 0
        blank_at: int | None = None
        while True:
            block = self._fh.read(_BLOCK_BYTES)
            data = rest + block
            if not data:
                break
            if block:
                cut = data.rfind(b'\n')
                if cut < 0:
                    if len(data) > MAX_LINE_CHARS:
                        raise self.error(self.row + 1, f'line is longer than {MAX_LINE_CHARS} '
                                         f'characters; expected rows like {expected!r}')
                    rest = data
                    continue
                data, rest = data[:cut + 1], data[cut + 1:]
            else:
                rest = b''
            lines = self._lines(data, expected)
            start_row = self.row + 1
            self.row += len(lines)
            lines, blank_at = self._drop_blank(lines, start_row, blank_at)
            if not lines:
                continue
            if max_rows is not None and n_rows + len(lines) > max_rows:
                k = max_rows - n_rows
                extra = start_row + (k if blank_at is None else k)
                raise self.error(extra, f'more rows than the {max_rows} the file states')
            n_rows += len(lines)
            if n_rows > MAX_SAMPLES:
                raise self.error(start_row + len(lines) - 1, f'more than {MAX_SAMPLES} samples; '
                                 'export fewer points or a shorter window')
            parts.append(self._parse(lines, start_row, usecols, delimiter, n_fields,
                                     expected, over))
            if not block:
                break
        if not parts:
            raise self.error(None, f'has no data rows (expected rows like {expected!r})')
        table = np.concatenate(parts) if len(parts) > 1 else parts[0]
        return Columns([np.ascontiguousarray(table[:, j]) for j in range(len(usecols))],
                       first, over)

    def _lines(self, data: bytes, expected: str) -> list[str]:
        lines = data.split(b'\n')
        if lines and lines[-1] == b'':
            lines.pop()
        longest = max(map(len, lines)) if lines else 0
        if longest > MAX_LINE_CHARS:
            k = next(i for i, ln in enumerate(lines) if len(ln) > MAX_LINE_CHARS)
            raise self.error(self.row + 1 + k, f'line is longer than {MAX_LINE_CHARS} '
                             f'characters; expected rows like {expected!r}')
        try:
            text = data.decode('utf-8')
        except UnicodeDecodeError:
            for k, ln in enumerate(lines):
                self._decode(ln, self.row + 1 + k)
            raise
        if '\x00' in text:
            k = next(i for i, ln in enumerate(lines) if b'\x00' in ln)
            raise self.error(self.row + 1 + k, 'has a NUL byte: binary data where text was '
                             'expected')
        text = text.replace('\r', '')
        if '\u221e' in text:
            text = _INFINITY.sub(lambda m: m.group(0).replace('\u221e', 'inf'), text)
        out = text.split('\n')
        if out and out[-1] == '':
            out.pop()
        return out

    def _drop_blank(self, lines: list[str], start_row: int, blank_at: int | None
                    ) -> tuple[list[str], int | None]:
        """Blank rows are allowed only at the end of the file."""
        blanks = [i for i, ln in enumerate(lines) if not ln.strip()]
        if blank_at is not None and len(blanks) < len(lines):
            k = next(i for i, ln in enumerate(lines) if ln.strip())
            raise self.error(blank_at, f'blank row inside the data (row {start_row + k} has '
                             'more data)')
        if not blanks:
            return lines, blank_at
        first_blank = blanks[0]
        if any(ln.strip() for ln in lines[first_blank:]):
            k = next(i for i in range(first_blank, len(lines)) if lines[i].strip())
            raise self.error(start_row + first_blank, f'blank row inside the data (row '
                             f'{start_row + k} has more data)')
        return lines[:first_blank], start_row + first_blank

    def _parse(self, lines: list[str], start_row: int, usecols: Sequence[int],
               delimiter: str, n_fields: int, expected: str, over: list[int]) -> np.ndarray:
        try:
            table = np.loadtxt(lines, delimiter=delimiter, usecols=tuple(usecols), ndmin=2,
                               dtype=np.float64, comments=None)
        except ValueError:
            self._find_bad_row(lines, start_row, usecols, delimiter, n_fields, expected)
            raise
        if table.shape[0] != len(lines):
            self._find_bad_row(lines, start_row, usecols, delimiter, n_fields, expected)
        inf = np.isinf(table)
        if inf.any():
            for j, count in enumerate(inf.sum(axis=0)):
                over[j] += int(count)
        return table

    def _find_bad_row(self, lines: list[str], start_row: int, usecols: Sequence[int],
                      delimiter: str, n_fields: int, expected: str) -> None:
        for k, line in enumerate(lines):
            fields = line.split(delimiter)
            row = start_row + k
            if len(fields) < n_fields or len(fields) <= max(usecols):
                raise self.error(row, f'has {len(fields)} fields, expected {n_fields} like '
                                 f'{expected!r} (a truncated or mixed file?): {line[:80]!r}')
            for j in usecols:
                try:
                    float(fields[j])
                except ValueError:
                    raise self.error(row, f'field {j + 1} {fields[j].strip()[:40]!r} is not a '
                                     f'number; expected rows like {expected!r}') from None
        raise self.error(start_row, f'rows could not be parsed as {expected!r}')
