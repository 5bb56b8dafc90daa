"""A record whose current does not follow its coil voltage is refused before any fitting;
a record with a real but small current is not (identification.measurement).

The records are voltage steps on the independent truth model (tests/datagen), sampled by
a scope with noise; the refused ones keep the voltage and lose the current.
"""
from __future__ import annotations

import numpy as np
import pytest
from datagen.exports import quantise, scope_trace

from valve_model_pkg.errors import MeasurementFormatError
from valve_model_pkg.identification.measurement import (RESPONSE_NOISE_SIGMAS, Measurement,
                                                        check_current_response,
                                                        current_response, with_current_lsb)
from valve_model_pkg.identification.pipeline import IdentifySettings, read_inputs
from valve_model_pkg.model import load_parameters

#: The parameter set's coil resistance [ohm] (the scale V/R of the check).
R_OHM = load_parameters().coil_resistance_ohm
NOISE_A = 2e-3


def _record(voltage_v: float, current: str = 'truth', lsb_a: float = 0.0,
            name: str = 'step.csv') -> Measurement:
    """A 15 ms step of ``voltage_v`` after 2 ms at rest (scope at 20 us); ``current``:
    the truth model's with noise, or ``noise`` alone (the coil's current lost)."""
    tr = scope_trace(voltage_v=voltage_v, dt_s=2e-5, noise_a=NOISE_A)
    cur = tr.current_a if current == 'truth' else np.random.default_rng(3).normal(
        0.0, NOISE_A, tr.t_s.size)
    if lsb_a:
        cur = quantise(cur, lsb_a, -5.0, 5.0)
    t = tr.t_s - tr.t_s[0]
    return with_current_lsb(Measurement(source=f'/data/{name}', t_s=t,
                                        voltage_v=tr.voltage_v, current_a=cur,
                                        supply_pressure_pa=4e5, experiment='step'))


@pytest.mark.parametrize('voltage_v', [24.0, 15.0, 0.5])
def test_a_record_whose_current_follows_its_voltage_passes(voltage_v: float) -> None:
    # 0.5 V on a 13 ohm coil: about 38 mA, small but 19 times the noise
    m = _record(voltage_v)
    r = current_response(m, R_OHM)
    assert r.responds, r
    check_current_response(m, R_OHM)
    assert r.response_a > 0.5 * voltage_v / R_OHM  # the rise reaches V/R within the step
    assert r.noise_a == pytest.approx(NOISE_A, rel=0.3)  # measured at rest


def test_a_current_lost_while_15_v_is_on_is_refused_naming_file_and_values() -> None:
    m = _record(15.0, current='noise', name='bench_15V.csv')
    with pytest.raises(MeasurementFormatError) as info:
        check_current_response(m, R_OHM)
    text = str(info.value)
    assert text.startswith('/data/bench_15V.csv: the current does not respond')
    assert '15 V is on' in text and '\n' not in text
    r = current_response(m, R_OHM)
    assert r.response_a < RESPONSE_NOISE_SIGMAS * NOISE_A
    assert f'{1e3 * r.response_a:.3g} mA' in text


def test_a_current_below_its_quantisation_step_is_refused() -> None:
    # a 16 mA converter step and 2 mA of noise: the lost current reads 0 throughout
    m = _record(15.0, current='noise', lsb_a=0.016)
    assert not current_response(m, R_OHM).responds
    with pytest.raises(MeasurementFormatError, match='does not respond'):
        check_current_response(m, None)  # the noise and the LSB alone refuse it


def test_the_physical_scale_refuses_a_noise_free_flat_current() -> None:
    m = _record(15.0, current='noise')
    flat = m.with_current(np.zeros(m.n_samples))
    with pytest.raises(MeasurementFormatError, match=r'1 % of V/R = 1\.15 A'):
        check_current_response(flat, R_OHM)


def test_identification_refuses_the_record_before_fitting() -> None:
    good, bad = _record(24.0), _record(15.0, current='noise', name='val.csv')
    lines: list[str] = []
    with pytest.raises(MeasurementFormatError, match='val.csv: the current does not'):
        read_inputs([good], [bad], IdentifySettings(quick=True), None, lines.append)
    inputs = read_inputs([good], [_record(15.0)], IdentifySettings(quick=True), None,
                         lines.append)
    assert len(inputs.fit) == len(inputs.validation) == 1
