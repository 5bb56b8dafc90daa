"""The chamber of a suite run (analysis.run_chamber, the source of the loop's flow
calibration and flow prediction error), from a hand-built bag: joint-state stamps as the
time base, the pressure interpolated onto them, the duty command in force; messages stamped
0 (before the lockstep clock's first step, in some runs only) do not shift the record."""
from __future__ import annotations

import numpy as np
import pytest

from suite_bags import header, write_bag
from valve_model_pkg.analysis import run_chamber, strictly_increasing
from valve_model_pkg.errors import RunAnalysisError
from valve_model_pkg.interface import ATMOSPHERIC_PRESSURE_PA
from valve_model_pkg.pneumatics.cylinder import CylinderParameters
from valve_model_pkg.recording import build_typestore

WALL0_NS = 1_700_000_000_000_000_000
TICK_NS = 5_000_000


def _messages(ty: dict, j: int, ns: int, log: int) -> list[tuple]:
    t = ns * 1e-9
    h = header(ty, ns)
    return [
        ('cylinder/joint_states', 'sensor_msgs/msg/JointState', log, ty[
            'sensor_msgs/msg/JointState'](header=h, name=['piston'],
                                          position=np.array([0.05 * t * t]),
                                          velocity=np.array([0.1 * t]),
                                          effort=np.array([0.0]))),
        ('valve/output_pressure', 'sensor_msgs/msg/FluidPressure', log, ty[
            'sensor_msgs/msg/FluidPressure'](header=h, fluid_pressure=1e5 + 2e5 * t,
                                             variance=0.0)),
        ('valve/duty_command', 'valve_msgs/msg/DutyCommand', log, ty[
            'valve_msgs/msg/DutyCommand'](header=h, sequence=j, duty=0.5 + 0.3 * t,
                                          pwm_frequency=50.0)),
        ('valve/state', 'valve_msgs/msg/ValveState', log, ty['valve_msgs/msg/ValveState'](
            header=h, sequence=j, coil_voltage=0.0, coil_current=0.0,
            coil_current_mean=0.0, coil_voltage_mean=0.0, spool_position=0.0,
            spool_velocity=0.0, spool_position_avg=0.0, mass_flow=0.0, duty=0.5,
            pwm_frequency=50.0, supply_pressure=4e5, output_pressure=1e5, source=1,
            position_measured=False))]


def _write_bag(path, with_stamp_zero: bool, repeat_tick: int | None = None,
               topics: set[str] | None = None) -> None:
    """200 control ticks of 5 ms: piston at 0.05 t^2 m, chamber at 1 + 2 t bar absolute,
    duty 0.5 + 0.3 t; optionally a message stamped 0 first and one tick twice."""
    store = build_typestore()
    ticks = ([0] if with_stamp_zero else []) + [TICK_NS * k for k in range(1, 201)]
    if repeat_tick is not None:
        ticks.insert(ticks.index(repeat_tick * TICK_NS), repeat_tick * TICK_NS)
    msgs = [m for j, ns in enumerate(ticks)
            for m in _messages(store.types, j, ns, WALL0_NS + 1_000_000 * j)]
    if topics is not None:
        msgs = [m for m in msgs if m[0] in topics]
    write_bag(path, store, msgs)


def test_the_chamber_is_on_the_joint_state_stamps(tmp_path) -> None:
    _write_bag(tmp_path / 'bag', False)
    ch = run_chamber(tmp_path / 'bag')
    t = TICK_NS * np.arange(1, 201) * 1e-9
    np.testing.assert_allclose(ch.t_s, t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ch.position_m, 0.05 * t ** 2, rtol=1e-12)
    np.testing.assert_allclose(ch.pressure_pa, 1e5 + 2e5 * t - ATMOSPHERIC_PRESSURE_PA,
                               rtol=0, atol=1e-6)
    np.testing.assert_allclose(ch.duty, 0.5 + 0.3 * t, rtol=1e-12)
    assert ch.pwm_frequency_hz == 50.0 and ch.supply_pressure_pa == 4e5
    cyl = CylinderParameters()
    rec = ch.chamber_record(cyl, from_zero=True)
    assert rec.t_s[0] == 0.0 and np.all(rec.opening_m == 0.0)
    area = np.pi * cyl.bore_diameter_m ** 2 / 4.0
    np.testing.assert_allclose(rec.volume_m3, cyl.dead_volume_m3 + area * 0.05 * t ** 2)
    np.testing.assert_array_equal(rec.supply_pressure_pa, np.full(200, 4e5))


def test_messages_stamped_zero_do_not_shift_the_chamber_record(tmp_path) -> None:
    _write_bag(tmp_path / 'with', True)
    _write_bag(tmp_path / 'without', False)
    a, b = run_chamber(tmp_path / 'with'), run_chamber(tmp_path / 'without')
    assert a.t_s[0] == b.t_s[0] == 0.005
    for k in ('t_s', 'position_m', 'pressure_pa', 'duty'):
        assert np.array_equal(getattr(a, k), getattr(b, k)), k
    assert a.t_s.size == 200


def test_a_repeated_stamp_keeps_one_sample(tmp_path) -> None:
    _write_bag(tmp_path / 'bag', False, repeat_tick=50)
    ch = run_chamber(tmp_path / 'bag')
    assert ch.t_s.size == 200 and np.all(np.diff(ch.t_s) > 0.0)


def test_strictly_increasing_keeps_the_last_of_equal_times() -> None:
    t = np.array([0.0, 1.0, 1.0, 2.0, 3.0, 3.0, 3.0])
    assert strictly_increasing(t).tolist() == [True, False, True, True, False, False, True]


def test_a_bag_without_the_duty_commands_is_refused_in_one_line(tmp_path) -> None:
    _write_bag(tmp_path / 'bag', False, topics={'cylinder/joint_states',
                                                'valve/output_pressure', 'valve/state'})
    with pytest.raises(RunAnalysisError, match='no valve/duty_command messages'):
        run_chamber(tmp_path / 'bag')
