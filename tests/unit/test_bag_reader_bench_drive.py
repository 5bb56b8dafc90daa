"""A bench bag (duty 0/1, the coil voltage unchopped) drives the bare coil with the states'
``coil_voltage_mean`` when every message carries it: the switch instants between two
1 kHz messages are placed from the means, and the valve that made the bag is reproduced
to the recorded resolution. Without the mean the sampled voltage is held from one message
to the next, and the reader says so.

The bag's valve is the suite's own model (the emulator runs it), switched at instants that
fall between messages, as a controller's command does.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from suite_bags import write_bench_state_bag

from valve_model_pkg.identification.bag_reader import read_bag
from valve_model_pkg.identification.model_adapter import prepare_trace, simulate_measurement
from valve_model_pkg.model import InputTrace, load_parameters, simulate_trace_batch

RATE_HZ = 1000.0
SUPPLY_V = 15.0
#: Switch on and off between two messages (0.4 ms after one).
ON_S, OFF_S = 0.3004, 1.1004


def _mean_voltage(t: np.ndarray) -> np.ndarray:
    """Exact mean of the step over each message's interval (t[k] - 1 ms, t[k]]."""
    begin = t - 1.0 / RATE_HZ
    on = np.clip(np.minimum(t, OFF_S) - np.maximum(begin, ON_S), 0.0, None)
    return SUPPLY_V * on * RATE_HZ


@pytest.fixture(scope='module')
def step() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t [s], sampled coil voltage [V], coil current [A]) of the suite's valve."""
    t = np.arange(int(1.5 * RATE_HZ)) / RATE_HZ
    trace = InputTrace.coil_voltage([0.0, ON_S, OFF_S], [0.0, SUPPLY_V, 0.0],
                                    supply_pressure_pa=4e5, output_pressure_pa=0.0)
    sim = simulate_trace_batch(load_parameters(), trace, t)
    v_sampled = np.where((t >= ON_S) & (t < OFF_S), SUPPLY_V, 0.0)
    return t, v_sampled, np.atleast_2d(sim.coil_current_a)[0]


def _bag(path: Path, t: np.ndarray, v: np.ndarray, i: np.ndarray, v_mean: np.ndarray,
         lost: np.ndarray | None = None) -> Path:
    kept = np.ones(t.size, dtype=bool) if lost is None else ~lost
    return write_bench_state_bag(path, t[kept], v[kept], i[kept], v_mean[kept],
                                 sequence=np.flatnonzero(kept))


def _misfit_a(m, truth_a: np.ndarray) -> float:
    current, _ = simulate_measurement(load_parameters().to_vector()[None, :], prepare_trace(m))
    return float(np.nanmax(np.abs(current[0] - truth_a)))


def test_the_mean_voltage_places_the_edges_and_reproduces_the_valve(tmp_path, step) -> None:
    t, v, i = step
    m = read_bag(_bag(tmp_path / 'bag', t, v, i, _mean_voltage(t)))
    assert m.voltage_hold == 'interval_mean'
    assert any('coil_voltage_mean held over each interval' in n for n in m.notes), m.notes
    seg_t = prepare_trace(m).seg_t0_s
    assert np.min(np.abs(seg_t - ON_S)) < 1e-7 and np.min(np.abs(seg_t - OFF_S)) < 1e-7, seg_t
    # The same model as the bag's valve: the reconstruction is the only difference.
    assert _misfit_a(m, i) < 1e-4


def test_without_the_mean_the_sampled_voltage_drives_and_the_edges_move(tmp_path,
                                                                        step) -> None:
    t, v, i = step
    m = read_bag(_bag(tmp_path / 'bag', t, v, i, np.full(t.size, np.nan)))
    assert m.voltage_hold == 'sample'
    seg_t = prepare_trace(m).seg_t0_s
    assert np.min(np.abs(seg_t - ON_S)) > 5e-4   # moved to the next message
    assert _misfit_a(m, i) > 0.02                 # tens of mA at the edges


def test_a_mean_missing_on_some_messages_is_said_and_the_sampled_voltage_drives(
        tmp_path, step) -> None:
    t, v, i = step
    v_mean = _mean_voltage(t)
    v_mean[100] = np.nan
    m = read_bag(_bag(tmp_path / 'bag', t, v, i, v_mean))
    assert m.voltage_hold == 'sample'
    assert any('missing on some messages' in n for n in m.notes), m.notes


def test_a_mean_that_contradicts_the_samples_is_not_used(tmp_path, step) -> None:
    # a source that fills the field with 0 while the coil sees the supply
    t, v, i = step
    m = read_bag(_bag(tmp_path / 'bag', t, v, i, np.zeros(t.size)))
    assert m.voltage_hold == 'sample'
    assert any('disagrees with coil_voltage at' in n and 'message 302' in n
               for n in m.notes), m.notes


def test_messages_lost_between_the_edges_are_put_back(tmp_path, step) -> None:
    t, v, i = step
    lost = np.zeros(t.size, dtype=bool)
    lost[[50, 51, 52, 600, 601, 1300]] = True
    m = read_bag(_bag(tmp_path / 'bag', t, v, i, _mean_voltage(t), lost=lost))
    assert m.n_samples == t.size and np.all(np.isnan(m.current_a[lost]))
    assert m.voltage_hold == 'interval_mean'
    assert _misfit_a(m, i) < 1e-4
