"""Intervals through the drive electronics: the current is not a smooth function of every
parameter (a chopper edge or the end of the boost moves by a whole switching event), so one
finite-difference step can land on a jump and claim a tight interval for a parameter far
off its truth. The analysis takes the Jacobian at three steps, uses the median variance,
and never calls a parameter whose sensitivity changes with the step pinned down."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from valve_model_pkg.identification import sensitivity as sens_mod
from valve_model_pkg.model import load_parameters


class _Bound(SimpleNamespace):
    pass


def _fake(monkeypatch, jump: bool):
    n = 4000
    t = np.linspace(0.0, 1.0, n)
    rng = np.random.default_rng(3)
    noise = rng.normal(0.0, 1e-3, n)

    def jacobian(space, data, params, step=sens_mod.JACOBIAN_STEP):
        a = np.full(n, 0.5)                      # smooth: the same at every step
        b = 0.5 * np.sin(2 * np.pi * 2 * t)      # smooth unless ``jump``
        if jump and step == sens_mod.JACOBIAN_STEP:
            b = b * 10.0                          # the 1 % step lands on a jump
        return np.column_stack([a, b])

    monkeypatch.setattr(sens_mod, 'current_jacobian', jacobian)
    space = SimpleNamespace(names=('coil_resistance_ohm', 'stroke_m'),
                            bounds=(_Bound(low=1.0, high=30.0), _Bound(low=1e-4, high=1e-3)))
    data = SimpleNamespace(residuals=lambda params: [noise],
                           measurements=[SimpleNamespace(name='fake.csv', current_lsb_a=None)])
    return space, data


def test_a_parameter_whose_sensitivity_jumps_with_the_step_is_not_pinned(monkeypatch) -> None:
    space, data = _fake(monkeypatch, jump=True)
    rep = sens_mod.analyse_sensitivity(space, data, load_parameters())
    assert 'stroke_m' not in rep.pinned
    assert 'coil_resistance_ohm' in rep.pinned
    assert any('not a smooth function of x_max' in n for n in rep.notes), rep.notes


def test_smooth_columns_keep_their_pinned_claims(monkeypatch) -> None:
    space, data = _fake(monkeypatch, jump=False)
    rep = sens_mod.analyse_sensitivity(space, data, load_parameters())
    assert {'coil_resistance_ohm', 'stroke_m'} <= set(rep.pinned)
    assert not any('not a smooth function' in n for n in rep.notes)
