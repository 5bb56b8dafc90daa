"""What valve_import cannot read it refuses: one line naming the file, the row and what was
expected, exit 2, nothing written; a missing or ambiguous channel lists the file's channels.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from datagen.exports import (
    ScopeTrace, scope_trace, write_pico_mat, write_rigol, write_tdms, write_tds_pair,
)
from valve_model_pkg.cli.import_record import main as valve_import


@pytest.fixture(scope='module')
def trace() -> ScopeTrace:
    return scope_trace(dt_s=16e-6)  # 2500 samples


def _refused(capsys: pytest.CaptureFixture, argv: list[str], out: Path) -> str:
    code = valve_import(argv + ['-o', str(out)])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith('valve_import: error: '), err
    assert 'Traceback' not in err
    assert not out.exists() and not out.with_name(out.name + '.part').exists()
    return lines[0]


def test_garbage_text_names_row_1_and_the_formats_expected(tmp_path: Path, capsys) -> None:
    path = tmp_path / 'notes.csv'
    path.write_text('dear diary\nthe valve clicked twice\n', encoding='utf-8')
    line = _refused(capsys, [str(path), '--voltage', 'CH1', '--current', 'CH2'],
                    tmp_path / 'o.csv')
    assert f'{path}:1:' in line and 'Rigol CSV' in line and 'NI TDMS' in line


def test_binary_garbage_is_refused(tmp_path: Path, capsys) -> None:
    path = tmp_path / 'scope.bin'
    path.write_bytes(np.random.default_rng(3).bytes(5000))
    line = _refused(capsys, [str(path), '--voltage', 'CH1', '--current', 'CH2'],
                    tmp_path / 'o.csv')
    assert str(path) in line and 'not an instrument export' in line


def test_a_rigol_file_cut_mid_row_names_the_row(trace: ScopeTrace, tmp_path: Path,
                                                capsys) -> None:
    path = tmp_path / 'rigol.csv'
    write_rigol(path, trace)
    text = path.read_bytes()
    cut = text.index(b'\r\n1200,') + 12
    path.write_bytes(text[:cut])
    line = _refused(capsys, [str(path), '--voltage', 'CH1', '--current', 'CH2',
                             '--current-scale', '10'], tmp_path / 'o.csv')
    # header rows 1-2, sample 0 on row 3: sample 1200 is on row 1203.
    assert f'{path}:1203:' in line and 'fields' in line


def test_a_truncated_tds_file_names_the_stated_record_length(trace: ScopeTrace,
                                                             tmp_path: Path,
                                                             capsys) -> None:
    ch1, ch2, _ = write_tds_pair(tmp_path, trace)
    lines = ch2.read_text(encoding='ascii').splitlines(keepends=True)
    ch2.write_text(''.join(lines[:1500]), encoding='ascii', newline='')
    line = _refused(capsys, [str(ch1), str(ch2), '--voltage', 'CH1', '--current', 'CH2'],
                    tmp_path / 'o.csv')
    assert f'{ch2}:1501:' in line and 'Record Length 2500' in line


def test_a_truncated_mat_file_is_refused(trace: ScopeTrace, tmp_path: Path, capsys) -> None:
    path = tmp_path / 'pico.mat'
    write_pico_mat(path, trace, version='5')
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2])
    line = _refused(capsys, [str(path), '--voltage', 'A', '--current', 'B'],
                    tmp_path / 'o.csv')
    assert str(path) in line and ('truncated' in line or 'corrupt' in line)


def test_a_truncated_tdms_file_is_refused(trace: ScopeTrace, tmp_path: Path, capsys) -> None:
    path = tmp_path / 'daq.tdms'
    write_tdms(path, trace, segment=1000)
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 3])
    code = valve_import([str(path), '--voltage', 'Measurement/Coil voltage', '--current',
                         'Measurement/Coil current', '-o', str(tmp_path / 'o.csv')])
    err = capsys.readouterr().err
    if code == 0:
        # npTDMS reads the whole segments before the cut: the record says how many.
        rec = (tmp_path / 'o.csv').read_text().splitlines()
        n = sum(1 for ln in rec if ln and not ln.startswith('#')) - 1
        assert 0 < n < trace.t_s.size
    else:
        assert code == 2 and str(path) in err and 'Traceback' not in err


def test_a_wrong_channel_lists_the_channels_of_the_file(trace: ScopeTrace, tmp_path: Path,
                                                        capsys) -> None:
    path = tmp_path / 'rigol.csv'
    write_rigol(path, trace)
    line = _refused(capsys, [str(path), '--voltage', 'CH1', '--current', 'CH3'],
                    tmp_path / 'o.csv')
    assert "current channel 'CH3' is not in the file" in line
    assert 'CH1 (Volt), CH2 (Volt)' in line


def test_an_ambiguous_channel_is_never_guessed(trace: ScopeTrace, tmp_path: Path,
                                               capsys) -> None:
    path = tmp_path / 'two_groups.tdms'
    write_tdms(path, trace, spare_group='Spare')
    line = _refused(capsys, [str(path), '--voltage', 'coil voltage', '--current',
                             'coil current'], tmp_path / 'o.csv')
    assert 'ambiguous' in line and 'Measurement/Coil current' in line \
        and 'Spare/Coil current' in line


def test_a_current_channel_in_volts_needs_its_factor(trace: ScopeTrace, tmp_path: Path,
                                                     capsys) -> None:
    path = tmp_path / 'rigol.csv'
    write_rigol(path, trace)
    line = _refused(capsys, [str(path), '--voltage', 'CH1', '--current', 'CH2'],
                    tmp_path / 'o.csv')
    assert 'current channel CH2 is in Volt' in line and '--current-scale' in line


def test_a_huge_line_is_refused_with_its_row(trace: ScopeTrace, tmp_path: Path,
                                             capsys) -> None:
    path = tmp_path / 'rigol.csv'
    write_rigol(path, trace)
    rows = path.read_bytes().split(b'\r\n')
    rows[40] = b'7' * 200_000
    path.write_bytes(b'\r\n'.join(rows))
    line = _refused(capsys, [str(path), '--voltage', 'CH1', '--current', 'CH2',
                             '--current-scale', '10'], tmp_path / 'o.csv')
    assert f'{path}:41:' in line and 'longer than' in line


def test_bytes_that_are_not_utf8_name_their_row(trace: ScopeTrace, tmp_path: Path,
                                                capsys) -> None:
    path = tmp_path / 'rigol.csv'
    write_rigol(path, trace)
    data = path.read_bytes().split(b'\r\n')
    data[100] = b'97,\xff\xfe,1.00e-02,'
    path.write_bytes(b'\r\n'.join(data))
    line = _refused(capsys, [str(path), '--voltage', 'CH1', '--current', 'CH2',
                             '--current-scale', '10'], tmp_path / 'o.csv')
    assert f'{path}:101:' in line and 'UTF-8' in line


def test_a_suite_record_is_not_imported_again(tmp_path: Path, capsys) -> None:
    path = tmp_path / 'rec.csv'
    path.write_text('# experiment: step\nt,voltage,current\n0,0,0\n1e-5,24,0.01\n',
                    encoding='utf-8')
    line = _refused(capsys, [str(path), '--voltage', 'voltage', '--current', 'current'],
                    tmp_path / 'o.csv')
    assert 'already a record of the measured-data format' in line


def test_a_capture_without_a_step_is_not_a_step_record(trace: ScopeTrace, tmp_path: Path,
                                                       capsys) -> None:
    path = tmp_path / 'rigol.csv'
    write_rigol(path, trace)
    line = _refused(capsys, [str(path), '--voltage', 'CH1', '--current', 'CH2',
                             '--current-scale', '10', '--stop', '-0.0005'],
                    tmp_path / 'o.csv')
    assert 'no voltage step in channel CH1' in line


def test_files_of_different_captures_are_not_merged(tmp_path: Path, capsys) -> None:
    a1, a2, _ = write_tds_pair(tmp_path / 'a', scope_trace(dt_s=16e-6))
    b1, b2, _ = write_tds_pair(tmp_path / 'b', scope_trace(dt_s=16e-6, pre_s=4e-3,
                                                           total_s=40e-3))
    line = _refused(capsys, [str(a1), str(b2), '--voltage', 'CH1', '--current', 'CH2'],
                    tmp_path / 'o.csv')
    assert str(b2) in line and 'not files of one capture' in line
