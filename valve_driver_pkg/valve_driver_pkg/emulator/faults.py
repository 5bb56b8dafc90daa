"""Fault injection state of the controller emulator: what is active, until when, how often."""
from __future__ import annotations

import random
import threading
from dataclasses import dataclass

from valve_driver_pkg.protocol.codec import EmulatorFault

__all__ = ['ActiveFault', 'FaultInjector', 'EmulatorRemote', 'parse_fault_spec', 'FAULT_NAMES']

#: Command-line / API names of the faults (lower case of the enum member).
FAULT_NAMES = {f.name.lower(): f for f in EmulatorFault if f is not EmulatorFault.CLEAR_ALL}


@dataclass(frozen=True, slots=True)
class ActiveFault:
    """One injected fault.

    Attributes
    ----------
    fault : EmulatorFault
    probability : float
        Per-frame probability for the per-frame faults (drop, corrupt, wrong length,
        unknown id); 1.0 = every frame.
    until_s : float | None
        Model time at which the fault ends by itself; ``None`` = until cleared.
    """

    fault: EmulatorFault
    probability: float = 1.0
    until_s: float | None = None


class FaultInjector:
    """Thread-safe set of active faults with expiry; the emulator asks it frame by frame.

    Parameters
    ----------
    seed : int | None
        Seed of the random draws of the probabilistic faults (reproducible tests).
    """

    def __init__(self, seed: int | None = None) -> None:
        self._lock = threading.Lock()
        self._active: dict[EmulatorFault, ActiveFault] = {}
        self._rng = random.Random(seed)

    def activate(self, fault: EmulatorFault, now_s: float, probability: float = 1.0,
                 duration_s: float = 0.0) -> None:
        """Switch ``fault`` on at model time ``now_s`` (``duration_s`` 0 = until cleared)."""
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f'fault probability {probability!r} outside [0, 1]')
        if duration_s < 0.0:
            raise ValueError(f'fault duration {duration_s!r} s is negative')
        if fault is EmulatorFault.CLEAR_ALL:
            self.clear()
            return
        until = now_s + duration_s if duration_s > 0.0 else None
        with self._lock:
            self._active[fault] = ActiveFault(fault, probability, until)

    def clear(self, fault: EmulatorFault | None = None) -> None:
        """Switch one fault (or all, ``None``) off."""
        with self._lock:
            if fault is None:
                self._active.clear()
            else:
                self._active.pop(fault, None)

    def expire(self, now_s: float) -> list[EmulatorFault]:
        """Remove the faults whose time is up; return them (the emulator reacts to ends)."""
        with self._lock:
            ended = [f for f, a in self._active.items()
                     if a.until_s is not None and now_s >= a.until_s]
            for fault in ended:
                del self._active[fault]
        return ended

    def is_active(self, fault: EmulatorFault) -> bool:
        """True while ``fault`` is injected."""
        return fault in self._active

    def hits(self, fault: EmulatorFault) -> bool:
        """True if ``fault`` is active and its per-frame draw says this frame is affected."""
        active = self._active.get(fault)
        if active is None:
            return False
        return active.probability >= 1.0 or self._rng.random() < active.probability

    def snapshot(self) -> dict[str, ActiveFault]:
        """Copy of the active faults by name."""
        with self._lock:
            return {f.name.lower(): a for f, a in self._active.items()}


def parse_fault_spec(text: str) -> tuple[EmulatorFault, float, float, float]:
    """Parse ``NAME[:START_S[:DURATION_S[:PROBABILITY]]]`` from the command line.

    Returns
    -------
    tuple
        ``(fault, start_s, duration_s, probability)``; start is model time after launch,
        duration 0 means until the end.

    Raises
    ------
    ValueError
        Unknown name or a bad number; the message lists the valid names.
    """
    parts = text.split(':')
    name = parts[0].strip().lower()
    if name not in FAULT_NAMES:
        raise ValueError(f'unknown fault {parts[0]!r}; expected one of '
                         f'{", ".join(sorted(FAULT_NAMES))}')
    try:
        numbers = [float(p) for p in parts[1:]]
    except ValueError as err:
        raise ValueError(f'fault {text!r}: {err}') from err
    if len(numbers) > 3:
        raise ValueError(f'fault {text!r}: expected NAME[:START_S[:DURATION_S[:PROBABILITY]]]')
    start, duration, probability = (numbers + [0.0, 0.0, 1.0][len(numbers):])[:3]
    if start < 0.0 or duration < 0.0 or not 0.0 <= probability <= 1.0:
        raise ValueError(f'fault {text!r}: start and duration must be >= 0, probability in '
                         '[0, 1]')
    return FAULT_NAMES[name], start, duration, probability


class EmulatorRemote:
    """Switches the faults of an emulator in another process with ``EmulatorControl`` frames.

    Parameters
    ----------
    bus : can.BusABC
        A bus on which the emulator listens (e.g. a ``TcpLoopbackBus`` on its hub).
    node_id : int
        The emulator's node id.
    """

    def __init__(self, bus, node_id: int = 0, codec=None) -> None:
        from valve_driver_pkg.protocol.codec import ValveCodec

        self.bus = bus
        self.codec = codec or ValveCodec(node_id, include_test_messages=True)
        self._counter = 0

    def frame(self, fault: EmulatorFault, active: bool = True, probability: float = 1.0,
              duration_s: float = 0.0):
        """The ``EmulatorControl`` frame for this request (counter advanced)."""
        msg = self.codec.encode('EmulatorControl', {
            'Fault': int(fault), 'Active': int(active), 'Probability': probability,
            'Duration': duration_s}, self._counter)
        self._counter = (self._counter + 1) & 0xF
        return msg

    def inject(self, fault: EmulatorFault, probability: float = 1.0,
               duration_s: float = 0.0) -> None:
        """Switch ``fault`` on (for ``duration_s``, 0 = until cleared)."""
        self.bus.send(self.frame(fault, True, probability, duration_s))

    def clear(self, fault: EmulatorFault = EmulatorFault.CLEAR_ALL) -> None:
        """Switch one fault, or all, off."""
        self.bus.send(self.frame(fault, False))
