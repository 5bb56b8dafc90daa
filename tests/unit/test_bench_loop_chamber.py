"""The operation loop's chamber data (bench_loop._chamber_data, the source of the flow
calibration and of the flow prediction error) do not depend on whether the recorder caught
the messages stamped 0, published before the lockstep clock's first step in some runs only:
with them the mass balance's windows (which start at the first stamp) shifted by a step, and
two loops on identical before runs calibrated C_A differently in the 4th digit."""
from __future__ import annotations

import numpy as np

from suite_bags import header, write_bag
from valve_bringup.bench_loop import _chamber_data


def _write_bag(path, with_stamp_zero: bool) -> None:
    from valve_model_pkg.recording import build_typestore
    store = build_typestore()
    ty = store.types
    wall0 = 1_700_000_000_000_000_000
    msgs = []
    ticks = ([0] if with_stamp_zero else []) + [5_000_000 * k for k in range(1, 201)]
    for j, ns in enumerate(ticks):
        t = ns * 1e-9
        h = header(ty, ns)
        log = wall0 + 1_000_000 * j
        msgs += [
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
    write_bag(path, store, msgs)


def test_messages_stamped_zero_do_not_shift_the_chamber_record(tmp_path) -> None:
    _write_bag(tmp_path / 'with', True)
    _write_bag(tmp_path / 'without', False)
    a, b = _chamber_data(tmp_path / 'with'), _chamber_data(tmp_path / 'without')
    assert a['t_s'][0] == b['t_s'][0] == 0.005
    for k in ('t_s', 'position_m', 'pressure_pa', 'duty'):
        assert np.array_equal(a[k], b[k]), k
    assert a['t_s'].size == 200
    assert a['pwm_frequency_hz'] == 50.0 and a['supply_pa'] == 4e5
