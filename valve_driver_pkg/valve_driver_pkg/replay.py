"""valve_can_replay: a recorded bus log (candump .log) -> the suite's bag.

Examples::

    valve_can_replay drive.log --protocol canopen --out drive_bag
    valve_can_replay board.log --protocol dbc --dbc-file board.dbc \\
        --dbc-mapping-file board_mapping.yaml --out board_bag

The log is what ``valve_can_driver -p log_frames_file:=...`` writes, or ``candump -l``.
Each host command frame becomes a ``valve/duty_command`` (valve_msgs/DutyCommand), each
device frame that reports the valve a ``valve/state`` (valve_msgs/ValveState,
``source = SOURCE_CAN``), stamped with the frame's log time, through the suite's bag
writer (``valve_model_pkg.recording``), so ``valve_identify`` reads a user's own bus
capture like a recording of the suite. Each state is built by the driver's own rule
(:class:`~valve_driver_pkg.devices.state.StateBuilder`): the measured fields from the
frame, the derived ones (position from the duty map, mass flow) from the duty last
commanded in the log, ``--pwm-frequency-hz`` and the pressures given, so the bag holds
what the driver published (the driver's README lists the fields per protocol). Exit 2 with
one line on a bad file or option.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import can

from valve_driver_pkg.devices.base import DeviceReading
from valve_driver_pkg.devices.derived import derived_opening_for
from valve_driver_pkg.devices.settings import (CanopenSettings, DbcSettings, J1939Settings,
                                               build_protocol)
from valve_driver_pkg.devices.state import CommandContext, StateBuilder
from valve_driver_pkg.driver.config import PROTOCOLS, DriverConfig
from valve_driver_pkg.errors import FrameRejected, ValveDriverError
from valve_model_pkg.model.sample import ValveSample

__all__ = ['main', 'build_parser', 'replay', 'ReplayCounts']

PROG = 'valve_can_replay'
_STATE = 'valve_msgs/msg/ValveState'
_DUTY = 'valve_msgs/msg/DutyCommand'


def build_parser() -> argparse.ArgumentParser:
    defaults = DriverConfig()
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split('\n')[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog=__doc__.split('\n', 2)[2])
    p.add_argument('log', help='candump .log file')
    p.add_argument('--protocol', choices=PROTOCOLS, required=True)
    p.add_argument('--out', required=True, help='bag folder to write')
    p.add_argument('--valve-name', default='valve', help='header.frame_id')
    p.add_argument('--node-id', type=int, default=0, help='suite: controller node id')
    p.add_argument('--canopen-node-id', type=int, default=1)
    p.add_argument('--canopen-mapping-file', default='')
    p.add_argument('--canopen-eds-file', default='')
    p.add_argument('--j1939-valve-index', type=int, default=0)
    p.add_argument('--dbc-file', default='')
    p.add_argument('--dbc-mapping-file', default='')
    p.add_argument('--params-file', default='',
                   help='valve parameter YAML (eq. 12, the duty map\'s check); default: the '
                        'suite\'s')
    p.add_argument('--duty-map-file', default='',
                   help='duty map for a device without a position; default: the suite\'s')
    p.add_argument('--pwm-frequency-hz', type=float, default=defaults.pwm_frequency_hz,
                   help='the device\'s PWM frequency where the frames carry none [Hz]')
    p.add_argument('--supply-pressure-pa', type=float, default=defaults.supply_pressure_pa,
                   help='supply pressure, gauge [Pa]')
    p.add_argument('--output-pressure-pa', type=float, default=defaults.output_pressure_pa,
                   help='output pressure, gauge [Pa]')
    return p


class _SuiteDecoder:
    """The suite's own protocol: ValveCommand -> duty, ValveTelemetry -> reading."""

    measures_position = True
    sends_pwm_frequency = True

    def __init__(self, node_id: int) -> None:
        from valve_driver_pkg.protocol.codec import ValveCodec
        self.codec = ValveCodec(node_id)

    def decode_command(self, msg: can.Message) -> float | None:
        from valve_driver_pkg.protocol.codec import COMMAND
        frame = self._decode(msg, COMMAND)
        if frame is None:
            return None
        return float(frame.signals['Duty']) if frame.signals['Enable'] else 0.0

    def reading(self, msg: can.Message) -> DeviceReading | None:
        from valve_driver_pkg.protocol.codec import TELEMETRY
        frame = self._decode(msg, TELEMETRY)
        if frame is None:
            return None
        s = frame.signals
        return DeviceReading(coil_current_a=float(s['CoilCurrent']),
                             coil_voltage_v=float(s['CoilVoltage']),
                             spool_position_m=float(s['SpoolPosition']))

    def _decode(self, msg: can.Message, name: str):
        found = self.codec.classify(msg.arbitration_id)
        if found is None or found[0] != name:
            return None
        try:
            return self.codec.decode(msg)
        except FrameRejected:
            return None


class _DeviceDecoder:
    """A device protocol read from the log: its host's commands and its readings."""

    def __init__(self, protocol) -> None:
        self.protocol = protocol
        self.measures_position = protocol.measures_position
        self.sends_pwm_frequency = protocol.sends_pwm_frequency

    def decode_command(self, msg: can.Message) -> float | None:
        return self.protocol.decode_command(msg)

    def reading(self, msg: can.Message) -> DeviceReading | None:
        return self.protocol.on_frame(msg).reading


