"""Coil heating named from an operational record through the drive electronics (the bench
loop's checker chooses the effect). The heating shows in the current only in the boost
and release phases of each PWM period, and a time constant of seconds is longer than the
0.4 s search window: the refit scans amount and time constant jointly on the fit window
(diagnosis.effect_scan, slow_effect): a search window alone answers such records by chance.
A whole close-the-loop run: slow."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from datagen.suite_records import suite_operation_record
from valve_model_pkg.cli.identify import main as identify_main
from valve_model_pkg.model import load_parameters

R_TH_K_PER_W, TAU_S = 40.0, 3.0   # the loop's coil (operation_loop.OPERATION_EFFECT_PARAMS)


@pytest.mark.slow
def test_coil_heating_through_the_electronics_is_named(tmp_path: Path) -> None:
    truth = load_parameters().replace(thermal_resistance_k_per_w=R_TH_K_PER_W,
                                      thermal_time_constant_s=TAU_S)
    rec = suite_operation_record(tmp_path / 'ops.csv', 3e-3, 5, duration_s=2.5,
                                 params=truth)
    out = tmp_path / 'rep'
    assert identify_main(['--fit', str(rec), '-o', str(out), '--no-plots', '--quiet',
                          '--quick']) == 0
    rep = json.loads((out / 'report.json').read_text())
    diag = rep['diagnosis']
    assert diag['effect'] == 'coil_heating', diag['evidence']
    assert rep['augmented']['validation']['iae'] < 0.5 * rep['baseline']['validation']['iae']
    # A 1 s fit window pins the heating's initial slope (R_th P / tau), not R_th and tau
    # apart: the ratio within a third of the truth's
    found = next(c for c in diag['candidates'] if c['effect'] == 'coil_heating')
    ratio = (found['extra_parameters']['thermal_resistance_k_per_w']
             / found['extra_parameters']['thermal_time_constant_s'])
    assert ratio == pytest.approx(R_TH_K_PER_W / TAU_S, rel=0.33)
    # ... and the report says so: the effect's intervals, and its weak direction
    md = (out / 'report.md').read_text()
    rows = [ln for ln in md.splitlines() if ln.startswith('| thermal_')]
    assert len(rows) == 2 and all('% (augmented)' in ln for ln in rows), rows
    assert any('augmented model, weak direction' in ln and 'thermal_time_constant_s' in ln
               for ln in md.splitlines()), md
