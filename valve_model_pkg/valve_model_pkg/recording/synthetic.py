"""Synthetic serialized messages of the suite, for tests and benchmarks of the bag code.

The values follow a plausible PWM pattern but are not a valve simulation; what matters is
that the bytes are real CDR of the suite's message types, with continuous sequence numbers
and stamps, as the recorder receives them.
"""
from __future__ import annotations

from rosbags.typesys.store import Typestore

__all__ = ['VALVE_STATE', 'DUTY_COMMAND', 'valve_state_cdr', 'duty_command_cdr']

VALVE_STATE = 'valve_msgs/msg/ValveState'
DUTY_COMMAND = 'valve_msgs/msg/DutyCommand'


def _stamp(store: Typestore, t_ns: int) -> object:
    time_cls = store.types['builtin_interfaces/msg/Time']
    return time_cls(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000)


def valve_state_cdr(store: Typestore, n: int, *, start_ns: int = 1_700_000_000_000_000_000,
                    period_ns: int = 1_000_000, first_sequence: int = 0,
                    frame_id: str = 'valve') -> list[tuple[int, bytes]]:
    """``n`` ValveState messages as ``(stamp_ns, cdr_bytes)``, one every ``period_ns``.

    Parameters
    ----------
    store : rosbags Typestore
        Must know ``valve_msgs/msg/ValveState`` (see :func:`.typestore.build_typestore`).
    n : int
        Number of messages.
    start_ns, period_ns : int
        Stamp of the first message and the spacing [ns].
    first_sequence : int
        ``sequence`` of the first message; +1 per message.
    frame_id : str
        ``header.frame_id`` (the valve name).
    """
    cls = store.types[VALVE_STATE]
    header_cls = store.types['std_msgs/msg/Header']
    out = []
    for i in range(n):
        t = start_ns + i * period_ns
        phase = (i % 20) / 20.0  # 50 Hz PWM at 1 kHz sampling
        on = phase < 0.6
        msg = cls(header=header_cls(stamp=_stamp(store, t), frame_id=frame_id),
                  sequence=first_sequence + i, coil_voltage=24.0 if on else -12.0 * (phase < 0.65),
                  coil_current=0.5 * on, coil_current_mean=0.5 * on,
                  coil_voltage_mean=24.0 if on else 0.0, spool_position=0.33e-3 * on,
                  spool_velocity=0.0, spool_position_avg=0.2e-3, mass_flow=1.0e-3 * on,
                  duty=0.6, pwm_frequency=50.0, supply_pressure=4.0e5, output_pressure=0.0,
                  source=0, position_measured=False)
        out.append((t, bytes(store.serialize_cdr(msg, VALVE_STATE))))
    return out


def duty_command_cdr(store: Typestore, duties: list[float], *,
                     start_ns: int = 1_700_000_000_000_000_000, period_ns: int = 20_000_000,
                     pwm_frequency_hz: float = 50.0) -> list[tuple[int, bytes]]:
    """DutyCommand messages, one per duty in ``duties``, as ``(stamp_ns, cdr_bytes)``."""
    cls = store.types[DUTY_COMMAND]
    header_cls = store.types['std_msgs/msg/Header']
    out = []
    for i, duty in enumerate(duties):
        t = start_ns + i * period_ns
        msg = cls(header=header_cls(stamp=_stamp(store, t), frame_id=''), sequence=i,
                  duty=float(duty), pwm_frequency=float(pwm_frequency_hz))
        out.append((t, bytes(store.serialize_cdr(msg, DUTY_COMMAND))))
    return out
