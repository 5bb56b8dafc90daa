"""The bench loop never hands identification a step that did not happen: it checks each
recorded bag (valve_bringup.bench.check_bench_bag), records a bad step once more saying
so, and stops with one line naming the step when the second is no better.

The bags hold the independent truth model's 15 V step (tests/datagen) as the CAN driver
publishes it: 1 kHz states, duty 0/1 and the unchopped coil voltage of the bench mode.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from datagen.truth import TruthValve, simulate_truth
from suite_bags import write_bench_state_bag

from valve_bringup.bench import (BenchRecord, BenchStep, bag_gaps, check_bench_bag,
                                 record_checked_step)

RECORD = BenchRecord('validate', 15.0)
RATE_HZ = 1000.0


@pytest.fixture(scope='module')
def truth_step() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t [s], coil voltage [V], current with 2 mA noise [A]) of 0.3 s at rest, the 0.8 s
    step and 0.4 s at rest."""
    t = np.arange(int(1.5 * RATE_HZ)) / RATE_HZ
    segments = [(0.0, 0.0), (0.3, RECORD.supply_voltage_v), (0.3 + RECORD.on_s, 0.0)]
    tr = simulate_truth(TruthValve(), segments, float(t[-1]), t, 4e5)
    current = tr.current_a + np.random.default_rng(5).normal(0.0, 2e-3, t.size)
    return t, tr.voltage_cmd_v.copy(), current


def _bag(path: Path, t: np.ndarray, voltage: np.ndarray, current: np.ndarray) -> Path:
    return write_bench_state_bag(path, t, voltage, current)


def test_a_recorded_step_passes(tmp_path: Path, truth_step) -> None:
    assert check_bench_bag(RECORD, _bag(tmp_path / 'bag', *truth_step)) is None


def test_a_step_whose_current_never_came_is_named(tmp_path: Path, truth_step) -> None:
    t, v, _ = truth_step
    noise = np.random.default_rng(6).normal(0.0, 2e-3, t.size)
    problem = check_bench_bag(RECORD, _bag(tmp_path / 'bag', t, v, noise))
    assert problem is not None and 'does not respond to the 15 V step' in problem


@pytest.mark.parametrize('end_s, says', [(0.45, 'holds 0.149 s of the 0.8 s step'),
                                         (1.1, 'ends before the step does')])
def test_a_bag_cut_in_the_step_is_named(tmp_path: Path, truth_step, end_s, says) -> None:
    # the recorder stopped while the state stream still lagged behind the step
    t, v, i = truth_step
    keep = t < end_s
    assert says in check_bench_bag(RECORD, _bag(tmp_path / 'bag', t[keep], v[keep], i[keep]))


def _recorder(truth_step, bad_attempts: int, said: list):
    """A record_step that writes a bag without the current for ``bad_attempts`` calls."""
    t, v, i = truth_step

    def record_step(record, bag, effect_args):
        said.append(bag.name)
        current = np.zeros_like(i) if len(said) <= bad_attempts else i
        _bag(bag, t, v, current)
        return BenchStep(bag, None, 0.9, 0.9, 0.0, 800)
    return record_step


def test_a_bad_step_is_recorded_once_more_saying_so(tmp_path: Path, truth_step,
                                                    capsys) -> None:
    calls: list[str] = []
    bag = record_checked_step(RECORD, tmp_path, 'S', (), _recorder(truth_step, 1, calls))
    assert calls == ['bench_15V_S', 'bench_15V_S_again'] and bag.name == 'bench_15V_S_again'
    out = capsys.readouterr().out
    assert 'validate: bench_15V_S is no record of the step' in out
    assert 'recording it once more' in out


def test_two_bad_steps_stop_the_loop_naming_the_step(tmp_path: Path, truth_step) -> None:
    calls: list[str] = []
    with pytest.raises(RuntimeError) as info:
        record_checked_step(RECORD, tmp_path, 'S', (), _recorder(truth_step, 2, calls))
    assert len(calls) == 2
    text = str(info.value)
    assert text.startswith('bench step validate (15 V) not recorded twice: bench_15V_S_again')
    assert '\n' not in text


def test_a_step_the_state_never_showed_is_recorded_again(tmp_path: Path, truth_step) -> None:
    t, v, i = truth_step
    calls: list[str] = []

    def record_step(record, bag, effect_args):
        calls.append(bag.name)
        _bag(bag, t, v, i)
        return BenchStep(bag, 'the valve state did not show the step' if len(calls) == 1
                         else None, 20.0, 0.0, 0.0, 0)
    assert record_checked_step(RECORD, tmp_path, 'S', (), record_step).name.endswith('_again')


def test_the_instants_a_controller_skipped_are_said(tmp_path: Path, truth_step) -> None:
    t, v, i = truth_step
    assert bag_gaps(_bag(tmp_path / 'whole', t, v, i)).endswith('no gap')
    keep = np.ones(t.size, bool)
    keep[400:430] = False           # 30 states lost: a 31 ms gap
    keep[900:905] = False           # 5 lost: 6 ms
    said = bag_gaps(_bag(tmp_path / 'gappy', t[keep], v[keep], i[keep]))
    assert said == '1465 states 1 ms apart, 2 gaps (largest 31 ms, 35 ms of states missing in all)'
