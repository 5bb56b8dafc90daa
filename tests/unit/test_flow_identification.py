"""The flow side identified: C_d*C_A from a flow_map record and from the chamber balance."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from valve_model_pkg.cli.flow_check import main as flow_check_main
from valve_model_pkg.maps import load_map
from valve_model_pkg.maps.flow_check import map_flow_position, read_flow_map, write_flow_map
from valve_model_pkg.maps.inversion import FlowToDutyInverter
from valve_model_pkg.maps.flow_identification import (
    ChamberRecord, FlowIdentificationError, chamber_record_from_bag, chamber_valve_flow,
    chamber_volume_m3, flow_edges,
    identify_from_chamber, identify_from_flow_map, write_parameters)
from valve_model_pkg.model import ValveParameters, load_parameters, orifice_mass_flow
from valve_model_pkg.pneumatics.cylinder import Cylinder, CylinderParameters

#: A few measured points, as a bench run would take them.
DUTIES = np.array([0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0])
TRUE_RATIO = 1.23          # the bench valve's C_d*C_A over the model's


@pytest.fixture(scope='module')
def prior() -> ValveParameters:
    return ValveParameters.from_dict(load_map().parameters)


def _bench_file(tmp_path: Path, dmap, prior: ValveParameters, ratio: float, *,
                noise: float = 0.01, seed: int = 7, supply_pa: float = 4e5,
                output_pa: float = 0.0, name: str = 'bench.csv') -> tuple[Path, float]:
    """A 'measured' flow map straight from eq. (12) on the map's x_avg, with a bench valve
    whose C_A is ``ratio`` times the model's, and multiplicative noise."""
    true = prior.replace(orifice_area_gradient_m=prior.orifice_area_gradient_m * ratio)
    x = prior.stroke_m * np.array([map_flow_position(dmap, d, 50.0, supply_pa)
                                   for d in DUTIES])
    q = orifice_mass_flow(x, supply_pa, output_pa, true)
    q = q * (1.0 + noise * np.random.default_rng(seed).standard_normal(q.size))
    path = write_flow_map(tmp_path / name, DUTIES, supply_pressure_pa=supply_pa,
                          output_pressure_pa=output_pa, pwm_frequency_hz=50.0,
                          mass_flow_kg_s=np.maximum(q, 0.0))
    return path, true.discharge_coefficient * true.orifice_area_gradient_m


@pytest.mark.parametrize('ratio, output_pa', [(TRUE_RATIO, 0.0), (0.8, 0.0), (1.15, 2.5e5)])
def test_known_orifice_constant_recovered_within_3_percent(tmp_path: Path, shipped, prior,
                                                           ratio: float,
                                                           output_pa: float) -> None:
    path, true_product = _bench_file(tmp_path, shipped, prior, ratio, output_pa=output_pa)
    res = identify_from_flow_map(shipped, read_flow_map(path), prior)
    est = res.estimate
    assert est.product_m == pytest.approx(true_product, rel=0.03)
    lo, hi = est.interval_m
    assert lo <= true_product <= hi
    # the prior is far outside: an estimate equal to the prior would fail the check above
    assert not lo <= est.prior_product_m <= hi
    assert abs(est.prior_product_m / true_product - 1.0) > 0.1
    assert res.choked == (output_pa == 0.0)
    # C_d kept, C_A scaled, and the written set carries them
    assert est.discharge_coefficient == prior.discharge_coefficient
    assert res.params.orifice_area_gradient_m == pytest.approx(est.product_m
                                                               / prior.discharge_coefficient)
    assert res.error_after_pct < 2.0 < res.error_before_pct
    assert res.dead_band.agrees and res.saturation.agrees


def test_flow_fraction_file_cannot_identify_the_product(tmp_path: Path, shipped) -> None:
    path = write_flow_map(tmp_path / 'f.csv', DUTIES, supply_pressure_pa=4e5,
                          pwm_frequency_hz=50.0, flow_fraction=DUTIES)
    with pytest.raises(FlowIdentificationError, match='needs the absolute flow'):
        identify_from_flow_map(shipped, read_flow_map(path))


