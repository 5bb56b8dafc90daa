"""Interval means over CAN: ValveTelemetryMean carries the exact mean within its quantisation.

The emulator averages coil current and voltage over each telemetry period as firmware
averaging its ADC would (here: the model's exact integrals); the driver publishes them in
``ValveSample.coil_current_mean_a`` / ``coil_voltage_mean_v``.
"""
from __future__ import annotations

import itertools
import math

import can
import numpy as np
import pytest
from suite_waits import wait_until

from valve_driver_pkg.driver import CanDriverCore, DriverConfig
from valve_driver_pkg.emulator import ControllerEmulator, EmulatorConfig
from valve_driver_pkg.protocol import COMMAND, TELEMETRY, TELEMETRY_MEAN, ValveCodec
from valve_model_pkg.model import (ElectronicsConfig, InputTrace, ValveStepper, load_parameters,
                                   simulate_trace_batch)

PARAMS = load_parameters()
_channels = itertools.count()


def test_emulator_means_equal_the_exact_integrals_within_quantisation() -> None:
    channel = f'mean_test_{next(_channels)}'
    emu_bus = can.Bus(interface='virtual', channel=channel)
    host = can.Bus(interface='virtual', channel=channel)
    codec = ValveCodec(0)
    emu = ControllerEmulator(emu_bus, ValveStepper(PARAMS, ElectronicsConfig()),
                             EmulatorConfig(command_timeout_s=0.0))
    try:
        host.send(codec.encode(COMMAND, {'Duty': 0.4, 'PwmFrequency': 50.0, 'Enable': 1,
                                         'ClearFaults': 0, 'HostId': 1}, 0))
        emu.poll(0.5)                              # applied at model time 0
        emu.step(0.2)
        frames = []
        msg = host.recv(0.0)
        while msg is not None:
            frames.append(msg)
            msg = host.recv(0.0)
    finally:
        emu_bus.shutdown()
        host.shutdown()
    names = [codec.classify(f.arbitration_id)[0] for f in frames]
    # one mean per telemetry frame, sent just before it, with the same counter
    order = [n for n in names if n in (TELEMETRY, TELEMETRY_MEAN)]
    assert order == [TELEMETRY_MEAN, TELEMETRY] * 201
    means = [codec.decode(f) for f in frames
             if codec.classify(f.arbitration_id)[0] == TELEMETRY_MEAN]
    tele = [codec.decode(f) for f in frames
            if codec.classify(f.arbitration_id)[0] == TELEMETRY]
    assert [m.counter for m in means] == [t.counter for t in tele]
    t = np.arange(1, 201) * 1e-3
    ref = simulate_trace_batch(PARAMS, InputTrace.pwm_commands([0.0], 0.4, 50.0), t,
                               sampling='interval_mean')
    cur = np.array([m.signals['CoilCurrentMean'] for m in means[1:]])
    volt = np.array([m.signals['CoilVoltageMean'] for m in means[1:]])
    width = np.array([m.signals['MeanInterval'] for m in means[1:]])
    np.testing.assert_allclose(cur, ref.coil_current_a[0], rtol=0.0, atol=1e-4 + 1e-9)
    np.testing.assert_allclose(volt, ref.coil_voltage_v[0], rtol=0.0, atol=0.005 + 1e-9)
    np.testing.assert_allclose(width, 1e-3, atol=5e-7)
    assert cur.max() > 0.4                         # the valve really switched


def test_the_driver_publishes_the_means() -> None:
    channel = f'mean_test_{next(_channels)}'
    bus = can.Bus(interface='virtual', channel=channel)
    emu = ControllerEmulator(bus, ValveStepper(PARAMS, ElectronicsConfig()),
                             EmulatorConfig(command_timeout_s=0.0))
    states = []
    core = CanDriverCore(DriverConfig(interface='virtual', channel=channel,
                                      command_timeout_s=0.0), on_state=states.append)
    emu.start()
    try:
        core.open()
        core.activate()
        core.set_command(0.5, 50.0)
        wait_until(lambda: len(states) >= 300, what='300 states')
    finally:
        core.close()
        emu.stop()
        bus.shutdown()
    paired = [s for s in states[-200:] if math.isfinite(s.coil_current_mean_a)]
    assert len(paired) >= 150                      # NaN only where a mean frame was missed
    assert all(abs(s.coil_current_mean_a) <= 6.6 and abs(s.coil_voltage_mean_v) <= 30.0
               for s in paired)
    assert max(s.coil_current_mean_a for s in paired) > 0.3
    assert min(s.coil_voltage_mean_v for s in paired) < 24.0 - 1e-3  # chopper/low phase


@pytest.mark.parametrize('signal, scale', [('CoilCurrentMean', 2e-4),
                                           ('CoilVoltageMean', 0.01)])
def test_mean_signals_have_the_resolution_of_the_samples(signal: str, scale: float) -> None:
    assert ValveCodec(0).signal_scale(TELEMETRY_MEAN, signal) == scale
