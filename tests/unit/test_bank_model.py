"""ValveBank: N valves in one compiled call, each bit-identical to a ValveStepper."""
from __future__ import annotations

import numpy as np
import pytest

from valve_model_pkg.model import ElectronicsConfig, ParameterError, ValveParameters, ValveStepper
from valve_model_pkg.model.bank import SAMPLE_COLUMNS, ValveBank

P = ValveParameters()


def test_every_valve_matches_its_own_stepper_bit_for_bit() -> None:
    duties = [0.0, 0.2, 0.4, 0.7, 1.0]
    freqs = [20.0, 50.0, 100.0, 200.0, 50.0]
    supplies = [0.0, 2e5, 4e5, 6e5, 4e5]
    params = [P, P.replace(coil_resistance_ohm=22.0), P, P, P]
    elec = [ElectronicsConfig(), ElectronicsConfig(), ElectronicsConfig.off(),
            ElectronicsConfig(), ElectronicsConfig()]
    bank = ValveBank(params, elec, duty=duties, pwm_frequency_hz=freqs,
                     supply_pressure_pa=supplies)
    steppers = [ValveStepper(p, c, duty=d, pwm_frequency_hz=f, supply_pressure_pa=s)
                for p, c, d, f, s in zip(params, elec, duties, freqs, supplies)]
    assert len(bank) == 5
    for k in range(1, 250):
        t = k * 1e-3
        if k == 100:  # commands and pressures reach only their valve
            bank.set_command(1, 0.6, 80.0)
            steppers[1].set_command(0.6, 80.0)
            bank.set_pressures(2, 3e5, 1e5)
            steppers[2].set_pressures(3e5, 1e5)
        if k == 150:  # duty 0 acts at once (the stepper's semantics)
            bank.set_command(3, 0.0, 200.0)
            steppers[3].set_command(0.0, 200.0)
        bank.advance_to(t)
        for s in steppers:
            s.advance_to(t)
        rows = bank.sample_array()
        for i, s in enumerate(steppers):
            assert bank.sample(i) == s.sample()
            assert tuple(rows[i]) == tuple(getattr(s.sample(), c) for c in SAMPLE_COLUMNS)


def test_per_valve_target_times_and_reset() -> None:
    bank = ValveBank(P, n_valves=3, duty=0.5)
    bank.advance_to(np.array([0.01, 0.02, 0.0]))
    assert bank.t_s.tolist() == pytest.approx([0.01, 0.02, 0.0], abs=1e-12)
    bank.advance_to(0.015)  # valve 1 is already past: left alone
    assert bank.t_s.tolist() == pytest.approx([0.015, 0.02, 0.015], abs=1e-12)
    bank.reset(1)
    assert bank.t_s[1] == 0.0 and bank.t_s[0] > 0.0
    bank.reset()
    assert np.all(bank.t_s == 0.0)


def test_bad_inputs_are_refused() -> None:
    with pytest.raises(ParameterError):
        ValveBank(P, n_valves=2, duty=[0.1, 0.2, 0.3])
    with pytest.raises(ParameterError):
        ValveBank(P, n_valves=0)
    bank = ValveBank(P, n_valves=2)
    with pytest.raises(ParameterError):
        bank.set_command(0, 1.5, 50.0)
    with pytest.raises(ParameterError):
        bank.set_pressures(1, float('nan'))
    with pytest.raises(ParameterError):
        bank.advance_to(float('inf'))
    with pytest.raises(IndexError):
        bank.set_command(2, 0.5, 50.0)


def test_whole_matrix_validation_never_accepts_what_the_row_check_refuses() -> None:
    """A parameter matrix given to simulate_trace_batch is refused exactly when one of its
    rows fails ``ValveParameters.from_vector`` (the batch checks the matrix at once)."""
    from valve_model_pkg.model import PARAMETER_FIELDS, InputTrace, simulate_trace_batch
    rng = np.random.default_rng(3)
    base = P.to_vector()
    agree = {True: 0, False: 0}
    trace = InputTrace.coil_voltage([0.0], 0.0)   # a coil at rest: a valid row runs fast
    for trial in range(400):
        row = base.copy()
        for k in rng.choice(len(PARAMETER_FIELDS), size=rng.integers(1, 4), replace=False):
            with np.errstate(invalid='ignore'):  # 0 x inf: a NaN is one of the cases
                row[k] *= rng.choice([-1.0, 0.0, 1e-9, 0.5, 1.5, 1e9, np.nan, np.inf])
        try:
            ValveParameters.from_vector(row)
            valid = True
        except ParameterError:
            valid = False
        try:
            simulate_trace_batch(np.vstack([base, row]), trace, [1e-6])
            accepted = True
        except ParameterError:
            accepted = False
        assert accepted == valid, (trial, dict(zip(PARAMETER_FIELDS, row)))
        agree[valid] += 1
    assert agree[True] > 20 and agree[False] > 20