def test_a_shifted_dead_band_is_flagged(tmp_path: Path, shipped, prior) -> None:
    """A bench valve that opens 0.15 later than the map: the dead band disagrees."""
    path, _ = _bench_file(tmp_path, shipped, prior, 1.0, noise=0.0)
    fm = read_flow_map(path)
    x = prior.stroke_m * np.array([map_flow_position(shipped, max(d - 0.15, 0.0) / 0.85,
                                                     50.0, 4e5) for d in DUTIES])
    q = orifice_mass_flow(x, 4e5, 0.0, prior)
    late = write_flow_map(tmp_path / 'late.csv', fm.duty, supply_pressure_pa=4e5,
                          pwm_frequency_hz=50.0, mass_flow_kg_s=q)
    res = identify_from_flow_map(shipped, read_flow_map(late), prior)
    assert not res.dead_band.agrees
    assert res.dead_band.measured_duty > res.dead_band.model_duty + 0.1
    assert any('dead band' in n for n in res.notes)


def test_flow_edges_interpolate() -> None:
    d = np.array([0.0, 0.2, 0.4, 0.6, 0.8, 1.0])
    f = np.array([0.0, 0.0, 0.22, 0.6, 1.0, 1.0])
    start, sat = flow_edges(d, f)
    assert start == pytest.approx(0.2 + 0.02 / 0.22 * 0.2)
    assert sat == pytest.approx(0.6 + 0.38 / 0.4 * 0.2)
    assert flow_edges(d, np.zeros(6)) == (None, None)


def _chamber_run(valve: ValveParameters, cyl: CylinderParameters, seed: int = 1,
                 noise_pa: float = 300.0) -> ChamberRecord:
    """The suite's plant driven by a 20 Hz on/off opening with changing duty; sampled at
    1 kHz as the bag would give it (chamber pressure with sensor noise)."""
    plant = Cylinder(cyl, valve_params=valve)
    dt, t_end = 1e-3, 1.6
    n = int(round(t_end / dt))
    t = np.arange(n + 1) * dt
    period = 0.05
    duty = np.where(t < 0.5, 0.5, np.where(t < 1.0, 0.2, 0.7))
    opening = np.where((t % period) < duty * period, valve.stroke_m, 0.0)
    p = np.empty(n + 1)
    y = np.empty(n + 1)
    p[0], y[0] = plant.state.pressure_pa, plant.state.position_m
    for k in range(n):
        st = plant.step_with_valve(dt, float(opening[k]), 4e5)
        p[k + 1], y[k + 1] = st.pressure_pa, st.position_m
    rng = np.random.default_rng(seed)
    p_meas = p - 101325.0 + noise_pa * rng.standard_normal(p.size)
    return ChamberRecord(t, p_meas, chamber_volume_m3(y, cyl.bore_diameter_m,
                                                      cyl.dead_volume_m3),
                         opening, np.full(t.size, 4e5))


@pytest.mark.parametrize('bleed_known', [False, True])
def test_chamber_mass_balance_recovers_the_orifice(prior, bleed_known: bool) -> None:
    true = prior.replace(orifice_area_gradient_m=prior.orifice_area_gradient_m * 0.8)
    cyl = CylinderParameters()
    rec = _chamber_run(true, cyl)
    res = identify_from_chamber(
        rec, prior, polytropic_exponent=cyl.polytropic_exponent,
        bleed_discharge_area_m2=cyl.bleed_discharge_area_m2 if bleed_known else None)
    true_product = true.discharge_coefficient * true.orifice_area_gradient_m
    assert res.estimate.product_m == pytest.approx(true_product, rel=0.03)
    assert abs(res.estimate.prior_product_m / true_product - 1.0) > 0.2
    lo, hi = res.estimate.interval_m
    assert not lo <= res.estimate.prior_product_m <= hi
    if not bleed_known:
        assert res.bleed_discharge_area_m2 == pytest.approx(cyl.bleed_discharge_area_m2,
                                                            rel=0.1)
    assert res.error_after_pct < res.error_before_pct


