"""What the nodes do with a message they cannot use, and how they count the command stream.

No message may end a node (docs/safety.md, "Node inputs"): every subscription checks its
message against the physical range written here, rejects what is outside with a warning
and keeps the last valid value. :class:`InputGuard` counts the rejections per input and
kind and throttles the warnings per kind (the first of each kind is always logged, so the
log names every kind of fault that happened). :class:`SequenceTracker` counts a command
stream by its ``sequence`` field, per publisher, so that a consumer reports what it lost.

ROS-free (the logger is anything with ``warning(str)``), so the CAN driver and unit tests
can use it too.
"""
from __future__ import annotations

import math
import time
from collections import OrderedDict
from collections.abc import Callable
from typing import Protocol

from valve_model_pkg.interface import (ATMOSPHERIC_PRESSURE_PA, MAX_PWM_FREQUENCY_HZ,
                                       MIN_PWM_FREQUENCY_HZ, absolute_from_gauge,
                                       gauge_from_absolute)

__all__ = ['MAX_PRESSURE_ABSOLUTE_PA', 'MAX_FLOW_COMMAND_KG_S', 'MAX_SEQUENCE_JUMP',
           'WARNING_THROTTLE_S', 'pressure_reason', 'gauge_pressure_reason', 'stamp_reason',
           'InputGuard', 'SequenceTracker', 'accept_duty_command', 'accept_pressure']

#: Highest pressure a message may carry, absolute [Pa]: 100 bar gauge, the highest
#: pressure any parameter of the suite accepts (flow_to_duty's supply_pressure_pa); a
#: pneumatic valve of this kind runs below 10 bar. 0 Pa absolute (a perfect vacuum) is legal.
MAX_PRESSURE_ABSOLUTE_PA = absolute_from_gauge(1.0e7)
#: Highest mass flow a command may ask for [kg/s]: the position controller's largest
#: ``max_mass_flow_kg_s``, about 1000 times what the paper's valve passes at 10 bar. A larger
#: command is garbage, not a request for full opening: it is rejected, not saturated.
MAX_FLOW_COMMAND_KG_S = 1.0
#: A sequence number this far ahead of the last one is a new publisher session (a
#: publisher that restarted without starting from 0, or garbage), not that many losses:
#: 10^6 commands are 17 min at 1 kHz.
MAX_SEQUENCE_JUMP = 1_000_000
#: Least time between two warnings of the same kind [s]; the first always appears.
WARNING_THROTTLE_S = 1.0


def pressure_reason(absolute_pa: float) -> str | None:
    """Why a ``sensor_msgs/FluidPressure.fluid_pressure`` (absolute [Pa]) is unusable.

    Returns ``None`` for a finite pressure in ``[0, MAX_PRESSURE_ABSOLUTE_PA]`` Pa.
    """
    if not isinstance(absolute_pa, float) or not math.isfinite(absolute_pa):
        return f'{absolute_pa!r} Pa absolute is not finite'
    if not 0.0 <= absolute_pa <= MAX_PRESSURE_ABSOLUTE_PA:
        return (f'{absolute_pa!r} Pa absolute is outside [0, {MAX_PRESSURE_ABSOLUTE_PA:g}] Pa '
                '(below a perfect vacuum or above 100 bar gauge)')
    return None


def gauge_pressure_reason(gauge_pa: float) -> str | None:
    """As :func:`pressure_reason` for a gauge pressure [Pa] (``ValveState`` fields)."""
    if not isinstance(gauge_pa, float) or not math.isfinite(gauge_pa):
        return f'{gauge_pa!r} Pa gauge is not finite'
    return pressure_reason(gauge_pa + ATMOSPHERIC_PRESSURE_PA)


def stamp_reason(stamp: object) -> str | None:
    """Why a ``builtin_interfaces/Time`` is unusable: ``nanosec`` must be below 10^9."""
    nanosec = getattr(stamp, 'nanosec', 0)
    if not 0 <= nanosec < 1_000_000_000:
        return f'header.stamp.nanosec = {nanosec} is not below 10^9'
    return None


