"""What the driver core asks of a device protocol (CANopen, J1939, a user's DBC).

A :class:`DeviceProtocol` turns the host's command (duty, enable) into the device's frames,
reads the device's frames into a :class:`DeviceReading`, sets the device up, and says how
often the device speaks (its liveness period). The core
(:class:`~valve_driver_pkg.devices.core.DeviceDriverCore`) owns the bus, the threads, the
command watchdog, the liveness judgement and the diagnostics; a protocol never sends by
itself except through the ``send`` function it is attached with.

Threads: :meth:`DeviceProtocol.on_frame` runs on the receive thread;
:meth:`DeviceProtocol.setup` on the caller's thread (configure) or the core's set-up
thread (a device that rebooted), never on the receive thread, since it waits for answers
that the receive thread delivers; the frame builders run on the I/O thread.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import can

from valve_driver_pkg.driver.core_base import ClearResult

__all__ = ['DeviceReading', 'FrameOutcome', 'DeviceFault', 'DeviceProtocol', 'SendFunction',
           'LIVENESS_PERIODS']

#: ``send(msg) -> bool``: put one frame on the bus (False: not sent).
SendFunction = Callable[[can.Message], bool]
#: A device silent for this many of its periods is lost (ERROR; valve/state stops).
LIVENESS_PERIODS = 3


@dataclass(frozen=True, slots=True)
class DeviceReading:
    """What one device frame reports; NaN where this frame carries nothing.

    ``duty`` is the opening in force as the device reports it (J1939 Estimated Flow / 100);
    NaN means the device does not report it and the core takes the duty last sent.
    """

    duty: float = math.nan
    coil_current_a: float = math.nan
    coil_voltage_v: float = math.nan
    spool_position_m: float = math.nan


@dataclass(frozen=True, slots=True)
class FrameOutcome:
    """What a received frame meant: from the device (liveness), a reading to publish."""

    from_device: bool = False
    reading: DeviceReading | None = None


@dataclass(frozen=True, slots=True)
class DeviceFault:
    """A fault the device reports (EMCY, DM1) or a problem with it (SDO abort, claim)."""

    text: str
    error: bool = True          # False: a warning
    values: dict = field(default_factory=dict)


class DeviceProtocol:
    """Base class of the device protocols; subclasses override the hooks below.

    Attributes
    ----------
    name : str
        ``'canopen'``, ``'j1939'`` or ``'dbc'``.
    label : str
        The device in diagnostics names and the hardware id (``'canopen node 5'``).
    command_period_s : float
        The command frames go out at once on a change and then every this long [s].
    liveness_period_s : float
        The device's own cyclic period [s] (heartbeat, Estimated Flow, status message);
        silence for :data:`LIVENESS_PERIODS` of them is a lost device. ``inf`` when the
        protocol receives nothing from the device.
    needs_setup : bool
        Set (receive thread) when the device asks to be set up again (a boot-up frame).
    sends_pwm_frequency : bool
        The command frames carry the PWM frequency (then it is the one in force).
    measures_position : bool
        The device reports the spool position (else the driver derives it).
    clear_timeout_s : float
        How long :meth:`clear_faults` waits for the device's answer by default [s].
    """

    name = ''
    sends_pwm_frequency = False
    measures_position = False
    clear_timeout_s = 1.0

    def __init__(self, label: str, command_period_s: float, liveness_period_s: float) -> None:
        self.label = label
        self.command_period_s = command_period_s
        self.liveness_period_s = liveness_period_s
        self.needs_setup = False
        self._send: SendFunction = lambda msg: False

    def attach(self, send: SendFunction, bus: can.BusABC | None) -> None:
        """A bus is open (again): frames go out through ``send``; ``bus`` is the raw bus."""
        self._send = send

    def setup(self, timeout_s: float) -> None:
        """Set the device up (blocking, bounded by ``timeout_s``); nothing to do by default.

        Raises
        ------
        DeviceSetupError
            No answer in time, or the device refused; the message says which and why.
        """

    def start_frames(self) -> list[can.Message]:
        """Frames that start the device on activate (CANopen: NMT start)."""
        return []

    def set_frequency(self, pwm_frequency_hz: float) -> None:
        """The PWM frequency in force [Hz] (only protocols that carry one use it)."""

    def command_frames(self, duty: float, enable: bool) -> list[can.Message]:
        """The command frames for ``duty`` in [0, 1] (already clamped) and ``enable``."""
        raise NotImplementedError

    def decode_command(self, msg: can.Message) -> float | None:
        """The duty a host's command frame carries (replay of a bus log); None if no command."""
        return None

    def own_frames(self, now: float, active: bool) -> list[can.Message]:
        """Frames of the protocol's own timing that are due at ``now`` (heartbeat)."""
        return []

    def next_own_due(self) -> float:
        """Monotonic time the next own frame is due (``inf``: none)."""
        return math.inf

    def on_frame(self, msg: can.Message) -> FrameOutcome:
        """Interpret one received frame (receive thread)."""
        return FrameOutcome()

    def faults(self) -> list[DeviceFault]:
        """Faults in force now (EMCY, DM1, refused set-up, lost address claim)."""
        return []

    def clear_faults(self, timeout_s: float) -> ClearResult:
        """Ask the device to clear its faults as the protocol allows; say what is left.

        Called on a thread of its own (the node's service), never the receive thread. By
        default the protocol has no such request: refused, naming the faults in force.
        """
        active = tuple(f.text for f in self.faults())
        return ClearResult(False, (), active,
                           f'not cleared: protocol {self.name} has no request to clear a '
                           'device\'s faults (clear them at the device); active: '
                           f'{", ".join(active) or "nothing"}')

    def bus_problem(self) -> str:
        """A problem of the host on the bus (J1939: address claim lost); '' if none."""
        return ''

    def describe(self) -> dict:
        """Values for the device status (ids, mapping)."""
        return {}

    def close(self) -> None:
        """Release what the protocol holds (safe twice)."""
