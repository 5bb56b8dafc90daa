"""valve_import reads each instrument's export as the instrument writes it.

The files come from tests/datagen/exports.py: the truth model's step response on a scope's
clock (2 ms pre-trigger), quantised and printed as each instrument does. Each import is
read back with the measured-data format's reader and compared with what the scope saw:
times exactly (n x interval, shifted so the record starts at 0), voltage and current
within half an LSB plus the file's print rounding.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from datagen.exports import (
    WRITERS, ScopeTrace, scope_trace, write_pico_csv, write_pico_mat, write_tds_pair,
)
from valve_model_pkg import dataformat
from valve_model_pkg.cli.import_record import main as valve_import
from valve_model_pkg.instruments import open_export


@pytest.fixture(scope='module')
def base() -> ScopeTrace:
    """The paper's valve, 24 V step, on a 2 us clock (40 ms, 2 ms pre-trigger)."""
    return scope_trace(dt_s=2e-6)


@pytest.fixture(scope='module')
def exports(base: ScopeTrace, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Each format written once: key -> (path, trace it holds, lsbs, voltage ch, current ch,
    extra options)."""
    d = tmp_path_factory.mktemp('exports')
    out = {}
    for key, (writer, step, vch, ich, extra) in WRITERS.items():
        tr = base.every(step)
        path = d / f'{key}.export'
        lsbs = writer(path, tr)
        out[key] = (path, tr, lsbs, vch, ich, extra)
    for version in ('4', '7.3'):
        path = d / f'pico{version}.mat'
        lsbs = write_pico_mat(path, base, version=version)
        out[f'picoscope-mat-v{version}'] = (path, base, lsbs, 'a', 'channel b', [])
    tab = d / 'pico.txt'
    out['picoscope-text'] = (tab, base.every(4), write_pico_csv(tab, base.every(4), tab=True),
                             'A', 'B', [])
    return out


def _import(paths: list[Path], vch: str, ich: str, out: Path, *extra: str) -> int:
    return valve_import([str(p) for p in paths] + ['--voltage', vch, '--current', ich,
                                                   '-o', str(out), '--decimate', '1',
                                                   '--supply-pressure-pa', '4e5', *extra])


#: Print rounding of each format's values beyond its LSB [V, A]: Rigol prints 3
#: significant digits (0.005 x 24 V; 0.5 mV of clamp output = 5 mA); the others print 6
#: or more (the relative term below).
_PRINT = {'rigol': (0.05, 0.005)}
_PRINT_RELATIVE = 5e-6


@pytest.mark.parametrize('key', ['tektronix-mso', 'rigol', 'keysight', 'picoscope-csv',
                                 'picoscope-mat', 'picoscope-mat-v4', 'picoscope-mat-v7.3',
                                 'picoscope-text', 'tdms', 'plain-csv'])
def test_each_format_imports_times_units_and_values(key: str, exports: dict,
                                                    tmp_path: Path) -> None:
    path, tr, lsbs, vch, ich, extra = exports[key]
    out = tmp_path / 'record.csv'
    assert _import([path], vch, ich, out, *extra) == 0
    rec = dataformat.read_trace(out)
    assert rec.experiment == 'step' and rec.supply_pressure_pa == 4e5
    np.testing.assert_allclose(rec.t_s, tr.t_s - tr.t_s[0], rtol=0, atol=1e-12)
    pv, pi = _PRINT.get(key, (0.0, 0.0))
    tol_v = 0.5 * lsbs['voltage'] + pv + _PRINT_RELATIVE * np.abs(tr.voltage_v) + 1e-9
    tol_i = 0.5 * lsbs['current'] + pi + _PRINT_RELATIVE * np.abs(tr.current_a) + 1e-9
    assert np.all(np.abs(rec.voltage_v - tr.voltage_v) <= tol_v)
    assert np.all(np.abs(rec.current_a - tr.current_a) <= tol_i)
    meta = rec.metadata
    assert meta['time_offset_s'] == f'{-tr.t_s[0]:.10g}'
    assert float(meta['step_time_s']) == pytest.approx(tr.pre_s, abs=1e-12)
    assert float(meta['step_time_in_file_s']) == pytest.approx(0.0, abs=1e-12)
    assert meta['source_files'] == str(path)
    assert float(meta['sample_rate_hz']) == pytest.approx(1.0 / tr.dt_s, rel=1e-9)


def test_a_tds_pair_is_one_capture_named_by_its_source_rows(tmp_path: Path) -> None:
    tr = scope_trace(dt_s=16e-6)  # 2500 points over 40 ms, as a TDS2000 at 4 ms/div
    ch1, ch2, lsbs = write_tds_pair(tmp_path / 'ALL0000', tr)
    out = tmp_path / 'tds.csv'
    # Given in either order, channels named as the file names them or by number.
    assert _import([ch2, ch1], 'ch1', '2', out) == 0
    rec = dataformat.read_trace(out)
    np.testing.assert_allclose(rec.t_s, np.arange(2500) * 16e-6, rtol=0, atol=1e-12)
    assert np.max(np.abs(rec.current_a - tr.current_a)) <= 0.5 * lsbs['current'] + 1e-9
    assert np.max(np.abs(rec.voltage_v - tr.voltage_v)) <= 0.5 * lsbs['voltage'] + 1e-9
    assert rec.metadata['instrument'] == 'Tektronix TDS2024B'
    assert rec.metadata['current_unit_in_file'] == 'A'
    assert set(rec.metadata['source_files'].split(', ')) == {str(ch1), str(ch2)}
    # The LSB the 8-bit scope gives (0.5 A/div / 25) is found in the samples.
    assert float(rec.metadata['current_lsb_a']) == pytest.approx(lsbs['current'], rel=1e-6)


def test_the_8bit_rigol_current_lsb_is_in_the_header(exports: dict, tmp_path: Path) -> None:
    path, tr, lsbs, vch, ich, extra = exports['rigol']
    out = tmp_path / 'rigol.csv'
    assert _import([path], vch, ich, out, *extra) == 0
    meta = dataformat.read_trace(out).metadata
    assert 0.010 <= lsbs['current'] <= 0.020
    # 3 printed digits round the clamp's volts, so the grid is found to print precision.
    assert float(meta['current_lsb_a']) == pytest.approx(lsbs['current'], rel=0.02)
    assert 'inferred from the samples' in meta['current_lsb_source']


def test_unquantised_samples_state_no_lsb(exports: dict, tmp_path: Path) -> None:
    path, tr, lsbs, vch, ich, extra = exports['plain-csv']
    out = tmp_path / 'plain.csv'
    assert _import([path], vch, ich, out) == 0
    meta = dataformat.read_trace(out).metadata
    assert 'current_lsb_a' not in meta
    assert meta['current_resolution'] == 'no quantisation grid found in the samples'


@pytest.mark.parametrize('key', ['tektronix-mso', 'rigol', 'keysight', 'picoscope-csv',
                                 'picoscope-mat-v7.3', 'tdms', 'plain-csv'])
def test_detection_reads_the_content_not_the_name(key: str, exports: dict,
                                                  tmp_path: Path) -> None:
    path = exports[key][0]
    renamed = tmp_path / 'capture_from_tuesday.txt'
    shutil.copyfile(path, renamed)
    assert open_export(renamed).format == key.removesuffix('-v7.3')
    misleading = tmp_path / 'looks_like.tdms'
    shutil.copyfile(path, misleading)
    assert open_export(misleading).format == key.removesuffix('-v7.3')


def test_picoscope_over_range_current_is_a_missing_value(base: ScopeTrace,
                                                         tmp_path: Path) -> None:
    tr = base.every(4)
    path = tmp_path / 'pico.csv'
    write_pico_csv(path, tr, over_range_at=1200)
    out = tmp_path / 'pico_rec.csv'
    assert _import([path], 'A', 'B', out) == 0
    rec = dataformat.read_trace(out)
    assert np.isnan(rec.current_a[1200]) and rec.n_missing_values == 1
    assert 'over range' in rec.metadata['import_note_1']


def test_window_and_auto_decimation_keep_the_step(exports: dict, tmp_path: Path) -> None:
    path, tr, lsbs, vch, ich, extra = exports['tektronix-mso']  # 2 us, 20 000 samples
    out = tmp_path / 'mso.csv'
    assert valve_import([str(path), '--voltage', vch, '--current', ich, '-o', str(out),
                         '--start', '-0.001', '--stop', '0.03']) == 0
    rec = dataformat.read_trace(out)
    meta = rec.metadata
    # auto: 20 us is below the current's rise / 100, so 10 samples of 2 us per block.
    assert meta['decimation'].startswith('10 (auto')
    assert meta['window'].startswith('file time -0.001 s to 0.03 s')
    assert float(meta['time_offset_s']) == pytest.approx(0.001)
    assert float(meta['step_time_s']) == pytest.approx(0.001, abs=1e-12)
    # Block means stamped at the block centre: (k * 10 + 4.5) x 2 us after -1 ms.
    n = rec.t_s.size
    np.testing.assert_allclose(rec.t_s, (np.arange(n) * 10 + 4.5) * 2e-6, atol=1e-12)
    assert n == (15_500 + 1) // 10
    first = tr.t_s.searchsorted(-0.001)
    block = tr.current_a[first:first + n * 10].reshape(n, 10).mean(axis=1)
    assert np.max(np.abs(rec.current_a - block)) <= 0.5 * lsbs['current'] + 1e-9
