"""The identification's front door: ``identify``, ``IdentifySettings``, ``read_measurements``
from the package, the settings every caller builds (command line, fleet manifest), and the
refusals that come before any simulation. Fast: no identification run."""
from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import pytest

from valve_model_pkg.errors import MeasurementFormatError, ParameterError
from valve_model_pkg.identification import IdentifySettings, identify, read_measurements
from valve_model_pkg.model.parameters import EFFECTS


def test_the_front_door_names_are_the_pipelines_and_the_readers() -> None:
    from valve_model_pkg.identification import pipeline, readers
    assert identify is pipeline.identify and IdentifySettings is pipeline.IdentifySettings
    assert read_measurements is readers.read_measurements


def test_settings_are_frozen_and_check_their_names() -> None:
    s = IdentifySettings()
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.quick = True  # type: ignore[misc]
    with pytest.raises(ParameterError, match="'coil_melting'"):
        IdentifySettings(effects=('eddy_current', 'coil_melting'))
    with pytest.raises(ParameterError, match='threads'):
        IdentifySettings(threads=0)
    with pytest.raises(ParameterError, match="topic_map: 'current/coil'"):
        IdentifySettings(topic_map=('current/coil',))


def test_quick_and_seed_set_the_search_effort() -> None:
    from valve_model_pkg.identification.pipeline import (BASELINE_EFFORT,
                                                         QUICK_BASELINE_EFFORT,
                                                         QUICK_REFIT_EFFORT, REFIT_EFFORT)
    full, quick = IdentifySettings(), IdentifySettings(quick=True)
    assert full.baseline_effort(False) == BASELINE_EFFORT
    assert full.refit_effort(False) == REFIT_EFFORT
    assert quick.baseline_effort(False) == QUICK_BASELINE_EFFORT
    assert quick.refit_effort(False) == QUICK_REFIT_EFFORT
    assert quick.baseline_effort(False).global_samples < BASELINE_EFFORT.global_samples
    # records through the electronics have an effort of their own
    assert quick.baseline_effort(True) == full.operation_baseline
    assert IdentifySettings(seed=7).baseline_effort(False).seed == 7


def test_only_the_chosen_effects_are_candidates() -> None:
    from valve_model_pkg.identification.pipeline import candidates_from_scores
    scores = {e: (0.1 * k, 1.0) for k, e in enumerate(EFFECTS)}
    every = candidates_from_scores(scores, IdentifySettings())
    assert [c.effect for c in every] == list(reversed(list(EFFECTS)))   # best score first
    some = candidates_from_scores(scores, IdentifySettings(
        effects=('eddy_current', 'coulomb_friction')))
    assert [c.effect for c in some] == ['coulomb_friction', 'eddy_current']


def test_the_command_line_only_parses_into_the_settings() -> None:
    from valve_model_pkg.cli.identify import _parser, settings_from_args
    args = _parser().parse_args([
        '--fit', 'a.csv', '-o', 'out', '--params', 'p.yaml', '--quick', '--no-diagnosis',
        '--effects', 'eddy_current', 'leakage_inductance', '--seed', '3', '--threads', '1',
        '--topic', '/left/valve/state', '--valve', 'v2', '--allow-implausible'])
    assert settings_from_args(args) == IdentifySettings(
        params_file='p.yaml', allow_implausible=True, topic='/left/valve/state', valve='v2',
        diagnose=False, effects=('eddy_current', 'leakage_inductance'), quick=True, seed=3,
        threads=1)
    assert settings_from_args(_parser().parse_args(['--fit', 'a.csv', '-o', 'o'])) \
        == IdentifySettings()


def test_an_unknown_effect_on_the_command_line_exits_2(capsys: pytest.CaptureFixture) -> None:
    from valve_model_pkg.cli.identify import main
    with pytest.raises(SystemExit) as stop:
        main(['--fit', 'a.csv', '-o', 'out', '--effects', 'coil_melting'])
    assert stop.value.code == 2
    assert 'coil_melting' in capsys.readouterr().err


def test_the_fleet_builds_the_same_settings_from_a_manifest() -> None:
    from valve_model_pkg.fleet.worker import settings_from_options
    assert settings_from_options({}) == IdentifySettings()
    assert settings_from_options({'params': '/p.yaml', 'quick': True, 'diagnose': False,
                                  'topic': '/x', 'valve': 'v'}) == IdentifySettings(
        params_file='/p.yaml', quick=True, diagnose=False, topic='/x', valve='v')


def test_a_record_without_its_supply_pressure_is_refused_before_any_fit(
        tmp_path: Path) -> None:
    rec = tmp_path / 'nopress.csv'
    rec.write_text('t,voltage,current\n' + ''.join(f'{k}e-5,24,0\n' for k in range(20)),
                   encoding='utf-8')
    with pytest.raises(MeasurementFormatError, match='supply_pressure_pa'):
        identify([rec])
    with pytest.raises(MeasurementFormatError, match='supply_pressure_pa'):
        identify(read_measurements([rec]))


@pytest.mark.parametrize('env, affinity', [({'NUMBA_NUM_THREADS': '1'}, None),
                                           ({}, 1)])
def test_the_identification_keeps_to_the_threads_the_process_is_given(env, affinity) -> None:
    """A fleet worker limited to one thread (NUMBA_NUM_THREADS) or a process pinned to one
    CPU runs the identification's Python threads on one, not one per CPU of the machine."""
    if affinity is not None and not hasattr(os, 'sched_setaffinity'):
        pytest.skip('no CPU affinity on this platform')
    code = ('import os\n'
            f'if {affinity!r}: os.sched_setaffinity(0, {{min(os.sched_getaffinity(0))}})\n'
            'from valve_model_pkg.identification import IdentifySettings\n'
            'print(IdentifySettings().workers, IdentifySettings(threads=3).workers)\n')
    environ = {k: v for k, v in os.environ.items() if k != 'NUMBA_NUM_THREADS'}
    out = subprocess.run([sys.executable, '-c', code], env={**environ, **env},
                         capture_output=True, text=True, timeout=120, check=True).stdout
    assert out.split() == ['1', '3']
