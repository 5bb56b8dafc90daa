"""Operational records made by the suite's OWN model (not independent: the truth valve of
:mod:`datagen.truth` is): the PWM schedule of the identification tests, the interval-mean
current through the drive electronics at 1 kHz, Gaussian noise, written as an
``operation`` CSV (shared/measured-data-format.md)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from valve_model_pkg.dataformat import write_table
from valve_model_pkg.model import InputTrace, ValveParameters, load_parameters, \
    simulate_trace_batch

#: Duties of the schedule, 0.2 s each in turn at 50 Hz after 40 ms at rest.
DUTIES = (0.2, 0.5, 0.8, 0.35, 0.65)


def suite_operation_record(path: Path, noise_a: float, seed: int, duration_s: float = 1.5,
                           params: ValveParameters | None = None) -> Path:
    """Write ``path``: ``duration_s`` of the valve ``params`` (default: the packaged set) at
    50 Hz through the electronics, supply 24 V and 4 bar, noise ``noise_a`` [A] std."""
    phase = 0.0073   # the first period starts off the 1 ms sample grid
    t_cmd, duty, freq = [0.0], [0.0], [1.0 / phase]
    s = phase
    while s < duration_s:
        d = 0.0 if s < 0.04 else DUTIES[int(s / 0.2) % len(DUTIES)]
        t_cmd += [s - 1e-6]
        duty += [d]
        freq += [50.0]
        s += 0.02
    t = np.arange(1, int(round(duration_s * 1000)) + 1) * 1e-3
    res = simulate_trace_batch(params or load_parameters(), InputTrace.pwm_commands(
        t_cmd, duty, freq, 24.0), t, sampling='interval_mean', supply_pressure_pa=4e5)
    starts = np.array(t_cmd[1:]) + 1e-6
    k = np.searchsorted(starts, t, side='right') - 1
    d_in = np.where(k >= 0, np.array(duty[1:])[np.clip(k, 0, None)], 0.0)
    cur = res.coil_current_a[0] + np.random.default_rng(seed).normal(0.0, noise_a, t.size)
    return write_table(path, {
        'experiment': 'operation', 'supply_voltage_v': 24, 'sample_rate_hz': 1000,
        'current_averaging': 'interval_mean', 'supply_pressure_pa': 400000},
        {'t': t, 'duty': d_in, 'pwm_frequency_hz': np.full(t.size, 50.0), 'current': cur})
