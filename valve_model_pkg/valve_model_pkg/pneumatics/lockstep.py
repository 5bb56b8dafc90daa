"""Simulation time in lockstep with a controller: the protocol's bookkeeping (no ROS here).

The lockstep simulation node (``valve_lockstep_sim``) owns the simulation clock. Its
protocol over topics, for a step of ``step_ns`` and a control tick every
``control_period_ns`` (a multiple of the step):

1. At a control tick T the simulation publishes, in this order, every valve's
   ``valve/output_pressure`` (the chamber pressure), ``cylinder/joint_states``, and
   ``/clock`` = T, all stamped T; every step it publishes each ``valve/state``.
2. The controller (``position_controller`` with ``lockstep:=true``) answers each joint state
   of a new tick with one ``valve/flow_command`` stamped T (per valve);
   ``flow_to_duty`` (``lockstep:=true``) answers each flow command with one
   ``valve/duty_command`` stamped with the flow command's stamp, computed with the output
   pressure stamped T (it waits for that pressure if the command overtook it).
3. The simulation advances past T only when every valve has a duty command stamped >= T
   (the first tick, t = 0, included: its answers may come while the simulation is held;
   with an external valve the valve's side holds that gate);
   an answer stamped older than the valve's newest is not applied.
   If one does not come within ``timeout_s`` of wall-clock time, the simulation goes on
   with the command in force and counts a *lockstep timeout* (diagnostics, report): the
   run is then no longer deterministic, and says so.
4. While it waits longer than ``resend_s`` it publishes tick T's messages again (a node
   that started late, or whose reader matched the publisher late, gets them; the
   controller answers a tick it already answered again with the same flow command, and
   ``flow_to_duty`` that with the same duty command, so a lost answer comes again and an
   answer that was not lost changes nothing). With an external valve the same holds for
   a step whose ``valve/state`` is overdue: the valve's side waits for tick T's duty
   command and output pressure before it advances past T, so T's pressures and joint
   states go out again, with the step's ``/clock`` (never T's: the clock never goes
   back).

With an external valve (``valve_source:=external``: the CAN controller emulator on the
simulation clock, read through the CAN driver) the simulation first holds a *start
handshake* (:class:`StartHandshake`): it asks for the first step only after one
``valve/state`` of every valve reached it at t = 0 -- the emulator sends its t = 0 frames
once, when the driver is on the bus and the simulation's clock reaches it -- so the whole
chain emulator -> CAN -> driver -> ``valve/state`` is known to carry the first step's
state. No t = 0 state can then arrive while a step waits (there is only one).

``simulation/run_until`` (std_msgs/Float64, seconds of simulation time) holds the
simulation at that time (a driver such as the demo sends goals while it is held, so they
take effect at a known tick); ``start_paused`` holds it at t = 0 until the first one.

The pace: at most ``real_time_factor_max`` seconds of simulation per second of wall time
(default 1: as fast as a real machine, never faster); 0 = as fast as possible. The pace
starts afresh after every hold or wait, so the simulation never races to catch up.

:class:`Pacer` and :class:`LockstepGate` are the ROS-free parts (tested alone).
"""
from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ['Pacer', 'LockstepGate', 'RealTimeFactor', 'StartHandshake']


@dataclass
class Pacer:
    """Caps the simulation's pace at ``max_factor`` x wall time (0 = no cap).

    Parameters
    ----------
    max_factor : float
        Largest real-time factor; 0 = as fast as possible.
    slack_s : float
        How far behind the pace the simulation may fall before the pace restarts from
        where it is (it then does not catch up faster than ``max_factor``) [s].
    """

    max_factor: float = 1.0
    slack_s: float = 0.05
    _wall0: float | None = None
    _sim0_ns: int = 0

    def restart(self, wall_s: float, sim_ns: int) -> None:
        """Start pacing afresh from (wall, simulation) time (after a hold or a wait)."""
        self._wall0, self._sim0_ns = wall_s, sim_ns

    def may_step(self, wall_s: float, sim_ns: int) -> bool:
        """Whether the simulation, at ``sim_ns``, may take its next step at ``wall_s``."""
        if self.max_factor <= 0.0:
            return True
        if self._wall0 is None:
            self.restart(wall_s, sim_ns)
        due = self._wall0 + (sim_ns - self._sim0_ns) * 1e-9 / self.max_factor
        if wall_s < due:
            return False
        if wall_s - due > self.slack_s:  # fell behind: never race to catch up
            self.restart(wall_s, sim_ns)
        return True

    def wait_s(self, wall_s: float, sim_ns: int) -> float:
        """Wall time until the next step is due [s] (0 if it is)."""
        if self.max_factor <= 0.0 or self._wall0 is None:
            return 0.0
        due = self._wall0 + (sim_ns - self._sim0_ns) * 1e-9 / self.max_factor
        return max(0.0, due - wall_s)


