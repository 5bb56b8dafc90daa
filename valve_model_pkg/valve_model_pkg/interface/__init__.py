"""The suite's interface facts, defined once (no ROS import here).

Topic names and their message types, and the physical constants the messages need, for
every node, the recorder, the report, the demo and the driver. The ROS objects built from
them (QoS profiles, the sample -> ``valve_msgs/ValveState`` conversion, log forwarding)
are in :mod:`valve_model_pkg.interface.ros`.

Topic names are relative, so a namespace (``/left/valve/state``) moves a whole valve.
"""
from __future__ import annotations

from valve_model_pkg.model.constants import (ATMOSPHERIC_PRESSURE_PA, absolute_from_gauge,
                                             gauge_from_absolute)

__all__ = [
    'ATMOSPHERIC_PRESSURE_PA', 'absolute_from_gauge', 'gauge_from_absolute',
    'TOPIC_STATE', 'TOPIC_DUTY_COMMAND', 'TOPIC_FLOW_COMMAND', 'TOPIC_SUPPLY_PRESSURE',
    'TOPIC_OUTPUT_PRESSURE', 'TOPIC_FLOW_STATUS', 'TOPIC_DIAGNOSTICS',
    'TOPIC_JOINT_STATES', 'TOPIC_POSITION_SETPOINT', 'TOPIC_POSITION_GOAL', 'TOPIC_CLOCK',
    'TOPIC_REAL_TIME_FACTOR', 'TOPIC_RUN_UNTIL', 'SUITE_TOPICS',
    'STATE_QUEUE_DEPTH', 'COMMAND_QUEUE_DEPTH', 'JOINT_STATES_QUEUE_DEPTH',
    'DIAGNOSTICS_QUEUE_DEPTH', 'MIN_PWM_FREQUENCY_HZ', 'MAX_PWM_FREQUENCY_HZ',
    'STATE_SOURCE_SIMULATOR',
]

TOPIC_STATE = 'valve/state'                      # valve_msgs/ValveState
TOPIC_DUTY_COMMAND = 'valve/duty_command'        # valve_msgs/DutyCommand
TOPIC_FLOW_COMMAND = 'valve/flow_command'        # valve_msgs/FlowCommand
TOPIC_SUPPLY_PRESSURE = 'valve/supply_pressure'  # sensor_msgs/FluidPressure (absolute Pa)
TOPIC_OUTPUT_PRESSURE = 'valve/output_pressure'  # sensor_msgs/FluidPressure (absolute Pa)
TOPIC_FLOW_STATUS = 'valve/flow_to_duty_status'  # valve_msgs/FlowToDutyStatus
TOPIC_DIAGNOSTICS = '/diagnostics'               # diagnostic_msgs/DiagnosticArray
TOPIC_JOINT_STATES = 'cylinder/joint_states'     # sensor_msgs/JointState
TOPIC_POSITION_SETPOINT = 'cylinder/position_setpoint'  # std_msgs/Float64 [m]
TOPIC_POSITION_GOAL = 'cylinder/position_goal'  # std_msgs/Float64 [m]
TOPIC_CLOCK = '/clock'                           # rosgraph_msgs/Clock (simulation time)
TOPIC_REAL_TIME_FACTOR = 'simulation/real_time_factor'  # std_msgs/Float64 [1]
TOPIC_RUN_UNTIL = 'simulation/run_until'        # std_msgs/Float64, simulation time [s]

#: Topic name (relative, as the nodes use it) -> message type, for every topic of the suite.
SUITE_TOPICS: dict[str, str] = {
    TOPIC_STATE: 'valve_msgs/msg/ValveState',
    TOPIC_DUTY_COMMAND: 'valve_msgs/msg/DutyCommand',
    TOPIC_FLOW_COMMAND: 'valve_msgs/msg/FlowCommand',
    TOPIC_SUPPLY_PRESSURE: 'sensor_msgs/msg/FluidPressure',
    TOPIC_OUTPUT_PRESSURE: 'sensor_msgs/msg/FluidPressure',
    TOPIC_FLOW_STATUS: 'valve_msgs/msg/FlowToDutyStatus',
    TOPIC_DIAGNOSTICS: 'diagnostic_msgs/msg/DiagnosticArray',
    TOPIC_JOINT_STATES: 'sensor_msgs/msg/JointState',
    TOPIC_POSITION_SETPOINT: 'std_msgs/msg/Float64',
    TOPIC_POSITION_GOAL: 'std_msgs/msg/Float64',
}

#: valve/state at 1 kHz: a deep queue so a slow subscriber (the recorder) does not lose
#: a burst; 1000 = 1 s of state.
STATE_QUEUE_DEPTH = 1000
#: Commands and pressures. Documented command rate: up to 1 kHz per publisher (the
#: position controller commands flow at 200 Hz by default, flow_to_duty answers every flow
#: command and re-evaluates at most 100 Hz, pressures come at 200 Hz-1 kHz). 1000 = 1 s of
#: commands at 1 kHz: a subscriber held up for up to 1 s loses none; beyond that the oldest
#: are dropped and the consumers report them as lost (sequence gaps; docs/safety.md).
COMMAND_QUEUE_DEPTH = 1000
#: cylinder/joint_states at 200 Hz: 50 = 0.25 s.
JOINT_STATES_QUEUE_DEPTH = 50
#: /diagnostics at about 1 Hz per node.
DIAGNOSTICS_QUEUE_DEPTH = 10

#: The accepted main PWM frequencies [Hz], one pair for the simulator node, the CAN driver
#: and the DBC (``ValveCommand.PwmFrequency`` min/max; a test checks they agree). 0.1 Hz is
#: the product's lowest frequency and the smallest non-zero value of the DBC signal (0.1 Hz
#: steps); 1000 Hz covers the product's 0.1-200 Hz with margin for test benches (the
#: model's chopper runs far above it) and is what every backend accepted before.
MIN_PWM_FREQUENCY_HZ = 0.1
MAX_PWM_FREQUENCY_HZ = 1000.0

#: ``ValveState.source`` of a state made by the suite's own simulator
#: (``ValveState.SOURCE_SIMULATOR``), for the ROS-free readers of recorded bags.
STATE_SOURCE_SIMULATOR = 0