def _decoder(opts: argparse.Namespace):
    if opts.protocol == 'suite':
        return _SuiteDecoder(opts.node_id)
    config = DriverConfig(protocol=opts.protocol)
    return _DeviceDecoder(build_protocol(
        config, CanopenSettings(node_id=opts.canopen_node_id, eds_file=opts.canopen_eds_file,
                                mapping_file=opts.canopen_mapping_file),
        J1939Settings(valve_index=opts.j1939_valve_index),
        DbcSettings(file=opts.dbc_file, mapping_file=opts.dbc_mapping_file)))


def _state_builder(opts: argparse.Namespace, decoder) -> StateBuilder:
    """The driver's rule for the fields, with the valve's parameters and duty map."""
    from valve_driver_pkg.driver.receive import mass_flow_function
    from valve_model_pkg.model import load_parameters
    params = load_parameters(opts.params_file or None)
    derived = derived_opening_for(decoder.measures_position, opts.duty_map_file, params,
                                  opts.params_file or 'the suite\'s valve.yaml',
                                  opts.pwm_frequency_hz)
    return StateBuilder(mass_flow_function(params), derived)


@dataclass(frozen=True, slots=True)
class ReplayCounts:
    """What :func:`replay` wrote."""

    duty_commands: int
    states: int


def _state_message(types, header, sequence: int, sample: ValveSample):
    return types[_STATE](
        header=header, sequence=sequence, coil_voltage=sample.coil_voltage_v,
        coil_current=sample.coil_current_a, coil_current_mean=sample.coil_current_mean_a,
        coil_voltage_mean=sample.coil_voltage_mean_v, spool_position=sample.spool_position_m,
        spool_velocity=sample.spool_velocity_m_s, spool_position_avg=sample.position_avg_m,
        mass_flow=sample.mass_flow_kg_s, duty=sample.duty,
        pwm_frequency=sample.pwm_frequency_hz, supply_pressure=sample.supply_pressure_pa,
        output_pressure=sample.output_pressure_pa, source=1,
        position_measured=sample.position_measured)


def replay(log: str, out: str, decoder, builder: StateBuilder, command: CommandContext,
           valve_name: str = 'valve') -> ReplayCounts:
    """Write the bag of ``log``: the host's commands and the device's states.

    ``command`` holds the frequency and pressures in force; its duty is replaced by the
    duty of each command frame as the log goes on.
    """
    from dataclasses import replace

    from valve_model_pkg.interface import TOPIC_DUTY_COMMAND, TOPIC_STATE
    from valve_model_pkg.recording import BagWriter, build_typestore, reliable_qos
    store = build_typestore()
    types = store.types
    commands = states = 0
    with BagWriter(out, store) as writer:
        duty_conn = writer.add_topic(TOPIC_DUTY_COMMAND, _DUTY, [reliable_qos(1000)])
        state_conn = writer.add_topic(TOPIC_STATE, _STATE, [reliable_qos(1000)])
        for msg in can.LogReader(log):
            if msg.is_error_frame:
                continue
            t_ns = int(round(msg.timestamp * 1e9))
            header = types['std_msgs/msg/Header'](
                stamp=types['builtin_interfaces/msg/Time'](sec=t_ns // 10**9,
                                                           nanosec=t_ns % 10**9),
                frame_id=valve_name)
            duty = decoder.decode_command(msg)
            if duty is not None:
                command = replace(command, duty_sent=float(duty))
                cmd = types[_DUTY](header=header, sequence=commands, duty=float(duty),
                                   pwm_frequency=0.0)
                writer.write(duty_conn, t_ns, bytes(store.serialize_cdr(cmd, _DUTY)))
                commands += 1
                continue
            reading = decoder.reading(msg)
            if reading is None:
                continue
            sample = builder.sample(reading, command, msg.timestamp, msg.timestamp)
            state = _state_message(types, header, states, sample)
            writer.write(state_conn, t_ns, bytes(store.serialize_cdr(state, _STATE)))
            states += 1
    return ReplayCounts(commands, states)


def main(args: list[str] | None = None) -> None:
    opts = build_parser().parse_args(args)
    if not Path(opts.log).is_file():
        print(f'{PROG}: error: {opts.log}: no such file', file=sys.stderr)
        sys.exit(2)
    try:
        decoder = _decoder(opts)
        command = CommandContext(0.0, opts.pwm_frequency_hz, decoder.sends_pwm_frequency,
                                 opts.supply_pressure_pa, opts.output_pressure_pa)
        counts = replay(opts.log, opts.out, decoder, _state_builder(opts, decoder), command,
                        opts.valve_name)
    except (ValveDriverError, ValueError, OSError) as err:
        print(f'{PROG}: error: {opts.log}: {err}', file=sys.stderr)
        sys.exit(2)
    print(f'{PROG}: {opts.out}: {counts.duty_commands} duty commands, {counts.states} states '
          f'from {opts.log}')


if __name__ == '__main__':
    main()
