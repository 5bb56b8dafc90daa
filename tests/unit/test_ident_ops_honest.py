"""No false discovery on clean data: records of the nominal valve made
by the suite's own model, at 0, 1, 3 and 10 mA of noise, are answered ``none``; steps (24 V
fit, 15 V validation from valve_simulate) and an operational record through the drive
electronics (one record: the last 30 % held out). Each is a whole close-the-loop run,
hence slow. The step runs also check that no effect outside the list is claimed."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from datagen.suite_records import suite_operation_record
from valve_model_pkg.cli.identify import main as identify_main
from valve_model_pkg.cli.simulate import main as simulate_main
from valve_model_pkg.dataformat import read_trace, write_table

import os

# Every level is a whole close-the-loop run of minutes on 2 cores: `make test` runs 0 and
# 3 mA; VALVE_FULL_IDENT_TESTS=1 runs all four within CI's budget only
# on a quiet machine.
NOISE_MA = ((0.0, 1.0, 3.0, 10.0) if os.environ.get('VALVE_FULL_IDENT_TESTS') == '1'
            else (0.0, 3.0))


def _noisy_step(tmp: Path, volts: float, noise_a: float, seed: int,
                duration_s: float = 0.04) -> Path:
    raw = tmp / f'raw{volts:g}.csv'
    assert simulate_main(['--experiment', 'step', '--voltage', f'{volts:g}', '--duration',
                          f'{duration_s:g}', '-o', str(raw), '--no-plot', '-q']) == 0
    rec = read_trace(raw)
    cur = rec.current_a + np.random.default_rng(seed).normal(0.0, noise_a, rec.t_s.size)
    return write_table(tmp / f'step{volts:g}.csv', rec.metadata,
                       {'t': rec.t_s, 'voltage': rec.voltage_v, 'current': cur})


@pytest.mark.slow
@pytest.mark.parametrize('noise_ma', NOISE_MA)
def test_clean_nominal_steps_are_answered_none(tmp_path: Path, noise_ma: float) -> None:
    # noise-free: 30 ms steps, on which the baseline misses the 15 V step by about 1 mA: a
    # resolution floor much below 1e-3 of the range reads that as leakage_inductance
    duration_s = 0.03 if noise_ma == 0.0 else 0.04
    fit = _noisy_step(tmp_path, 24.0, 1e-3 * noise_ma, 1, duration_s)
    val = _noisy_step(tmp_path, 15.0, 1e-3 * noise_ma, 2, duration_s)
    out = tmp_path / 'rep'
    assert identify_main(['--fit', str(fit), '--validate', str(val), '-o', str(out),
                          '--no-plots', '--quiet']) == 0
    rep = json.loads((out / 'report.json').read_text())
    assert rep['diagnosis']['effect'] == 'none', rep['diagnosis']['evidence']
    if noise_ma == 0.0:   # a residual below the resolution floor is not structure
        assert rep['diagnosis']['confidence'] == 'high', rep['diagnosis']['evidence']
    assert rep['baseline_convergence']['converged']
    # Nor an effect outside the list: no sparse term is claimed.
    assert rep['unlisted'] is None or not rep['unlisted']['claimed']


@pytest.mark.slow
@pytest.mark.parametrize('noise_ma', NOISE_MA)
def test_clean_nominal_operation_record_is_answered_none(
        tmp_path: Path, noise_ma: float) -> None:
    rec = suite_operation_record(tmp_path / 'ops.csv', 1e-3 * noise_ma, 3)
    out = tmp_path / 'rep'
    assert identify_main(['--fit', str(rec), '-o', str(out), '--no-plots', '--quiet',
                          '--quick']) == 0
    rep = json.loads((out / 'report.json').read_text())
    assert rep['diagnosis']['effect'] == 'none', rep['diagnosis']['evidence']
    # the suite's own model describes the record: no misfit statement
    assert rep['diagnosis']['model_misfit'] is None, rep['diagnosis']['evidence']
    assert any('held out' in n for n in rep['data_notes'])
    drive = rep['drive_electronics']
    assert drive['values']['holding_current_a'] == pytest.approx(0.5, rel=0.02)
