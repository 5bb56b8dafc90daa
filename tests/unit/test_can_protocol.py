"""The valve CAN protocol: DBC layout, strict encoding, checks on decoding, counters, fuzzing."""
from __future__ import annotations

import math

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from valve_driver_pkg.errors import DbcError, FrameRejected, ProtocolEncodeError
from valve_driver_pkg.protocol import (COMMAND, CONTROL, PERIOD, PRESSURE, STATUS, TELEMETRY,
                                       BusCondition, CounterCheck, CounterTracker, ValveCodec,
                                       crc8, default_dbc_path, make_error_frame,
                                       parse_error_frame)
from valve_driver_pkg.protocol.codec import MAX_NODE_ID, RejectReason, frame_checksum

CODEC = ValveCodec(0, include_test_messages=True)   # the emulator's view: with CONTROL

SAMPLE_SIGNALS = {
    COMMAND: {'Duty': 0.3333, 'PwmFrequency': 50.0, 'Enable': 1, 'ClearFaults': 0,
              'HostId': 5},
    TELEMETRY: {'CoilCurrent': 0.5123, 'CoilVoltage': -23.99, 'SpoolPosition': 3.3e-4,
                'Enabled': 1, 'PositionValid': 1, 'FaultActive': 0, 'CommandTimeout': 0},
    PERIOD: {'PositionAverage': 1.2345e-4, 'DutyActive': 0.25, 'PwmFrequencyActive': 100.0},
    PRESSURE: {'SupplyPressure': 400_000.0, 'OutputPressure': -50_000.0},
    STATUS: {'DutyActive': 0.5, 'PwmFrequencyActive': 50.0, 'SupplyVoltage': 24.0,
             'FaultOvercurrent': 0, 'FaultUndervoltage': 0, 'FaultCommandTimeout': 1,
             'FaultCommandChecksum': 0, 'FaultCommandCounter': 0, 'FaultCommandRange': 0,
             'FaultOvertemperature': 0, 'FaultInternal': 0, 'ControllerState': 2},
    CONTROL: {'Fault': 4, 'Active': 1, 'Probability': 0.25, 'Duration': 1.5},
}
STEPS = {'Duty': 1e-4, 'PwmFrequency': 0.1, 'CoilCurrent': 2e-4, 'CoilVoltage': 0.01,
         'SpoolPosition': 1e-8, 'PositionAverage': 1e-8, 'DutyActive': 1e-4,
         'PwmFrequencyActive': 0.1, 'SupplyPressure': 50.0, 'OutputPressure': 50.0,
         'SupplyVoltage': 0.25, 'Probability': 1e-3, 'Duration': 1e-3}


def test_crc8_sae_j1850_check_value() -> None:
    # The catalogue check value of CRC-8/SAE-J1850 (poly 0x1D, init 0xFF, xorout 0xFF).
    assert crc8(b'123456789') == 0x4B


@pytest.mark.parametrize('name', list(SAMPLE_SIGNALS))
def test_round_trip_within_quantisation(name: str) -> None:
    msg = CODEC.encode(name, SAMPLE_SIGNALS[name], counter=7)
    assert len(msg.data) == 8 and not msg.is_extended_id
    frame = CODEC.decode(msg)
    assert (frame.name, frame.node_id, frame.counter) == (name, 0, 7)
    for signal, value in SAMPLE_SIGNALS[name].items():
        step = STEPS.get(signal, 1.0)
        assert frame.signals[signal] == pytest.approx(value, abs=step / 2 + 1e-12), signal


@pytest.mark.parametrize('node_id', [0, 1, 9, MAX_NODE_ID])
def test_node_id_selects_the_frame_ids(node_id: int) -> None:
    codec = ValveCodec(node_id, include_test_messages=True)
    assert codec.frame_id(COMMAND) == 0x680 + node_id
    assert codec.frame_id(TELEMETRY) == 0x690 + node_id
    assert codec.frame_id(PERIOD) == 0x6A0 + node_id
    assert codec.frame_id(PRESSURE) == 0x6B0 + node_id
    assert codec.frame_id(STATUS) == 0x6C0 + node_id
    assert codec.frame_id(CONTROL) == 0x6D0 + node_id
    msg = codec.encode(TELEMETRY, SAMPLE_SIGNALS[TELEMETRY], 0)
    assert codec.classify(msg.arbitration_id) == (TELEMETRY, node_id)
    assert codec.decode(msg).node_id == node_id


@pytest.mark.parametrize('node_id', [-1, MAX_NODE_ID + 1])
def test_node_id_outside_range_is_refused(node_id: int) -> None:
    with pytest.raises(ValueError, match='node id'):
        ValveCodec(node_id)