def _write_chamber_bag(path: Path, rec: ChamberRecord, position_m: np.ndarray) -> None:
    """The topics the suite records: valve/state at 1 kHz, the cylinder node's
    valve/output_pressure (absolute) and cylinder/joint_states at 200 Hz."""
    from suite_bags import header as _header, write_bag
    from valve_model_pkg.recording import build_typestore
    store = build_typestore()
    types = store.types
    start = 1_700_000_000_000_000_000

    def header(k: int, frame: str) -> object:
        return _header(types, start + k * 1_000_000, frame)

    msgs = []
    for k in range(rec.t_s.size):
        state = types['valve_msgs/msg/ValveState'](
            header=header(k, 'valve'), sequence=k, coil_voltage=0.0, coil_current=0.0,
            coil_current_mean=0.0, coil_voltage_mean=0.0,
            spool_position=float(rec.opening_m[k]), spool_velocity=0.0,
            spool_position_avg=0.0, mass_flow=0.0, duty=0.5, pwm_frequency=20.0,
            supply_pressure=float(rec.supply_pressure_pa[k]),
            output_pressure=float(rec.chamber_pressure_pa[k]), source=0,
            position_measured=False)
        msgs.append(('valve/state', 'valve_msgs/msg/ValveState', k, state))
        if k % 5 == 0:
            pres = types['sensor_msgs/msg/FluidPressure'](
                header=header(k, 'cylinder_chamber'),
                fluid_pressure=float(rec.chamber_pressure_pa[k]) + 101325.0, variance=0.0)
            joint = types['sensor_msgs/msg/JointState'](
                header=header(k, ''), name=['piston'],
                position=np.array([position_m[k]]), velocity=np.array([0.0]),
                effort=np.array([0.0]))
            msgs.append(('valve/output_pressure', 'sensor_msgs/msg/FluidPressure', k, pres))
            msgs.append(('cylinder/joint_states', 'sensor_msgs/msg/JointState', k, joint))
    write_bag(path, store, [(topic, msgtype, start + k * 1_000_000, msg)
                            for topic, msgtype, k, msg in msgs])


def test_chamber_identification_from_a_suite_bag(tmp_path: Path, prior) -> None:
    """The bag carries chamber pressure, piston and spool position; the geometry is given."""
    true = prior.replace(orifice_area_gradient_m=prior.orifice_area_gradient_m * 1.2)
    cyl = CylinderParameters()
    rec = _chamber_run(true, cyl)
    area = np.pi * cyl.bore_diameter_m ** 2 / 4.0
    _write_chamber_bag(tmp_path / 'bag', rec, (rec.volume_m3 - cyl.dead_volume_m3) / area)
    from_bag = chamber_record_from_bag(tmp_path / 'bag', bore_diameter_m=cyl.bore_diameter_m,
                                       dead_volume_m3=cyl.dead_volume_m3)
    assert from_bag.t_s.size == rec.t_s.size
    res = identify_from_chamber(from_bag, prior, polytropic_exponent=cyl.polytropic_exponent)
    true_product = true.discharge_coefficient * true.orifice_area_gradient_m
    assert res.estimate.product_m == pytest.approx(true_product, rel=0.03)
    assert abs(res.estimate.prior_product_m / true_product - 1.0) > 0.15


def test_chamber_record_refuses_bad_arrays(prior) -> None:
    t = np.linspace(0.0, 1.0, 11)
    rec = ChamberRecord(t, np.zeros(11), np.ones(10), np.zeros(11), np.zeros(11))
    with pytest.raises(FlowIdentificationError, match='volume_m3 has shape'):
        identify_from_chamber(rec, prior)


