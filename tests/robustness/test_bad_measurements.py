"""Bad measured-data files: a clear refusal at once, bounded memory.

A 1 GB file is refused before it is read (size limit, tested with a sparse file), a binary
file at its first bytes, a time axis in ms, a current beyond the sensor's range and a
record without excitation are refused naming the line or the file, before any fitting.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from valve_model_pkg import dataformat
from valve_model_pkg.dataformat import DataFormatError, read_record
from valve_model_pkg.errors import MeasurementFormatError
from valve_model_pkg.identification.csv_reader import read_csv

HEAD = ('# experiment: step\n# supply_pressure_pa: 400000\n# sample_rate_hz: 50000\n'
        't,voltage,current\n')

#: The memory bound for a 1 GB input [bytes].
MEMORY_BOUND = 1.5e9


def _rows(n: int = 40, dt: float = 2e-5, current=lambda k: 0.01 * k,
          voltage: float = 24.0) -> str:
    return ''.join(f'{k * dt:.9g},{voltage},{current(k):.6g}\n' for k in range(n))


def _write(tmp_path: Path, text: str | bytes, name: str = 'm.csv') -> Path:
    path = tmp_path / name
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text, encoding='utf-8')
    return path


def _run_measured(argv: list[str]) -> tuple[int, str, int]:
    """Run a command; (exit status, stderr, peak resident memory [bytes])."""
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            stdin=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    stderr = proc.stderr.read().decode('utf-8', 'replace')
    proc.stderr.close()
    proc.returncode = os.waitstatus_to_exitcode(status)
    return proc.returncode, stderr, usage.ru_maxrss * 1024


def test_a_1_gb_file_of_nul_bytes_is_refused_at_once_with_bounded_memory(
        tmp_path: Path) -> None:
    path = tmp_path / 'nul.csv'
    with open(path, 'wb') as fh:
        fh.truncate(1 << 30)  # sparse: 1 GiB of NUL bytes without writing them
    with pytest.raises(DataFormatError) as info:
        read_record(path)
    assert f'read up to {dataformat.MAX_FILE_BYTES} bytes' in str(info.value)
    script = shutil.which('valve_identify')
    assert script, 'source ros2_ws/env.bash'
    start = time.monotonic()
    code, stderr, peak = _run_measured([script, '--fit', str(path), '-o',
                                        str(tmp_path / 'out'), '--quick'])
    elapsed = time.monotonic() - start
    print(f'valve_identify on 1 GiB of NUL bytes: exit {code}, {elapsed:.2f} s, peak '
          f'{peak / 1e6:.0f} MB')
    assert code == 2 and 'Traceback' not in stderr
    # The command line looks at the first bytes before any reader: NUL bytes are no
    # instrument export and no record, said in one line naming the file and the bytes.
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, stderr
    assert lines[0].startswith(f'valve_identify: error: {path}: not an instrument export')
    assert 'binary' in lines[0] and '\\x00' in lines[0]
    assert peak < MEMORY_BOUND
    assert elapsed < 20.0


def test_a_small_binary_file_is_refused_at_its_first_bytes(tmp_path: Path) -> None:
    path = _write(tmp_path, b'\x00' * (4 << 20))
    with pytest.raises(DataFormatError, match=r'binary file.*NUL byte at offset 0'):
        read_record(path)
    # NUL bytes after a valid start are refused at their line
    path = _write(tmp_path, (HEAD + _rows(5000)).encode() + b'\x00' * 100, 'late.csv')
    with pytest.raises(DataFormatError) as info:
        read_record(path)
    assert info.value.line == 5005 and 'NUL byte' in str(info.value)


def test_streaming_read_keeps_memory_near_the_data(tmp_path: Path) -> None:
    """50 000 rows are read into float arrays, not held as text or Python objects."""
    import tracemalloc
    n = 50_000
    path = _write(tmp_path, HEAD + _rows(n, current=lambda k: 0.5))
    size = path.stat().st_size
    tracemalloc.start()
    rec = read_record(path)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert rec.t_s.size == n
    # the parsed columns (t, voltage, current, line numbers: 32 B a row) plus a bounded
    # overhead; reading the whole text into Python objects took about 20 x the file size
    assert peak < 32 * n + (4 << 20), (peak, size)


def test_time_in_ms_is_refused_naming_line_spacing_and_expected(tmp_path: Path) -> None:
    path = _write(tmp_path, HEAD + _rows(40, dt=2e-2))  # ms written as s: 1000 x too slow
    with pytest.raises(DataFormatError) as info:
        read_record(path)
    err = info.value
    assert err.line == 6 and err.key == 't'
    assert '0.02 s after the previous row' in err.reason and '2e-05 s' in err.reason
    # a moderate disagreement is kept, with a note (the time axis is used)
    ok = read_record(_write(tmp_path, HEAD + _rows(40, dt=2.5e-5), 'ok.csv'))
    assert any('sample_rate_hz says' in n for n in ok.notes)


def test_a_current_beyond_the_sensor_range_is_refused_naming_the_line(tmp_path: Path) -> None:
    path = _write(tmp_path, HEAD + _rows(40, current=lambda k: 1e6 if k == 17 else 0.2))
    with pytest.raises(DataFormatError) as info:
        read_record(path)
    assert info.value.line == 5 + 17 and info.value.key == 'current'
    assert "'1e+06'" in str(info.value) and '50 A' in str(info.value)
    assert dataformat.MAX_ABS_CURRENT_A == 50.0


def test_a_record_without_excitation_is_refused_before_fitting(tmp_path: Path) -> None:
    path = _write(tmp_path, HEAD + _rows(400, voltage=0.0, current=lambda k: 0.0))
    with pytest.raises(MeasurementFormatError, match='no excitation: the coil voltage is 0 V'):
        read_csv(path)  # the reader refuses it: nothing is simulated or fitted


def test_non_utf8_bytes_are_refused_naming_the_line(tmp_path: Path) -> None:
    path = _write(tmp_path, (HEAD + _rows(10)).encode() + b'1e-3,24,0.5\xe9\n')
    with pytest.raises(DataFormatError) as info:
        read_record(path)
    assert info.value.line == 15 and 'not UTF-8' in str(info.value)


def test_limits_on_lines_columns_and_rows(tmp_path: Path, monkeypatch) -> None:
    wide = _write(tmp_path, 'c,' * 1_000_000 + 'c\n', 'wide.csv')  # 1e6 columns, one line
    with pytest.raises(DataFormatError, match='longer than'):
        read_record(wide)
    many = _write(tmp_path, ','.join(f'c{i}' for i in range(2000)) + '\n', 'many.csv')
    with pytest.raises(DataFormatError, match='2000 columns'):
        read_record(many)
    from valve_model_pkg.dataformat import csv_format as csv_module
    monkeypatch.setattr(csv_module, 'MAX_ROWS', 30)
    with pytest.raises(DataFormatError, match='more than 30 data rows'):
        read_record(_write(tmp_path, HEAD + _rows(40), 'rows.csv'))


def test_good_files_still_read_alike(tmp_path: Path) -> None:
    path = _write(tmp_path, HEAD + _rows(40, current=lambda k: 0.01 * k))
    rec = read_record(path)
    np.testing.assert_allclose(rec.current_a, 0.01 * np.arange(40))
    np.testing.assert_array_equal(rec.line_numbers, np.arange(5, 45))
    assert read_csv(path).n_samples == 40