@pytest.mark.parametrize('signal, value, limit', [
    ('Duty', 1.2, '1'), ('Duty', -0.1, '0'), ('PwmFrequency', 5000.0, '1000'),
    ('PwmFrequency', 0.0, '0.1'),
])
def test_strict_encoding_names_signal_limit_and_value(
        signal: str, value: float, limit: str) -> None:
    signals = dict(SAMPLE_SIGNALS[COMMAND], **{signal: value})
    with pytest.raises(ProtocolEncodeError,
                       match=rf'"{signal}".*{limit}.*"ValveCommand".*{value}'):
        CODEC.encode(COMMAND, signals, 0)


def test_missing_signal_is_an_encode_error() -> None:
    with pytest.raises(ProtocolEncodeError, match='ValveCommand'):
        CODEC.encode(COMMAND, {'Duty': 0.5}, 0)


def _valid(name: str = TELEMETRY, node_id: int = 0) -> can.Message:
    return ValveCodec(node_id).encode(name, SAMPLE_SIGNALS[name], 3)


def _with_checksum(arbitration_id: int, data: bytes) -> can.Message:
    data = bytearray(data)
    data[7] = frame_checksum(arbitration_id, data)
    return can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False)


@pytest.mark.parametrize('make, reason', [
    (lambda: can.Message(arbitration_id=0x123, data=bytes(8), is_extended_id=False),
     RejectReason.UNKNOWN_ID),
    (lambda: _valid(node_id=5), RejectReason.UNKNOWN_ID),          # another node's frame
    (lambda: can.Message(arbitration_id=0x690, data=_valid().data[:6], is_extended_id=False),
     RejectReason.WRONG_LENGTH),
    (lambda: can.Message(arbitration_id=0x690, data=bytes(_valid().data[:7])
                         + bytes([_valid().data[7] ^ 1]), is_extended_id=False),
     RejectReason.CHECKSUM),
    (lambda: can.Message(arbitration_id=0x690, is_remote_frame=True, dlc=8,
                         is_extended_id=False), RejectReason.FRAME_TYPE),
    (lambda: can.Message(arbitration_id=0x690, data=_valid().data, is_extended_id=True),
     RejectReason.FRAME_TYPE),
    # DutyActive raw 0xFFFF = 6.5535 > 1, with a correct checksum: range check.
    (lambda: _with_checksum(0x6C0, b'\xff\xff' + bytes(_valid(STATUS).data[2:])),
     RejectReason.OUT_OF_RANGE),
])
def test_decoder_rejects_with_the_reason(make, reason: RejectReason) -> None:
    with pytest.raises(FrameRejected) as info:
        CODEC.decode(make())
    assert info.value.reason == reason.value
    assert '0x' in info.value.detail or 'signal' in info.value.detail


def test_checksum_covers_the_frame_id() -> None:
    # The same payload under another id (node 1) must not pass as node 0's frame.
    msg = _valid(node_id=1)
    moved = can.Message(arbitration_id=0x690, data=msg.data, is_extended_id=False)
    with pytest.raises(FrameRejected, match='checksum'):
        CODEC.decode(moved)


@pytest.mark.parametrize('sequence, results, lost', [
    ([3, 4], [CounterCheck.FIRST, CounterCheck.OK], 0),
    ([15, 0], [CounterCheck.FIRST, CounterCheck.OK], 0),          # wraps at 16
    ([3, 6], [CounterCheck.FIRST, CounterCheck.JUMP], 2),
    ([14, 1], [CounterCheck.FIRST, CounterCheck.JUMP], 2),
    ([9, 9], [CounterCheck.FIRST, CounterCheck.FROZEN], 0),
])
def test_counter_tracker(sequence: list[int], results: list[CounterCheck], lost: int) -> None:
    tracker = CounterTracker()
    assert [tracker.check(c) for c in sequence] == results
    assert tracker.lost == lost
    tracker.reset()
    assert tracker.check(sequence[-1]) is CounterCheck.FIRST


@pytest.mark.parametrize('condition', [BusCondition.BUS_OFF, BusCondition.ERROR_PASSIVE,
                                       BusCondition.WARNING, BusCondition.ERROR_ACTIVE,
                                       BusCondition.RESTARTED, BusCondition.OTHER])
def test_error_frames_round_trip(condition: BusCondition) -> None:
    msg = make_error_frame(condition)
    assert msg.is_error_frame
    info = parse_error_frame(msg)
    assert info.condition is condition
    assert 'error frame class' in info.text


def test_socketcan_bus_off_error_frame_is_recognised() -> None:
    # As python-can's socketcan interface delivers it: class bits in the id, flag stripped.
    msg = can.Message(arbitration_id=0x040, is_error_frame=True, data=bytes(8),
                      is_extended_id=True)
    assert parse_error_frame(msg).condition is BusCondition.BUS_OFF


def test_shipped_dbc_is_found() -> None:
    assert default_dbc_path().is_file()
    assert CODEC.dbc_path == default_dbc_path()