class _Logger(Protocol):
    def warning(self, message: str) -> object: ...


class InputGuard:
    """Counts rejected messages per ``input`` and ``kind``; throttles warnings per kind.

    Parameters
    ----------
    logger : object with ``warning(str)``
        The node's logger.
    throttle_s : float
        Least time between two warnings of one kind [s]. The first warning of each kind is
        always logged; a later one says how many were not.
    clock : callable returning seconds
        Monotonic clock (for tests).
    """

    def __init__(self, logger: _Logger, throttle_s: float = WARNING_THROTTLE_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._logger = logger
        self._throttle_s = throttle_s
        self._clock = clock
        self.counts: dict[str, int] = {}
        self.total = 0
        self.last_reason = ''
        self._last_logged: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}

    def reject(self, input_name: str, kind: str, text: str) -> None:
        """Count one rejection of ``input_name`` (a topic) for ``kind``; warn if due."""
        key = f'{input_name}_{kind}'
        self.counts[key] = self.counts.get(key, 0) + 1
        self.total += 1
        self.last_reason = text
        now = self._clock()
        last = self._last_logged.get(key)
        if last is not None and now - last < self._throttle_s:
            self._suppressed[key] = self._suppressed.get(key, 0) + 1
            return
        self._last_logged[key] = now
        skipped = self._suppressed.pop(key, 0)
        more = f' ({skipped} more like it not logged)' if skipped else ''
        self._logger.warning(text + more)

    def count(self, input_name: str) -> int:
        """Rejections of one input, all kinds."""
        prefix = f'{input_name}_'
        return sum(n for k, n in self.counts.items() if k.startswith(prefix))

    def diagnostic_values(self) -> dict[str, int]:
        """``rejected_<input>_<kind>`` -> count, for the diagnostics."""
        return {f'rejected_{k}': n for k, n in sorted(self.counts.items())}


def accept_duty_command(msg: object, inputs: InputGuard,
                        frequency_in_force: Callable[[], float],
                        who: str = '') -> tuple[float, float] | None:
    """(duty, pwm_frequency_hz) to apply for a DutyCommand, or None when it is refused.

    Valid: duty and pwm_frequency finite, pwm_frequency 0 (keep the frequency in force,
    DutyCommand.msg) or within [MIN_PWM_FREQUENCY_HZ, MAX_PWM_FREQUENCY_HZ],
    header.stamp.nanosec < 10^9. A duty outside [0, 1] is clamped (and counted): the
    command's intent is plain. Refusals and clamps are counted on ``inputs`` (input
    ``duty_command``); ``who`` prefixes their messages (``'cap: '`` in a bank).

    Parameters
    ----------
    msg : valve_msgs/DutyCommand
    inputs : InputGuard
    frequency_in_force : callable returning float
        The valve's PWM frequency now [Hz], asked only for a command of frequency 0.
    who : str
    """
    duty, freq = float(msg.duty), float(msg.pwm_frequency)
    topic = 'duty_command'
    keep = '; keeping the last valid command'
    if not math.isfinite(duty) or not math.isfinite(freq):
        inputs.reject(topic, 'not_finite', f'{who}duty command rejected: duty={duty!r}, '
                      f'pwm_frequency={freq!r} is not finite' + keep)
        return None
    if freq != 0.0 and not MIN_PWM_FREQUENCY_HZ <= freq <= MAX_PWM_FREQUENCY_HZ:
        inputs.reject(topic, 'frequency_out_of_range',
                      f'{who}duty command rejected: pwm_frequency={freq!r} Hz outside '
                      f'[{MIN_PWM_FREQUENCY_HZ:g}, {MAX_PWM_FREQUENCY_HZ:g}] (0 = keep)' + keep)
        return None
    reason = stamp_reason(msg.header.stamp)
    if reason is not None:
        inputs.reject(topic, 'bad_stamp', f'{who}duty command rejected: {reason}' + keep)
        return None
    if freq == 0.0:
        freq = frequency_in_force()
    if not 0.0 <= duty <= 1.0:
        clamped = min(max(duty, 0.0), 1.0)
        inputs.reject(topic, 'duty_clamped',
                      f'{who}duty {duty!r} outside [0, 1]; clamped to {clamped:g}')
        duty = clamped
    return duty, freq


