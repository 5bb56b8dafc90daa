"""The CAN emulator on the simulation clock (valve_driver_pkg.emulator.lockstep): the model
advances past a control tick only with that tick's duty command in force on the bus, and a
command that never comes is a counted timeout, not a hang."""
from __future__ import annotations

from valve_driver_pkg.emulator.lockstep import LockstepGateState


def test_steps_past_a_tick_only_with_its_command_on_the_bus() -> None:
    gate = LockstepGateState(control_period_ns=5_000_000, timeout_s=2.0)
    gate.tick_output_pa[5_000_000] = gate.bus_output_pa = 0.0   # the pressure is there
    assert gate.may_step(0, 0.0)                 # t = 0: duty 0 until the first tick
    assert gate.may_step(4_000_000, 0.0)
    assert not gate.may_step(5_000_000, 0.0)     # tick 5 ms: no command known yet
    gate.tick_duty[5_000_000] = 0.25
    assert not gate.may_step(5_000_000, 0.1)     # known on ROS, not yet on the bus
    gate.bus_duty = 0.2500                        # the CAN frame (resolution 1e-4)
    assert gate.may_step(5_000_000, 0.2)
    assert gate.may_step(9_000_000, 0.2)
    gate.forget_before(10_000_000)
    assert gate.tick_duty == {}
    assert gate.timeouts == 0


def test_the_first_tick_waits_for_its_command_when_a_controller_publishes_one() -> None:
    # Ungated, the first 5 ms would run with duty 0 or with the t = 0 answer, whichever
    # reached the emulator first: two runs of the same demo would differ from the start.
    gate = LockstepGateState(control_period_ns=5_000_000, timeout_s=2.0)
    gate.gate_first_tick = True
    assert not gate.may_step(0, 0.0)
    assert 'duty command (none stamped' in gate.missing(0)
    gate.tick_duty[0] = 0.14
    gate.bus_duty = 0.0                           # the bus still carries the driver's duty 0
    assert not gate.may_step(0, 0.1)
    gate.bus_duty = 0.14
    gate.tick_output_pa[0] = gate.bus_output_pa = 0.0
    assert gate.may_step(0, 0.2)
    assert gate.may_step(4_000_000, 0.2)
    assert gate.timeouts == 0


def test_a_tick_needs_its_pressure_stamped_on_ros_too() -> None:
    # The bus carrying the previous tick's pressure is no proof: the tick's own pressure
    # must have come on ROS (a message lost before a DDS match is sent again by the
    # simulation, so waiting for it is safe).
    gate = LockstepGateState(control_period_ns=5_000_000, timeout_s=2.0)
    gate.tick_duty[5_000_000] = gate.bus_duty = 0.25
    gate.bus_output_pa = 0.0
    assert not gate.may_step(5_000_000, 0.0)
    assert 'output pressure (none stamped' in gate.missing(5_000_000)
    gate.tick_output_pa[5_000_000] = 10.0        # within the frame's resolution of 0 Pa
    assert gate.missing(5_000_000) is None
    assert gate.may_step(5_000_000, 0.1)


def test_a_missing_command_times_out_and_is_counted() -> None:
    gate = LockstepGateState(control_period_ns=5_000_000, timeout_s=1.0)
    gate.bus_duty = 0.1
    assert not gate.may_step(10_000_000, 5.0)
    assert not gate.may_step(10_000_000, 5.9)
    assert gate.may_step(10_000_000, 6.2)
    assert gate.timeouts == 1 and 't = 0.010 s' in gate.last_timeout


def test_steps_past_a_tick_only_with_its_output_pressure_on_the_bus() -> None:
    # The chamber pressure of tick T must reach the valve at T, not a step early or late
    # depending on which of the driver's frames arrives first (the CAN demo's settling
    # times varied by up to 30 ms between runs before).
    gate = LockstepGateState(control_period_ns=5_000_000, timeout_s=1.0)
    gate.tick_duty[5_000_000] = 0.5
    gate.bus_duty = 0.5
    gate.tick_output_pa[5_000_000] = 123_450.0
    gate.bus_output_pa = 120_000.0             # the previous tick's pressure
    assert not gate.may_step(5_000_000, 0.0)
    gate.bus_output_pa = 123_450.0 + 20.0      # within one 50 Pa step of the frame
    assert gate.may_step(5_000_000, 0.1)
    gate.forget_before(10_000_000)
    assert gate.tick_output_pa == {}


def test_a_missing_pressure_times_out_and_says_so() -> None:
    gate = LockstepGateState(control_period_ns=5_000_000, timeout_s=1.0)
    gate.tick_duty[10_000_000] = 0.3
    gate.bus_duty = 0.3
    gate.tick_output_pa[10_000_000] = 2e5
    gate.bus_output_pa = 1e5
    assert not gate.may_step(10_000_000, 5.0)
    assert gate.may_step(10_000_000, 6.1)
    assert gate.timeouts == 1 and 'output pressure' in gate.last_timeout