def test_cli_out_dir_writes_identified_values_and_params(tmp_path: Path, capsys, shipped,
                                                         prior) -> None:
    path, true_product = _bench_file(tmp_path, shipped, prior, TRUE_RATIO)
    out = tmp_path / 'out'
    assert flow_check_main([str(path), '--out', str(out)]) == 0
    text = capsys.readouterr().out
    assert 'C_d*C_A' in text and 'overall: rms' in text
    data = json.loads((out / 'flow_identified.json').read_text())
    assert data['product_m'] == pytest.approx(true_product, rel=0.03)
    assert data['interval_m'][0] <= true_product <= data['interval_m'][1]
    assert data['discharge_coefficient'] == prior.discharge_coefficient
    assert data['flow_error_pct_of_full_flow']['after']['rms'] \
        < data['flow_error_pct_of_full_flow']['before']['rms']
    assert set(data['dead_band']) >= {'measured_duty', 'model_duty', 'agrees'}
    written = load_parameters(out / 'params.yaml')
    assert written.discharge_coefficient * written.orifice_area_gradient_m == pytest.approx(
        data['product_m'])
    assert written.replace(orifice_area_gradient_m=prior.orifice_area_gradient_m) == prior
    # the recalibrated map goes with params.yaml, and flow_to_duty's duty for a flow
    # gives that flow on the bench valve (the old map is off by the constant's ratio)
    new_map = load_map(out / 'map.json')
    new_map.check_parameters(written, 'map.json', 'params.yaml')
    np.testing.assert_array_equal(new_map.position_fraction, shipped.position_fraction)
    true = prior.replace(orifice_area_gradient_m=prior.orifice_area_gradient_m * TRUE_RATIO)
    for dmap, ok in ((new_map, True), (shipped, False)):
        inv = FlowToDutyInverter(dmap, 50.0)
        for frac in (0.4, 0.7):
            q_cmd = frac * float(orifice_mass_flow(prior.stroke_m, 4e5, 0.0, true))
            duty = inv.compute(q_cmd, 4e5, 0.0).duty
            q_got = float(orifice_mass_flow(
                prior.stroke_m * map_flow_position(shipped, duty, 50.0, 4e5), 4e5, 0.0, true))
            assert (abs(q_got / q_cmd - 1.0) < 0.03) == ok, (frac, q_got / q_cmd)
    # --params: the start set is the given file (it must match the map)
    start = tmp_path / 'start.yaml'
    write_parameters(prior, start)
    out2 = tmp_path / 'out2'
    assert flow_check_main([str(path), '--params', str(start), '--out', str(out2)]) == 0
    assert load_parameters(out2 / 'params.yaml') == written
    # a start set the map was not made for is refused (exit 2, one line)
    other = tmp_path / 'other.yaml'
    write_parameters(prior.replace(coil_resistance_ohm=prior.coil_resistance_ohm * 1.1), other)
    capsys.readouterr()
    assert flow_check_main([str(path), '--params', str(other), '--out',
                            str(tmp_path / 'out3')]) == 2
    assert capsys.readouterr().err.count('\n') == 1
    assert not (tmp_path / 'out3').exists()


