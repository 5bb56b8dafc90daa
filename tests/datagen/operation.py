"""Operational records (``experiment: operation``) from the truth valve with its own driver.

What a valve in service reports: the main PWM command in force and the coil current as a
1 ms interval mean, with the drive electronics on. The valve is the independent truth model
of :mod:`.truth` (its :class:`~.truth._Truth` right-hand side, flux, force and the effects);
the drive electronics are written here again, in a form of their own, independently of the
suite's (``valve_model_pkg.model.electronics`` / ``kernel``, which this module never
imports), so a shared mistake cannot hide itself in the data:

1. **Main PWM.** A schedule of periods (frequency 20-100 Hz, duty per period); the command
   in force changes only at a period start.
2. **Boost.** At each rising edge the supply voltage is applied. An analogue peak/valley
   detector watches the coil current at every integration step: it arms once the current
   has fallen ``dip_threshold_a`` below its running peak (the spool moves), then ends the
   boost when the current has risen ``valley_rise_a`` above its running minimum (the end
   of stroke). ``max_boost_s`` bounds the boost.
3. **Hold: a clocked hysteresis (bang-bang) regulator**, not a PI chopper. A comparator
   sampled by a ``comparator_clock_hz`` clock (20 kHz) switches the coil to the supply when
   the current is below ``hold_current_a - band/2`` and to free-wheeling (0 V) when above
   ``hold_current_a + band/2``, and keeps its state in between; so the switching rate is at
   most the clock rate and every switching instant lies on the integration grid.
4. **Release.** A capacitor charged towards ``capacitor_voltage_v`` (first order,
   ``capacitor_charge_time_s``, while it is not connected) is applied reversed at the
   falling edge and discharges as a first-order decay (``capacitor_discharge_time_s``)
   until the coil current reaches zero.
5. **Reverse blocking.** The terminal current never goes below 0: when it reaches 0 in the
   off phase the driver's diode opens the circuit until the next rising edge.

Integration: a fixed-step classical Runge-Kutta (RK4) at ``step_s`` (25 us by default,
two steps per comparator tick) in plain Python floats over the truth model's ``rhs``. The
driver's voltage is constant within a step except the capacitor's exponential, which is
evaluated at the stage times. Step ends that cross an event (end stop, release of a held
spool, friction sticking, the current reaching zero) are split at the crossing, found by
Illinois regula falsi on the event function and redone. A spool that lands on a stop while
the net force already pulls it away (the next boost began before it had closed) leaves
the stop at once; the truth model's own event loop never meets that case on bench steps.
The interval means integrate the terminal current with the trapezoid rule per step.

Only :mod:`valve_model_pkg.dataformat` (the one home of the CSV format) is used from the
suite, to write the file. ``supply_ripple`` is not offered here (the truth model applies
its ripple to every commanded voltage, the capacitor's included).
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from .generate import LISTED_EFFECTS, effect_changes
from .truth import _FREE, _HELD, _V_STICK, TruthValve, _Truth, perturbed

__all__ = ['DriveCircuit', 'PwmSchedule', 'OperationTrace', 'OPERATION_EFFECTS',
           'simulate_operation', 'write_operation_record', 'default_schedule']

#: Effects an operational record can carry (``none`` or one of the listed ones).
OPERATION_EFFECTS = ('none',) + LISTED_EFFECTS
#: Noise levels of the interval-mean current the tests and benchmarks use [A].
NOISE_LEVELS_A = (0.0, 1e-3, 3e-3, 10e-3)

# Electronics phases.
_BOOST, _HOLD, _RELEASE, _BLOCKED = 'boost', 'hold', 'release', 'blocked'


@dataclass(frozen=True)
class DriveCircuit:
    """Constants of the generator's drive electronics (SI units)."""

    supply_voltage_v: float = 24.0
    hold_current_a: float = 0.5
    #: Total width of the hysteresis band around the hold current [A].
    hysteresis_band_a: float = 0.02
    #: Rate at which the hold comparator is sampled (upper bound of the switching rate) [Hz].
    comparator_clock_hz: float = 20_000.0
    #: Fall below the running peak that arms the end-of-stroke detection [A].
    dip_threshold_a: float = 0.01
    #: Rise above the running minimum after arming that ends the boost [A].
    valley_rise_a: float = 0.002
    max_boost_s: float = 0.010
    capacitor_voltage_v: float = 24.0
    capacitor_charge_time_s: float = 1.0e-3
    capacitor_discharge_time_s: float = 0.5e-3