@dataclass
class LockstepGate:
    """Which valves still owe the duty command of the tick in force.

    Parameters
    ----------
    names : tuple of str
        The valves that must answer each tick.
    timeout_s : float
        Wall time after which the simulation stops waiting for a tick [s].
    """

    names: tuple[str, ...]
    timeout_s: float = 1.0
    tick_ns: int | None = None
    waiting_since_s: float = 0.0
    owed: set[str] = field(default_factory=set)
    timeouts: int = 0
    ticks: int = 0
    max_wait_s: float = 0.0
    last_timeout: str = ''
    newest_ns: dict[str, int] = field(default_factory=dict)

    def open_tick(self, tick_ns: int, wall_s: float) -> None:
        """A control tick was published: every valve owes its answer, but one whose answer
        to this tick came already (the first tick's, answered while the simulation was
        held before it could open it)."""
        self.tick_ns = tick_ns
        self.waiting_since_s = wall_s
        self.owed = {n for n in self.names if self.newest_ns.get(n, -1) < tick_ns}
        self.ticks += 1

    def is_stale(self, name: str, stamp_ns: int) -> bool:
        """True for an answer older than valve ``name``'s newest one (a tick's answer sent
        again that overtook nothing): applying it would undo the newer command."""
        return stamp_ns < self.newest_ns.get(name, -1)

    def answer(self, name: str, stamp_ns: int, wall_s: float) -> None:
        """Valve ``name``'s duty command stamped ``stamp_ns`` arrived."""
        self.newest_ns[name] = max(stamp_ns, self.newest_ns.get(name, -1))
        if self.owed and self.tick_ns is not None and stamp_ns >= self.tick_ns:
            self.owed.discard(name)
            if not self.owed:
                self.max_wait_s = max(self.max_wait_s, wall_s - self.waiting_since_s)

    @property
    def waiting(self) -> bool:
        """Whether some valve still owes its answer."""
        return bool(self.owed)

    def check_timeout(self, wall_s: float) -> bool:
        """Give up on the tick if it waited ``timeout_s``; returns True if it gave up."""
        if self.owed and wall_s - self.waiting_since_s > self.timeout_s:
            names = ', '.join(repr(n) for n in sorted(self.owed))
            self.last_timeout = (f'no duty command for tick t = {self.tick_ns * 1e-9:.3f} s '
                                 f'from valve(s) {names} within {self.timeout_s:g} s')
            self.timeouts += 1
            self.owed.clear()
            return True
        return False


@dataclass
class StartHandshake:
    """External valves: which still owe their t = 0 state before the first step.

    Parameters
    ----------
    names : tuple of str
        The valves whose state must arrive.
    timeout_s : float
        Wall time the simulation waits for the states, once it wants to run, before it
        gives up, counts a lockstep timeout and asks for the first step anyway [s].
    """

    names: tuple[str, ...]
    timeout_s: float = 10.0
    seen: set[str] = field(default_factory=set)
    gave_up: bool = False
    waiting_since_s: float | None = None
    last_timeout: str = ''

    @property
    def ready(self) -> bool:
        """Whether the first step may be asked for (every state came, or it gave up)."""
        return self.gave_up or self.seen >= set(self.names)

    def state(self, name: str) -> bool:
        """Valve ``name``'s state arrived before the first step; True if that made it ready."""
        before = self.ready
        if name in self.names:
            self.seen.add(name)
        return self.ready and not before

    def check_timeout(self, wall_s: float) -> bool:
        """The simulation wants to run at ``wall_s`` and is not ready: give up if it waited
        ``timeout_s`` (returns True then, once)."""
        if self.ready:
            return False
        if self.waiting_since_s is None:
            self.waiting_since_s = wall_s
            return False
        if wall_s - self.waiting_since_s <= self.timeout_s:
            return False
        missing = ', '.join(repr(n) for n in sorted(set(self.names) - self.seen))
        self.last_timeout = (f'no valve/state at t = 0 from valve(s) {missing} within '
                             f'{self.timeout_s:g} s (start handshake)')
        self.gave_up = True
        return True


@dataclass
class RealTimeFactor:
    """Simulation seconds per wall second, over the whole run and over a recent window."""

    window_s: float = 1.0
    _start: tuple[float, int] | None = None
    _window: tuple[float, int] | None = None
    last_window: float = 0.0

    def update(self, wall_s: float, sim_ns: int) -> None:
        """Record the (wall, simulation) time of now."""
        if self._start is None:
            self._start = self._window = (wall_s, sim_ns)
            return
        w0, s0 = self._window
        if wall_s - w0 >= self.window_s:
            self.last_window = (sim_ns - s0) * 1e-9 / (wall_s - w0)
            self._window = (wall_s, sim_ns)

    def overall(self, wall_s: float, sim_ns: int) -> float:
        """Simulation time / wall time since the first update."""
        if self._start is None or wall_s <= self._start[0]:
            return 0.0
        return (sim_ns - self._start[1]) * 1e-9 / (wall_s - self._start[0])