def accept_pressure(msg: object, inputs: InputGuard, port: str, who: str = '') -> float | None:
    """The gauge pressure [Pa] of a FluidPressure message (absolute), or None when refused.

    Refused (and counted on ``inputs`` as ``<port>_pressure``): a pressure that is not
    finite or outside [0, MAX_PRESSURE_ABSOLUTE_PA], or a bad stamp; the node keeps its
    last valid value. ``who`` prefixes the message.
    """
    reason = pressure_reason(float(msg.fluid_pressure))
    if reason is None:
        reason = stamp_reason(msg.header.stamp)
    if reason is not None:
        kind = 'not_finite' if 'not finite' in reason else (
            'bad_stamp' if 'stamp' in reason else 'out_of_range')
        inputs.reject(f'{port}_pressure', kind,
                      f'{who}{port} pressure rejected: {reason}; keeping the last valid value')
        return None
    return gauge_from_absolute(float(msg.fluid_pressure))


class SequenceTracker:
    """Counts a command stream by its per-publisher ``sequence`` (+1 per message).

    Publishers are told apart by a key (``header.frame_id``: rclpy's ``MessageInfo`` on
    Jazzy carries no publisher gid). Per key: the first message starts a session (messages
    before it cannot be told from messages sent before this subscriber existed); a step of
    ``n > 1`` counts ``n - 1`` lost messages; a sequence of 0 starts a new session (the
    publisher restarted); a sequence not above the last one is counted as out of order
    (duplicate, reordered, or two publishers sharing a key); a jump beyond
    :data:`MAX_SEQUENCE_JUMP` is counted as a jump and starts a new session. At most
    ``max_publishers`` keys are followed (the least recently heard is forgotten), so a
    stream of odd keys cannot grow the memory.
    """

    def __init__(self, max_publishers: int = 64) -> None:
        self._last: OrderedDict[str, int] = OrderedDict()
        self._max = max_publishers
        self.received = 0
        self.lost = 0
        self.sessions = 0
        self.out_of_order = 0
        self.jumps = 0
        self.forgotten = 0

    def update(self, key: str, sequence: int) -> int:
        """Count one message; returns the number of messages lost just before it."""
        self.received += 1
        sequence = int(sequence)
        last = self._last.get(key)
        lost = 0
        if last is None or sequence == 0:
            self.sessions += 1
            self._last[key] = sequence
        elif sequence <= last:
            self.out_of_order += 1
        elif sequence - last > MAX_SEQUENCE_JUMP:
            self.jumps += 1
            self.sessions += 1
            self._last[key] = sequence
        else:
            lost = sequence - last - 1
            self.lost += lost
            self._last[key] = sequence
        self._last.move_to_end(key)
        while len(self._last) > self._max:
            self._last.popitem(last=False)
            self.forgotten += 1
        return lost

    @property
    def publishers(self) -> int:
        """Keys (publishers) followed now."""
        return len(self._last)

    def diagnostic_values(self, prefix: str) -> dict[str, int]:
        """The counts as ``<prefix>_received`` etc., for the diagnostics."""
        return {f'{prefix}_received': self.received, f'{prefix}_lost': self.lost,
                f'{prefix}_sessions': self.sessions,
                f'{prefix}_out_of_order': self.out_of_order,
                f'{prefix}_sequence_jumps': self.jumps,
                f'{prefix}_publishers': self.publishers,
                f'{prefix}_publishers_forgotten': self.forgotten}
