"""From an instrument export to the identification's report, as a user runs it.

``valve_import`` then ``valve_identify --fit F --validate F``, and ``valve_identify`` on
the exports directly, on captures of truth-model valves (tests/datagen): a clean 8-bit
Rigol record and a Tektronix TDS pair are answered ``none``, a PicoScope MATLAB v7.3
capture of a valve with eddy currents names them; the validation error stays below 3 %
NRMSE. Each test is one identification run (``--quick``, 10-40 s): marked slow.
"""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from datagen.exports import scope_trace, write_pico_mat, write_rigol, write_tds_pair
from datagen.truth import TruthValve, perturbed
from valve_model_pkg.cli.identify import main as valve_identify
from valve_model_pkg.cli.import_record import main as valve_import

pytestmark = pytest.mark.slow


def _valve(seed: int, **changes: float) -> TruthValve:
    return replace(perturbed(TruthValve(), np.random.default_rng(seed), spread=0.1),
                   **changes)


def _report(out: Path) -> dict:
    return json.loads((out / 'report.json').read_text(encoding='utf-8'))


def test_an_8bit_rigol_step_imported_then_identified_is_none(tmp_path: Path) -> None:
    tr = scope_trace(_valve(11), dt_s=10e-6, noise_a=3e-3, seed=5)
    export = tmp_path / 'NewFile1.csv'
    write_rigol(export, tr, current_lsb_a=0.016)
    record = tmp_path / 'step.csv'
    assert valve_import([str(export), '--voltage', 'CH1', '--current', 'CH2',
                         '--current-scale', '10', '--supply-pressure-pa', '4e5',
                         '-o', str(record)]) == 0
    out = tmp_path / 'report'
    assert valve_identify(['--fit', str(record), '--validate', str(record), '--out', str(out),
                           '--quick', '--no-plots', '--quiet']) == 0
    rep = _report(out)
    assert rep['diagnosis']['effect'] == 'none'
    assert rep['augmented']['validation']['nrmse_pct'] < 3.0
    # the importer's LSB reached the noise model, and the report says so
    assert rep['baseline']['sensitivity']['current_lsb_a'] == {
        'step.csv': pytest.approx(0.016, rel=0.02)}
    assert rep['baseline']['sensitivity']['quantisation_share_of_noise_variance'] > 0.3


def test_valve_identify_takes_a_tds_pair_directly(tmp_path: Path) -> None:
    tr = scope_trace(_valve(12), dt_s=16e-6, noise_a=3e-3, seed=6)
    ch1, ch2, _ = write_tds_pair(tmp_path / 'ALL0001', tr)
    out = tmp_path / 'report'
    assert valve_identify(['--fit', str(ch1), str(ch2), '--validate', str(ch1), str(ch2),
                           '--voltage', 'CH1', '--current', 'CH2',
                           '--supply-pressure-pa', '4e5', '--out', str(out), '--quick',
                           '--no-diagnosis', '--no-plots', '--quiet']) == 0
    rep = _report(out)
    assert sorted(p.name for p in (out / 'imported').iterdir()) == ['F0000CH1.csv']
    # The pair read right (scales, time axis, channels): the valve's own model fits it. The
    # answer on a clean record through an importer is the Rigol test's.
    assert rep['baseline']['validation']['nrmse_pct'] < 3.0


def test_a_picoscope_v73_capture_with_eddy_currents_names_them(tmp_path: Path) -> None:
    tr = scope_trace(_valve(13, eddy_resistance_ohm=250.0), dt_s=4e-6, noise_a=3e-3,
                     seed=7)
    export = tmp_path / 'capture.mat'
    write_pico_mat(export, tr, version='7.3')
    record = tmp_path / 'step.csv'
    assert valve_import([str(export), '--voltage', 'A', '--current', 'B',
                         '--supply-pressure-pa', '4e5', '-o', str(record)]) == 0
    out = tmp_path / 'report'
    assert valve_identify(['--fit', str(record), '--validate', str(record), '--out', str(out),
                           '--quick', '--no-plots', '--quiet']) == 0
    rep = _report(out)
    assert rep['diagnosis']['effect'] == 'eddy_current'
    assert rep['augmented']['validation']['nrmse_pct'] < 3.0