@dataclass(frozen=True)
class PwmSchedule:
    """Main PWM periods: start [s], frequency [Hz] and duty [1] of each, in time order.

    Before the first start the main PWM is low (duty 0).
    """

    starts_s: tuple[float, ...]
    frequency_hz: tuple[float, ...]
    duty: tuple[float, ...]

    def in_force(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Duty and frequency in force at each time (the period with start <= t)."""
        k = np.searchsorted(np.asarray(self.starts_s), t_s, side='right') - 1
        kk = np.clip(k, 0, None)
        duty = np.where(k >= 0, np.asarray(self.duty)[kk], 0.0)
        freq = np.where(k >= 0, np.asarray(self.frequency_hz)[kk], self.frequency_hz[0])
        return duty, freq

    def edges(self, t_end_s: float) -> list[tuple[float, str]]:
        """Rising and falling edges of the main PWM before ``t_end_s``, in time order."""
        out: list[tuple[float, str]] = []
        high = False
        for n, (s, f, d) in enumerate(zip(self.starts_s, self.frequency_hz, self.duty)):
            end = self.starts_s[n + 1] if n + 1 < len(self.starts_s) else s + 1.0 / f
            if d <= 0.0:
                if high:
                    out.append((s, 'fall'))
                high = False
                continue
            if not high:
                out.append((s, 'rise'))
            high = True
            if d < 1.0:
                out.append((s + d / f, 'fall'))
                high = False
            if end >= t_end_s:
                break
        return [e for e in out if e[0] < t_end_s]


def default_schedule(duration_s: float, rng: np.random.Generator, *,
                     frequency_hz: float | tuple[float, ...] = 50.0,
                     duty_levels: tuple[float, ...] = (0.2, 0.35, 0.5, 0.65, 0.8),
                     block_s: float = 0.2, rest_s: float = 0.04,
                     phase_s: float = 0.0073) -> PwmSchedule:
    """A record that starts at rest, then holds a drawn duty for ``block_s`` at a time.

    Parameters
    ----------
    duration_s : float
        Length of the record [s].
    rng : numpy.random.Generator
        Draws the duty (and frequency) of each block.
    frequency_hz : float or tuple of float
        Main PWM frequency, or the frequencies to draw from per block [Hz] (20-100 Hz).
    duty_levels : tuple of float
        Duties to draw from; consecutive blocks differ, so the command changes at every
        block start and the reader can place the period grid.
    block_s : float
        Length of a block; rounded to whole periods [s].
    rest_s : float
        Duty 0 at the start (at least one period of the first frequency) [s].
    phase_s : float
        Offset of the period grid, so that period starts do not fall on sample times [s].
    """
    freqs = (frequency_hz,) if isinstance(frequency_hz, (int, float)) else tuple(frequency_hz)
    starts: list[float] = []
    fr: list[float] = []
    du: list[float] = []
    s = phase_s
    f0 = freqs[0]
    while s < rest_s or s < phase_s + 1.0 / f0:
        starts.append(s)
        fr.append(f0)
        du.append(0.0)
        s += 1.0 / f0
    last = 0.0
    while s < duration_s:
        f = float(freqs[rng.integers(len(freqs))])
        d = last
        while d == last:
            d = float(duty_levels[rng.integers(len(duty_levels))])
        last = d
        for _ in range(max(1, int(round(block_s * f)))):
            starts.append(s)
            fr.append(f)
            du.append(d)
            s += 1.0 / f
    return PwmSchedule(tuple(starts), tuple(fr), tuple(du))


@dataclass
class OperationTrace:
    """Output of :func:`simulate_operation`.

    ``t_s`` .. ``phase`` are the fine trace at the integration step ends, shape (n,);
    ``sample_t_s`` and ``interval_mean_current_a`` the telemetry, shape (m,).
    """

    t_s: np.ndarray
    current_a: np.ndarray
    position_m: np.ndarray
    coil_voltage_v: np.ndarray
    phase: np.ndarray
    sample_t_s: np.ndarray
    interval_mean_current_a: np.ndarray
    boost_ends_s: list[float] = field(default_factory=list)
    wall_time_s: float = 0.0
    steps: int = 0


class _Driver:
    """The generator's drive electronics: phase, comparator state, capacitor."""

    def __init__(self, circuit: DriveCircuit, eddy_ohm: float) -> None:
        self.c = circuit
        self.eddy_ohm = eddy_ohm
        self.phase = _BLOCKED
        self.switch_on = False
        self.boost_start = 0.0
        self.peak = 0.0
        self.valley = math.inf
        self.armed = False
        # capacitor: value at t_ref, charging (True) or discharging into the coil (False)
        self.cap_ref_v = circuit.capacitor_voltage_v
        self.cap_ref_t = 0.0
        self.cap_charging = True

    def capacitor_v(self, t: float) -> float:
        c = self.c
        dt = t - self.cap_ref_t
        if self.cap_charging:
            return c.capacitor_voltage_v + (self.cap_ref_v - c.capacitor_voltage_v) * math.exp(
                -dt / c.capacitor_charge_time_s)
        return self.cap_ref_v * math.exp(-dt / c.capacitor_discharge_time_s)

    def _cap_switch(self, t: float, charging: bool) -> None:
        self.cap_ref_v = self.capacitor_v(t)
        self.cap_ref_t = t
        self.cap_charging = charging

    def voltage(self, t: float, y: list[float]) -> float:
        """Voltage the driver puts on the coil terminals [V]."""
        if self.phase == _BOOST:
            return self.c.supply_voltage_v
        if self.phase == _HOLD:
            return self.c.supply_voltage_v if self.switch_on else 0.0
        if self.phase == _RELEASE:
            return -self.capacitor_v(t)
        # Blocked: the open circuit's terminal voltage, the one that keeps the terminal
        # current at zero (the eddy path still carries the magnetising current).
        return -self.eddy_ohm * y[0] if math.isfinite(self.eddy_ohm) else 0.0

    def rise(self, t: float) -> None:
        if self.phase == _RELEASE:
            self._cap_switch(t, True)
        self.phase = _BOOST
        self.boost_start = t
        self.peak, self.valley, self.armed = 0.0, math.inf, False

    def fall(self, t: float) -> None:
        if self.phase in (_BOOST, _HOLD):
            self.phase = _RELEASE
            self._cap_switch(t, False)

    def block(self, t: float) -> None:
        if self.phase == _RELEASE:
            self._cap_switch(t, True)
        self.phase = _BLOCKED

    def after_step(self, t: float, i: float) -> bool:
        """End-of-stroke detection during the boost; True when the boost ends now."""
        if self.phase != _BOOST:
            return False
        if not self.armed:
            self.peak = max(self.peak, i)
            self.armed = i < self.peak - self.c.dip_threshold_a
            self.valley = i
        else:
            self.valley = min(self.valley, i)
        detected = self.armed and i > self.valley + self.c.valley_rise_a
        if detected or t - self.boost_start >= self.c.max_boost_s - 1e-12:
            self.phase = _HOLD
            self.switch_on = i < self.c.hold_current_a - 0.5 * self.c.hysteresis_band_a
            return True
        return False

    def tick(self, i: float) -> None:
        """The hold comparator, sampled on the comparator clock."""
        if self.phase != _HOLD:
            return
        half = 0.5 * self.c.hysteresis_band_a
        if i < self.c.hold_current_a - half:
            self.switch_on = True
        elif i > self.c.hold_current_a + half:
            self.switch_on = False


def _rk4(model: _Truth, drv: _Driver, t: float, y: list[float], h: float, mode: int,
         sign: float = 0.0) -> list[float]:
    """One classical Runge-Kutta step of the truth model's ``rhs`` under the driver."""
    fc_m = model.v.friction_n / model.v.spool_mass_kg if mode == _FREE and sign else 0.0

    def f(tt: float, yy: list[float]) -> list[float]:
        d = model.rhs(tt, yy, drv.voltage(tt, yy), mode).tolist()
        if fc_m:
            # Kinetic friction acts against the motion of the whole piece (as between the
            # truth model's stop events); a stage velocity of the other sign must not flip it.
            vel = yy[3]
            used = math.copysign(1.0, vel) if vel != 0.0 else 0.0
            d[3] -= fc_m * (sign - used)
        return d
    k1 = f(t, y)
    y2 = [a + 0.5 * h * b for a, b in zip(y, k1)]
    k2 = f(t + 0.5 * h, y2)
    y3 = [a + 0.5 * h * b for a, b in zip(y, k2)]
    k3 = f(t + 0.5 * h, y3)
    y4 = [a + h * b for a, b in zip(y, k3)]
    k4 = f(t + h, y4)
    return [a + h / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
            for a, b1, b2, b3, b4 in zip(y, k1, k2, k3, k4)]


class _Integrator:
    """Mechanical mode bookkeeping around the RK4 step (the truth model's semantics)."""

    def __init__(self, valve: TruthValve, supply_pa: float, drv: _Driver) -> None:
        self.v = valve
        self.model = _Truth(valve, supply_pa)
        self.drv = drv
        self.y = [0.0, 0.0, 0.0, 0.0, 0.0]
        self.mode, self.held_at = _HELD, 'closed'

    def current(self, t: float, y: list[float]) -> float:
        vel = 0.0 if self.mode == _HELD else y[3]
        return self.model.electrical(t, y, self.drv.voltage(t, y), vel)[0]

    def _events(self, t: float, y: list[float]) -> list[float]:
        """Event functions, each crossing from >= 0 to < 0 when it fires."""
        v, m = self.v, self.model
        g: list[float] = []
        if self.mode == _HELD:
            f = m.drive_force(y[0], y[2])
            fc = v.friction_n
            rel = {'closed': f - fc, 'open': -f - fc}.get(self.held_at, abs(f) - fc)
            g += [-rel, 1.0, 1.0, 1.0]
        else:
            stick = 1.0
            if v.friction_n > 0.0:
                stick = y[3] * self._sign
            g += [1.0, v.stroke_m - y[2], y[2], stick]
        if self.drv.phase == _RELEASE:
            g.append(self.current(t, y))
        else:
            g.append(1.0)
        return g

    def _step(self, t: float, y: list[float], h: float) -> list[float]:
        sign = self._sign if self.mode == _FREE else 0.0
        return _rk4(self.model, self.drv, t, y, h, self.mode, sign)

    def advance(self, t: float, h: float, depth: int = 0) -> float:
        """Integrate over [t, t + h] with events; returns the terminal current at t + h."""
        if self.mode == _FREE:
            self._sign = math.copysign(1.0, self.y[3]) if self.y[3] != 0.0 else 1.0
        g0 = self._events(t, self.y)
        if self.drv.phase == _RELEASE and g0[4] <= 0.0:
            self._block(t)
            g0 = self._events(t, self.y)
        if self.mode == _HELD and g0[0] < 0.0:
            # Already free to move (the spool landed on a stop while the net force pulls
            # it away, e.g. the boost began before it had closed): leave at once.
            self._transition(t, 0)
            self._sign = math.copysign(1.0, self.y[3])
            g0 = self._events(t, self.y)
        y1 = self._step(t, self.y, h)
        g1 = self._events(t + h, y1)
        fired = [(g0[k] / (g0[k] - g1[k]), k) for k in range(5)
                 if g1[k] < 0.0 <= g0[k]]
        if not fired or depth > 20 or h < 1e-10:
            self.y = y1
            return self.current(t + h, y1)
        _, k = min(fired)
        # Illinois regula falsi on the first event's function; the piece ends just past
        # the crossing (on the side where the event has fired).
        a, ga, b, gb, yb = 0.0, g0[k], 1.0, g1[k], y1
        side = 0
        for _ in range(6):
            c = a + (b - a) * ga / (ga - gb)
            yc = self._step(t, self.y, h * c)
            gc = self._events(t + h * c, yc)[k]
            if gc < 0.0:
                b, gb, yb = c, gc, yc
                if side == -1:
                    ga *= 0.5
                side = -1
            else:
                a, ga = c, gc
                if side == 1:
                    gb *= 0.5
                side = 1
            if (b - a) * h < 1e-9:
                break
        h1 = h * b
        self.y = yb
        self._transition(t + h1, k)
        return self.advance(t + h1, h - h1, depth + 1) if h - h1 > 1e-12 else \
            self.current(t + h, self.y)

    def _block(self, t: float) -> None:
        self.drv.block(t)
        y = self.y
        if not math.isfinite(self.v.eddy_resistance_ohm):
            y[0] = 0.0
        y[1] = 0.0

    def _transition(self, t: float, k: int) -> None:
        v, y, m = self.v, self.y, self.model
        if k == 0:
            # released from a stop (or a stuck point): move the way the force pushes
            direction = {'closed': 1.0, 'open': -1.0}.get(
                self.held_at, math.copysign(1.0, m.drive_force(y[0], y[2])))
            self.mode = _FREE
            y[3] = 1e-9 * direction
        elif k in (1, 2):
            at_open = k == 1
            y[2] = v.stroke_m if at_open else 0.0
            if v.restitution > 0.0 and abs(y[3]) * v.restitution > _V_STICK * 100:
                y[3] = -v.restitution * y[3]
            else:
                y[3] = 0.0
                self.mode, self.held_at = _HELD, 'open' if at_open else 'closed'
        elif k == 3:
            y[3] = 0.0
            f = m.drive_force(y[0], y[2])
            if abs(f) <= v.friction_n:
                self.mode, self.held_at = _HELD, 'mid'
            else:
                y[3] = 1e-9 * math.copysign(1.0, f)
        else:
            self._block(t)


def simulate_operation(valve: TruthValve, schedule: PwmSchedule, duration_s: float, *,
                       circuit: DriveCircuit = DriveCircuit(), supply_pa: float = 4e5,
                       sample_rate_hz: float = 1000.0, step_s: float = 25e-6
                       ) -> OperationTrace:
    """Run the truth valve through the generator's drive electronics.

    Parameters
    ----------
    valve : TruthValve
        The valve instance (effects as its fields say).
    schedule : PwmSchedule
        Main PWM periods.
    duration_s : float
        Length of the record [s]; telemetry samples at ``n / sample_rate_hz``, n >= 1.
    circuit : DriveCircuit
        Drive electronics constants.
    supply_pa : float
        Supply pressure, gauge [Pa].
    sample_rate_hz : float
        Telemetry rate [Hz]; its period must be a whole number of steps.
    step_s : float
        Integration step [s]; the comparator period must be a whole number of steps.

    Returns
    -------
    OperationTrace
    """
    start = time.perf_counter()
    per_sample = int(round(1.0 / (sample_rate_hz * step_s)))
    per_tick = int(round(1.0 / (circuit.comparator_clock_hz * step_s)))
    if abs(per_sample * step_s * sample_rate_hz - 1.0) > 1e-9 or \
            abs(per_tick * step_s * circuit.comparator_clock_hz - 1.0) > 1e-9:
        raise ValueError('the sample and comparator periods must be whole numbers of steps')
    drv = _Driver(circuit, valve.eddy_resistance_ohm)
    sim = _Integrator(valve, supply_pa, drv)
    n_steps = int(round(duration_s / step_s))
    edges = schedule.edges(n_steps * step_s)
    e_idx = 0
    t_out = np.empty(n_steps + 1)
    i_out = np.empty(n_steps + 1)
    x_out = np.empty(n_steps + 1)
    v_out = np.empty(n_steps + 1)
    ph_out: list[str] = [drv.phase]
    t_out[0], i_out[0], x_out[0], v_out[0] = 0.0, 0.0, 0.0, 0.0
    means = np.empty(n_steps // per_sample)
    boost_ends: list[float] = []
    acc = 0.0
    i_prev = 0.0
    t = 0.0
    for n in range(1, n_steps + 1):
        t_grid = n * step_s
        # edges inside the step split it (the current stays continuous across them)
        while e_idx < len(edges) and edges[e_idx][0] < t_grid - 1e-12:
            te, kind = edges[e_idx]
            if te > t:
                i_e = sim.advance(t, te - t)
                acc += 0.5 * (i_prev + i_e) * (te - t)
                i_prev, t = i_e, te
            (drv.rise if kind == 'rise' else drv.fall)(t)
            # the terminal current may jump with the voltage (eddy path)
            i_prev = sim.current(t, sim.y)
            e_idx += 1
        i1 = sim.advance(t, t_grid - t)
        acc += 0.5 * (i_prev + i1) * (t_grid - t)
        t = t_grid
        if drv.after_step(t, i1):
            boost_ends.append(t)
        if n % per_tick == 0:
            drv.tick(i1)
        # value after the switching decisions, for the next step's trapezoid
        i_prev = sim.current(t, sim.y)
        t_out[n], i_out[n], x_out[n] = t, i1, sim.y[2]
        v_out[n] = drv.voltage(t, sim.y)
        ph_out.append(drv.phase)
        if n % per_sample == 0:
            means[n // per_sample - 1] = acc * sample_rate_hz
            acc = 0.0
    sample_t = np.arange(1, means.size + 1) / sample_rate_hz
    return OperationTrace(
        t_s=t_out, current_a=i_out, position_m=np.clip(x_out, 0.0, valve.stroke_m),
        coil_voltage_v=v_out, phase=np.array(ph_out), sample_t_s=sample_t,
        interval_mean_current_a=means, boost_ends_s=boost_ends,
        wall_time_s=time.perf_counter() - start, steps=n_steps)


def _valve(seed: int, effect: str, spread: float) -> TruthValve:
    base = TruthValve()
    if spread > 0.0:
        base = perturbed(base, np.random.default_rng(seed), spread=spread)
    return replace(base, **effect_changes(effect))


def write_operation_record(out_dir: str | Path, name: str = 'operation', *, seed: int = 1,
                           effect: str = 'none', noise_a: float = 0.0,
                           duration_s: float = 3.0, spread: float = 0.0,
                           valve: TruthValve | None = None,
                           circuit: DriveCircuit = DriveCircuit(),
                           schedule: PwmSchedule | None = None, supply_pa: float = 4e5,
                           step_s: float = 25e-6) -> dict[str, object]:
    """Simulate an operational record and write ``out_dir/name.csv`` and its truth JSON.

    Parameters
    ----------
    out_dir : str or pathlib.Path
        Directory for ``<name>.csv`` and ``<name>.truth.json``.
    name : str
        File stem.
    seed : int
        Seeds the valve draw (with ``spread``), the schedule and the noise.
    effect : str
        ``none`` or one of the listed effects, at the size of :func:`.generate.effect_changes`.
    noise_a : float
        Standard deviation of Gaussian noise on the interval means [A].
    duration_s : float
        Record length [s].
    spread : float
        Relative spread of the Table 2 parameters around the paper's (0: the paper's valve).
    valve : TruthValve, optional
        The valve instance itself (then ``seed``, ``spread`` and ``effect`` do not draw it).
    circuit, schedule, supply_pa, step_s
        See :func:`simulate_operation`; the default schedule is :func:`default_schedule`.

    Returns
    -------
    dict
        The truth JSON content: file, effect, valve, circuit, noise, timing and checks.
    """
    from valve_model_pkg.dataformat import write_table
    if effect not in OPERATION_EFFECTS:
        raise ValueError(f'effect {effect!r} not offered for operation records; choose from '
                         f'{", ".join(OPERATION_EFFECTS)}')
    rng = np.random.default_rng(seed)
    if valve is None:
        valve = _valve(seed, effect, spread)
    if schedule is None:
        schedule = default_schedule(duration_s, rng)
    tr = simulate_operation(valve, schedule, duration_s, circuit=circuit, supply_pa=supply_pa,
                            step_s=step_s)
    current = tr.interval_mean_current_a + (rng.normal(0.0, noise_a, tr.sample_t_s.size)
                                            if noise_a > 0.0 else 0.0)
    duty, freq = schedule.in_force(tr.sample_t_s)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = write_table(out / f'{name}.csv', {
        'experiment': 'operation',
        'valve': f'generated valve ({effect}, seed {seed})',
        'supply_voltage_v': circuit.supply_voltage_v,
        'sample_rate_hz': 1000,
        'current_averaging': 'interval_mean',
        'supply_pressure_pa': supply_pa,
        'output_pressure_pa': 0,
        'generator': 'tests.datagen.operation (truth valve, own drive electronics)',
    }, {'t': tr.sample_t_s, 'duty': duty, 'pwm_frequency_hz': freq, 'current': current,
        'supply_pressure': np.full(tr.sample_t_s.size, supply_pa),
        'output_pressure': np.zeros(tr.sample_t_s.size)})
    truth = {
        'file': str(path), 'effect': effect, 'seed': seed, 'spread': spread,
        'valve': valve.as_dict(), 'circuit': asdict(circuit),
        'noise_std_a': noise_a, 'duration_s': duration_s, 'supply_pressure_pa': supply_pa,
        'step_s': step_s, 'generation_wall_time_s': tr.wall_time_s,
        'boosts_ended': len(tr.boost_ends_s),
        'rising_edges': sum(1 for e in schedule.edges(duration_s) if e[1] == 'rise'),
    }
    (out / f'{name}.truth.json').write_text(json.dumps(truth, indent=2), encoding='utf-8')
    return truth