def test_dbc_missing_a_message_is_refused(tmp_path) -> None:
    lines = default_dbc_path().read_text().splitlines()
    start = lines.index(next(line for line in lines if line.startswith('BO_ 1696 ')))
    end = lines.index('', start)
    kept = [line for i, line in enumerate(lines)
            if not start <= i < end and not line.startswith(('CM_ BO_ 1696', 'CM_ SG_ 1696'))]
    broken = tmp_path / 'broken.dbc'
    broken.write_text('\n'.join(kept) + '\n')
    with pytest.raises(DbcError, match='ValvePeriod'):
        ValveCodec(0, broken)


def test_unreadable_dbc_is_refused(tmp_path) -> None:
    with pytest.raises(DbcError, match='cannot load DBC'):
        ValveCodec(0, tmp_path / 'missing.dbc')


frames = st.builds(
    lambda arbitration_id, data, ext, remote, error, fd: can.Message(
        arbitration_id=arbitration_id if ext else arbitration_id & 0x7FF, data=data,
        is_extended_id=ext, is_remote_frame=remote and not fd and not error,
        is_error_frame=error, is_fd=fd, check=False),
    arbitration_id=st.one_of(st.integers(0, 0x1FFFFFFF),
                             st.sampled_from([0x680, 0x690, 0x6A0, 0x6B0, 0x6C0, 0x6D0,
                                              0x691, 0x6C1])),
    data=st.binary(min_size=0, max_size=64), ext=st.booleans(), remote=st.booleans(),
    error=st.booleans(), fd=st.booleans())


@settings(max_examples=400, deadline=None)
@given(frames)
def test_decoder_fuzz_only_accepts_or_rejects(msg: can.Message) -> None:
    try:
        frame = CODEC.decode(msg)
    except FrameRejected as err:
        assert err.reason in {r.value for r in RejectReason}
        return
    assert all(math.isfinite(v) for v in frame.signals.values())


# --- the drive mode and the drive electronics are part of the protocol ---------------------------
def test_drive_mode_is_encoded_and_defaults_to_normal() -> None:
    from valve_driver_pkg.protocol import DriveMode

    old_host = CODEC.encode(COMMAND, SAMPLE_SIGNALS[COMMAND], 1)   # a 2.0 host: no DriveMode
    assert CODEC.decode(old_host).signals['DriveMode'] == DriveMode.NORMAL == 0
    bench = CODEC.encode(COMMAND, dict(SAMPLE_SIGNALS[COMMAND], DriveMode=DriveMode.BENCH), 1)
    assert CODEC.decode(bench).signals['DriveMode'] == 1
    # bit 34 (byte 4, bit 2) and the checksum are all that differ: the old signals keep
    # their bits and meaning
    assert bytes(bench.data[:7]) == bytes(old_host.data[:4]) + bytes(
        [old_host.data[4] | 0x04]) + bytes(old_host.data[5:7])
    assert bench.data[7] != old_host.data[7]
    with pytest.raises(ProtocolEncodeError, match='DriveMode'):
        CODEC.encode(COMMAND, dict(SAMPLE_SIGNALS[COMMAND], DriveMode=2), 3)


@pytest.mark.parametrize('raw', [2, 3])
def test_reserved_drive_mode_values_are_rejected(raw: int) -> None:
    msg = CODEC.encode(COMMAND, SAMPLE_SIGNALS[COMMAND], 4)
    data = bytearray(msg.data)
    data[4] |= raw << 2
    with pytest.raises(FrameRejected) as err:
        CODEC.decode(_with_checksum(msg.arbitration_id, data))
    assert err.value.reason == RejectReason.OUT_OF_RANGE.value
    assert 'DriveMode' in str(err.value)


def test_drive_mode_names_parse_and_a_bad_name_is_refused() -> None:
    from valve_driver_pkg.protocol import DriveMode

    assert DriveMode.parse('bench') is DriveMode.BENCH
    assert DriveMode.parse(' Normal ') is DriveMode.NORMAL
    with pytest.raises(ValueError, match=r"'turbo'.*'normal', 'bench'"):
        DriveMode.parse('turbo')


def test_drive_report_round_trips_on_its_extended_id() -> None:
    from valve_driver_pkg.protocol import DRIVE

    signals = {'DriveModeActive': 1, 'CapacitorVoltage': 23.8, 'HoldingCurrent': 0.4567,
               'SupplyVoltageMeasured': 24.37}
    msg = CODEC.encode(DRIVE, signals, 9)
    assert msg.is_extended_id and msg.arbitration_id == 0x16910
    frame = CODEC.decode(msg)
    assert (frame.name, frame.counter) == (DRIVE, 9)
    steps = {'CapacitorVoltage': 0.25, 'HoldingCurrent': 1e-4, 'SupplyVoltageMeasured': 0.01}
    for signal, value in signals.items():
        assert frame.signals[signal] == pytest.approx(value, abs=steps.get(signal, 1) / 2)
    moved = can.Message(arbitration_id=0x16911, data=msg.data, is_extended_id=True)
    with pytest.raises(FrameRejected):   # the checksum covers the 4 id bytes
        CODEC.decode(moved, expect_node=False)
