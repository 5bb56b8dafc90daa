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
capture like a recording of the suite. Fields the protocol does not carry are NaN (the
driver's README lists them per protocol). Exit 2 with one line on a bad file or option.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import can

from valve_driver_pkg.devices.base import DeviceReading
from valve_driver_pkg.devices.settings import (CanopenSettings, DbcSettings, J1939Settings,
                                               build_protocol)
from valve_driver_pkg.driver.config import PROTOCOLS, DriverConfig
from valve_driver_pkg.errors import FrameRejected, ValveDriverError

__all__ = ['main', 'build_parser', 'replay']

PROG = 'valve_can_replay'
_STATE = 'valve_msgs/msg/ValveState'
_DUTY = 'valve_msgs/msg/DutyCommand'


def build_parser() -> argparse.ArgumentParser:
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
    return p


class _SuiteDecoder:
    """The suite's own protocol: ValveCommand -> duty, ValveTelemetry -> reading."""

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


def _decoder(opts: argparse.Namespace):
    if opts.protocol == 'suite':
        return _SuiteDecoder(opts.node_id)
    config = DriverConfig(protocol=opts.protocol)
    protocol = build_protocol(
        config, CanopenSettings(node_id=opts.canopen_node_id, eds_file=opts.canopen_eds_file,
                                mapping_file=opts.canopen_mapping_file),
        J1939Settings(valve_index=opts.j1939_valve_index),
        DbcSettings(file=opts.dbc_file, mapping_file=opts.dbc_mapping_file))

    class _Device:
        decode_command = staticmethod(protocol.decode_command)

        @staticmethod
        def reading(msg: can.Message) -> DeviceReading | None:
            return protocol.on_frame(msg).reading
    return _Device()


def replay(log: str, out: str, decoder, valve_name: str = 'valve') -> tuple[int, int]:
    """Write the bag of ``log``; returns (duty commands, states) written."""
    from valve_model_pkg.interface import TOPIC_DUTY_COMMAND, TOPIC_STATE
    from valve_model_pkg.recording import BagWriter, build_typestore, reliable_qos
    store = build_typestore()
    types = store.types
    counts = [0, 0]
    duty_in_force = 0.0
    with BagWriter(out, store) as writer:
        duty_conn = writer.add_topic(TOPIC_DUTY_COMMAND, _DUTY, [reliable_qos(1000)])
        state_conn = writer.add_topic(TOPIC_STATE, _STATE, [reliable_qos(1000)])
        for msg in can.LogReader(log):
            if msg.is_error_frame:
                continue
            t_ns = int(msg.timestamp * 1e9)
            header = types['std_msgs/msg/Header'](
                stamp=types['builtin_interfaces/msg/Time'](sec=t_ns // 10**9,
                                                           nanosec=t_ns % 10**9),
                frame_id=valve_name)
            duty = decoder.decode_command(msg)
            if duty is not None:
                duty_in_force = duty
                cmd = types[_DUTY](header=header, sequence=counts[0], duty=float(duty),
                                   pwm_frequency=0.0)
                writer.write(duty_conn, t_ns, bytes(store.serialize_cdr(cmd, _DUTY)))
                counts[0] += 1
                continue
            reading = decoder.reading(msg)
            if reading is None:
                continue
            position = reading.spool_position_m
            state = types[_STATE](
                header=header, sequence=counts[1], coil_voltage=reading.coil_voltage_v,
                coil_current=reading.coil_current_a, coil_current_mean=math.nan,
                coil_voltage_mean=math.nan, spool_position=position,
                spool_velocity=math.nan, spool_position_avg=math.nan, mass_flow=math.nan,
                duty=reading.duty if math.isfinite(reading.duty) else duty_in_force,
                pwm_frequency=math.nan, supply_pressure=math.nan, output_pressure=math.nan,
                source=1, position_measured=math.isfinite(position))
            writer.write(state_conn, t_ns, bytes(store.serialize_cdr(state, _STATE)))
            counts[1] += 1
    return counts[0], counts[1]


def main(args: list[str] | None = None) -> None:
    opts = build_parser().parse_args(args)
    if not Path(opts.log).is_file():
        print(f'{PROG}: error: {opts.log}: no such file', file=sys.stderr)
        sys.exit(2)
    try:
        commands, states = replay(opts.log, opts.out, _decoder(opts), opts.valve_name)
    except (ValveDriverError, ValueError, OSError) as err:
        print(f'{PROG}: error: {opts.log}: {err}', file=sys.stderr)
        sys.exit(2)
    print(f'{PROG}: {opts.out}: {commands} duty commands, {states} states from {opts.log}')


if __name__ == '__main__':
    main()
