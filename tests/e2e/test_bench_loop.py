"""The loop through the bench (README): CAN backend with an injected effect -> recorded bags
-> valve_identify names the effect -> the identified parameters drive the model again."""
from __future__ import annotations

import json
import os
import subprocess

import pytest

pytestmark = [pytest.mark.e2e, pytest.mark.slow]


def test_bench_loop_names_the_injected_effect_and_improves_the_error(tmp_path):
    out = tmp_path / 'bench'
    proc = subprocess.run(['valve_bench_loop', '--effect', 'coil_heating', '--quick',
                           '--out', str(out)], capture_output=True, text=True, timeout=1500,
                          env=dict(os.environ))
    text = proc.stdout + proc.stderr
    assert proc.returncode == 0, text[-5000:]
    report = json.loads((out / 'identification' / 'report.json').read_text())
    assert report['diagnosis']['effect'] == 'coil_heating', report['diagnosis']
    base, aug = report['baseline'], report['augmented']
    assert aug['validation']['iae'] < 0.5 * base['validation']['iae']
    assert aug['fit']['iae'] < base['fit']['iae']
    # The recorded bags came through the CAN driver.
    assert len(list(out.glob('bench_24V_*/metadata.yaml'))) == 1
    assert 'diagnosis: coil_heating' in text
    assert (out / 'step24_identified.csv').exists()
    assert (out / 'map_identified.json').exists()
    assert 'valve_simulator with the identified parameters: started and stopped cleanly' in text