def test_cli_out_dir_refuses_flow_fraction_file(tmp_path: Path, capsys) -> None:
    path = write_flow_map(tmp_path / 'f.csv', DUTIES, supply_pressure_pa=4e5,
                          pwm_frequency_hz=50.0, flow_fraction=DUTIES)
    assert flow_check_main([str(path), '--out', str(tmp_path / 'o')]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'mass_flow' in err and 'Traceback' not in err
    assert not (tmp_path / 'o' / 'params.yaml').exists()


def test_cli_chamber_mode_identifies_from_a_bag_and_names_the_defaults(
        tmp_path: Path, capsys, prior) -> None:
    """``valve_flow_check BAG --chamber --out DIR``: the constant from the chamber's mass
    balance, written where the flow-map mode writes it; the cylinder geometry the bag lacks
    is the suite cylinder's unless given, and the output says which defaults were used."""
    import json as _json

    from valve_model_pkg.cli.flow_check import main
    true = prior.replace(orifice_area_gradient_m=prior.orifice_area_gradient_m * 1.2)
    cyl = CylinderParameters()
    rec = _chamber_run(true, cyl)
    area = np.pi * cyl.bore_diameter_m ** 2 / 4.0
    _write_chamber_bag(tmp_path / 'bag', rec, (rec.volume_m3 - cyl.dead_volume_m3) / area)
    out = tmp_path / 'cal'
    assert main([str(tmp_path / 'bag'), '--chamber', '--out', str(out)]) == 0
    said = capsys.readouterr().out
    assert 'defaults were used for --bore-m, --dead-volume-m3' in said
    data = _json.loads((out / 'flow_identified.json').read_text())
    true_product = true.discharge_coefficient * true.orifice_area_gradient_m
    assert data['source'] == 'chamber'
    assert data['product_m'] == pytest.approx(true_product, rel=0.03)
    assert (out / 'params.yaml').is_file() and (out / 'map.json').is_file()
    # a wrong bore (twice the real one) gives a different constant: the geometry matters
    assert main([str(tmp_path / 'bag'), '--chamber', '--bore-m',
                 str(2 * cyl.bore_diameter_m), '--out', str(tmp_path / 'wrong')]) == 0
    wrong = _json.loads((tmp_path / 'wrong' / 'flow_identified.json').read_text())
    assert abs(wrong['product_m'] / true_product - 1.0) > 0.5


def test_cli_chamber_mode_refuses_bad_input_in_one_line(tmp_path: Path, capsys) -> None:
    from valve_model_pkg.cli.flow_check import main
    with pytest.raises(SystemExit) as exc:
        main([str(tmp_path), '--chamber', '--bore-m', 'nan', '--out', str(tmp_path / 'o')])
    assert exc.value.code == 2
    assert '--bore-m nan' in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main([str(tmp_path), '--chamber'])   # no --out
    assert exc.value.code == 2
    assert '--chamber needs -o/--out DIR' in capsys.readouterr().err
    garbage = tmp_path / 'garbage'
    garbage.mkdir()
    (garbage / 'metadata.yaml').write_text('\x00\x01 not a bag')
    assert main([str(garbage), '--chamber', '--out', str(tmp_path / 'o')]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(garbage) in err[0] and 'Traceback' not in err[0]


def test_chamber_valve_flow_is_the_flow_the_valve_delivered(prior) -> None:
    """The chamber as a flow meter (the loop's flow prediction error is measured by it):
    window means of the plant's own valve flow, from pressure and position alone."""
    cyl = CylinderParameters()
    plant = Cylinder(cyl, valve_params=prior)
    dt, n, period = 1e-3, 1200, 0.05
    t = np.arange(n + 1) * dt
    duty = np.where(t < 0.6, 0.6, 0.25)
    opening = np.where((t % period) < duty * period, prior.stroke_m, 0.0)
    p, y, q = np.empty(n + 1), np.empty(n + 1), np.zeros(n + 1)
    p[0], y[0] = plant.state.pressure_pa, plant.state.position_m
    for k in range(n):
        st = plant.step_with_valve(dt, float(opening[k]), 4e5)
        p[k + 1], y[k + 1], q[k + 1] = st.pressure_pa, st.position_m, \
            plant.last_valve_flow_kg_s
    rec = ChamberRecord(t, p - 101325.0, chamber_volume_m3(y, cyl.bore_diameter_m,
                                                           cyl.dead_volume_m3),
                        np.zeros_like(t), np.full(t.size, 4e5))
    starts, flow = chamber_valve_flow(rec, prior, polytropic_exponent=cyl.polytropic_exponent,
                                      bleed_discharge_area_m2=cyl.bleed_discharge_area_m2,
                                      window_s=0.1)
    assert starts.size == 12 and starts[0] == 0.0
    true = np.array([q[(t > s) & (t <= s + 0.1 + 1e-9)].mean() for s in starts])
    assert np.max(true) > 1e-4                        # the valve did deliver
    np.testing.assert_allclose(flow, true, atol=0.03 * np.max(true))
    # without the bleed the meter reads only what stayed in the chamber: less
    _, stored = chamber_valve_flow(rec, prior, polytropic_exponent=cyl.polytropic_exponent,
                                   bleed_discharge_area_m2=0.0, window_s=0.1)
    assert np.all(stored[2:] < flow[2:])
