"""A parameter vector of the search whose coil is far faster than the rest step of a long
record (L/R ~ 0.1 ms against 500 us) is simulated with shorter steps, not refused, and
the other vectors of its batch keep their results bit for bit
(identification.model_adapter.simulate_measurement)."""
from __future__ import annotations

import numpy as np
import pytest

from valve_model_pkg.identification.measurement import Measurement
from valve_model_pkg.identification.model_adapter import prepare_trace, simulate_measurement
from valve_model_pkg.model import load_parameters

GOOD = load_parameters()
#: A vector the effect search visited in a loaded bench run: low permeability with strong
#: saturation. Its incremental inductance at the 24 V step's current is about 1.8 mH, so
#: L/R ~ 0.1 ms: an RK4 step of 500 us (stable up to 2.8 L/R) diverges.
FAST_COIL = GOOD.replace(coil_resistance_ohm=18.6567, relative_permeability=10.2318,
                         stroke_m=2.04935e-4, core_area_m2=4.42875e-5,
                         spring_pretension_m=1.26975e-3, damping_n_s_per_m=0.0970872,
                         saturation_coefficient_per_a=0.8)
VOLTAGE_V = 24.0


@pytest.fixture(scope='module')
def setup():
    # 1.2 s at 1 kHz: a multi-second-class record, which prepare_trace steps at 500 us
    t = np.arange(1200) / 1000.0
    v = np.where((t >= 0.2) & (t < 1.0), VOLTAGE_V, 0.0)
    m = Measurement(source='long_step.csv', t_s=t, voltage_v=v, current_a=np.zeros(t.size),
                    supply_pressure_pa=4e5, experiment='step')
    s = prepare_trace(m)
    assert s.h_stop_s == pytest.approx(500e-6)
    return s


def test_a_fast_coil_is_simulated_and_its_batch_keeps_its_results(setup) -> None:
    raw = np.array([GOOD.to_vector(), FAST_COIL.to_vector()])
    cur, pos = simulate_measurement(raw, setup)
    assert np.all(np.isfinite(cur)) and np.all(np.isfinite(pos))
    # at the end of the 0.8 s step the current is V/R (eq. 5 at rest: di/dt = 0)
    i_end = cur[1, 999]
    assert i_end == pytest.approx(VOLTAGE_V / FAST_COIL.coil_resistance_ohm, rel=1e-3)
    alone, _ = simulate_measurement(raw[:1], setup)
    np.testing.assert_array_equal(cur[0], alone[0])
