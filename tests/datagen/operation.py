"""Operational records (``experiment: operation``) from the truth valve with its own driver.

What a valve in service reports: the main PWM command in force and the coil current as a
1 ms interval mean, with the drive electronics on, and where the controller measures it the
coil voltage as a mean over the same interval. The valve is the independent truth model of
:mod:`.truth` (its :class:`~.truth._Truth` right-hand side, flux, force and the effects);
the drive electronics are those of :mod:`.electronics`, a family of peak-and-hold forms
written independently of the suite's (``valve_model_pkg.model.electronics`` / ``kernel``,
which the generator never imports), so a shared mistake cannot hide itself in the data:

1. **Main PWM.** A schedule of periods (frequency 20-100 Hz, duty per period); the command
   in force changes only at a period start.
2. **Peak, hold, release, reverse blocking** as the driver's forms say
   (:class:`~.electronics.DriveElectronics`). The default, :class:`~.electronics.
   DriveCircuit`, is an analogue dip-and-rise detector ending the peak phase, a clocked
   hysteresis regulator (20 kHz comparator clock) holding 0.5 A with 0 V free-wheeling, a
   capacitor release pulse (charged whenever idle) and a diode blocking reverse current.

Integration: a fixed-step classical Runge-Kutta (RK4) at ``step_s`` (25 us by default) in
plain Python floats over the truth model's ``rhs``. The driver's voltage is constant within
a step except a capacitor's exponential and an open terminal's voltage, which are evaluated
at the stage times. Main PWM edges and the driver's switching instants inside a step (a
timer's end, a chopper's turn-off) split the step; the driver's clocked decisions fall on
the grid. Step ends that cross an event (end stop, release of a held spool, friction
sticking, the current reaching zero where the driver stops it, a peak-current threshold)
are split at the crossing, found by Illinois regula falsi on the event function and redone.
A spool that lands on a stop while the net force already pulls it away (the next boost
began before it had closed) leaves the stop at once; the truth model's own event loop never
meets that case on bench steps. The interval means integrate the terminal current with the
trapezoid rule per step and the terminal voltage with the RK4 quadrature of its stage
values.

Nothing of the suite is imported: the file is written by :mod:`.csvfile` in the shared
format. ``supply_ripple`` is not offered here (the truth model applies its ripple to every
commanded voltage, the capacitor's included).
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from .csvfile import bench_current, write_table
from .electronics import Drive, DriveCircuit, DriveElectronics
from .generate import LISTED_EFFECTS, effect_changes, effect_name
from .truth import _FREE, _HELD, _V_STICK, TruthValve, _Truth, perturbed

__all__ = ['DriveCircuit', 'DriveElectronics', 'PwmSchedule', 'OperationTrace',
           'OPERATION_EFFECTS', 'simulate_operation', 'write_operation_record',
           'default_schedule', 'electronics_of']

#: Effects an operational record can carry (``none``, a listed one, or friction with
#: stiction).
OPERATION_EFFECTS = ('none',) + LISTED_EFFECTS + ('coulomb_friction_stiction',)
#: Noise levels of the interval-mean current the tests and benchmarks use [A].
NOISE_LEVELS_A = (0.0, 1e-3, 3e-3, 10e-3)


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
    ``coil_voltage_v`` is the driver's voltage just after its decisions there.
    ``sample_t_s``, ``interval_mean_current_a`` and ``interval_mean_coil_voltage_v`` the
    telemetry (means over the sample interval ending at ``sample_t_s``), shape (m,): the
    current by the trapezoid rule per step (what the records carry), the voltage by the RK4
    quadrature of its stage values; ``interval_mean_current_rk4_a`` is the current's RK4
    quadrature (the voltage's exact counterpart: the two satisfy the coil's balance to the
    integrator's precision, the trapezoid means to about 1e-5 A while the spool moves).
    """

    t_s: np.ndarray
    current_a: np.ndarray
    position_m: np.ndarray
    coil_voltage_v: np.ndarray
    phase: np.ndarray
    sample_t_s: np.ndarray
    interval_mean_current_a: np.ndarray
    interval_mean_coil_voltage_v: np.ndarray
    interval_mean_current_rk4_a: np.ndarray
    main_pwm_high: np.ndarray
    boost_ends_s: list[float] = field(default_factory=list)
    wall_time_s: float = 0.0
    steps: int = 0


@dataclass
class _Step:
    """Result of one RK4 step: the state and the RK4 quadratures of the applied voltage
    [V s] and of the terminal current [A s] over the step."""

    y: list[float]
    v_int: float
    i_int: float


def _stage_current(model: _Truth, t: float, y: list[float], u: float) -> float:
    """Terminal current of state ``y`` under the voltage ``u`` [A]."""
    if not model.eddy:
        return y[0]
    if model.leak:
        return y[1]
    return model.electrical(t, y, u, 0.0)[0]


def _rk4(model: _Truth, drv: Drive, t: float, y: list[float], h: float, mode: int,
         sign: float = 0.0) -> _Step:
    """One classical Runge-Kutta step of the truth model's ``rhs`` under the driver."""
    fc_m = model.v.friction_n / model.v.spool_mass_kg if mode == _FREE and sign else 0.0
    volts: list[float] = []
    amps: list[float] = []

    def f(tt: float, yy: list[float]) -> list[float]:
        u = drv.voltage(tt, yy)
        volts.append(u)
        amps.append(_stage_current(model, tt, yy, u))
        d = model.rhs(tt, yy, u, mode).tolist()
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
    return _Step([a + h / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
                  for a, b1, b2, b3, b4 in zip(y, k1, k2, k3, k4)],
                 h / 6.0 * (volts[0] + 2.0 * volts[1] + 2.0 * volts[2] + volts[3]),
                 h / 6.0 * (amps[0] + 2.0 * amps[1] + 2.0 * amps[2] + amps[3]))


# Event functions of the integrator, each crossing from >= 0 to < 0 when it fires.
_EV_RELEASE, _EV_OPEN, _EV_CLOSED, _EV_STICK, _EV_ZERO, _EV_THRESHOLD = range(6)


class _Integrator:
    """Mechanical mode bookkeeping around the RK4 step (the truth model's semantics)."""

    def __init__(self, valve: TruthValve, supply_pa: float, drv: Drive) -> None:
        self.v = valve
        self.model = _Truth(valve, supply_pa)
        self.drv = drv
        self.y = [0.0, 0.0, 0.0, 0.0, 0.0]
        self.mode, self.held_at = _HELD, 'closed'
        #: RK4 quadratures of the applied voltage [V s] and the current [A s] since the
        #: last reset
        self.v_int = 0.0
        self.i_int = 0.0

    def current(self, t: float, y: list[float]) -> float:
        vel = 0.0 if self.mode == _HELD else y[3]
        return self.model.electrical(t, y, self.drv.voltage(t, y), vel)[0]

    def _events(self, t: float, y: list[float]) -> list[float]:
        """Event functions, each crossing from >= 0 to < 0 when it fires."""
        v, m = self.v, self.model
        g: list[float] = []
        if self.mode == _HELD:
            f = m.drive_force(y[0], y[2])
            fs = v.breakaway_n
            rel = {'closed': f - fs, 'open': -f - fs}.get(self.held_at, abs(f) - fs)
            g += [-rel, 1.0, 1.0, 1.0]
        else:
            stick = 1.0
            if v.breakaway_n > 0.0:
                stick = y[3] * self._sign
            g += [1.0, v.stroke_m - y[2], y[2], stick]
        g.append(self.current(t, y) if self.drv.watch_zero() else 1.0)
        threshold = self.drv.threshold_a()
        g.append(1.0 if threshold is None else threshold - self.current(t, y))
        return g

    def _step(self, t: float, y: list[float], h: float) -> _Step:
        sign = self._sign if self.mode == _FREE else 0.0
        return _rk4(self.model, self.drv, t, y, h, self.mode, sign)

    def _settle(self, t: float) -> list[float]:
        """Conditions already met at ``t`` (a crossing that happened on a switch)."""
        g0 = self._events(t, self.y)
        if self.drv.watch_zero() and g0[_EV_ZERO] <= 0.0:
            self._zero(t)
            g0 = self._events(t, self.y)
        if g0[_EV_THRESHOLD] < 0.0:
            self.drv.threshold_reached(t, self.current(t, self.y))
            g0 = self._events(t, self.y)
        if self.mode == _HELD and g0[_EV_RELEASE] < 0.0:
            # Already free to move (the spool landed on a stop while the net force pulls
            # it away, e.g. the boost began before it had closed): leave at once.
            self._transition(t, _EV_RELEASE)
            self._sign = math.copysign(1.0, self.y[3])
            g0 = self._events(t, self.y)
        return g0

    def advance(self, t: float, h: float, depth: int = 0) -> float:
        """Integrate over [t, t + h] with events; returns the terminal current at t + h."""
        if self.mode == _FREE:
            self._sign = math.copysign(1.0, self.y[3]) if self.y[3] != 0.0 else 1.0
        g0 = self._settle(t)
        s1 = self._step(t, self.y, h)
        g1 = self._events(t + h, s1.y)
        fired = [(g0[k] / (g0[k] - g1[k]), k) for k in range(len(g0))
                 if g1[k] < 0.0 <= g0[k]]
        if not fired or depth > 20 or h < 1e-10:
            self.y = s1.y
            self.v_int += s1.v_int
            self.i_int += s1.i_int
            return self.current(t + h, s1.y)
        _, k = min(fired)
        # Illinois regula falsi on the first event's function; the piece ends just past
        # the crossing (on the side where the event has fired).
        a, ga, b, gb, sb = 0.0, g0[k], 1.0, g1[k], s1
        side = 0
        for _ in range(6):
            c = a + (b - a) * ga / (ga - gb)
            sc = self._step(t, self.y, h * c)
            gc = self._events(t + h * c, sc.y)[k]
            if gc < 0.0:
                b, gb, sb = c, gc, sc
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
        self.y = sb.y
        self.v_int += sb.v_int
        self.i_int += sb.i_int
        self._transition(t + h1, k)
        return self.advance(t + h1, h - h1, depth + 1) if h - h1 > 1e-12 else \
            self.current(t + h, self.y)

    def _zero(self, t: float) -> None:
        """The driver stops the current at zero: the terminal opens."""
        self.drv.zero_reached(t)
        y = self.y
        if not math.isfinite(self.v.eddy_resistance_ohm):
            y[0] = 0.0
        y[1] = 0.0

    def _transition(self, t: float, k: int) -> None:
        v, y, m = self.v, self.y, self.model
        if k == _EV_RELEASE:
            # released from a stop (or a stuck point): move the way the force pushes
            direction = {'closed': 1.0, 'open': -1.0}.get(
                self.held_at, math.copysign(1.0, m.drive_force(y[0], y[2])))
            self.mode = _FREE
            y[3] = 1e-9 * direction
        elif k in (_EV_OPEN, _EV_CLOSED):
            at_open = k == _EV_OPEN
            y[2] = v.stroke_m if at_open else 0.0
            if v.restitution > 0.0 and abs(y[3]) * v.restitution > _V_STICK * 100:
                y[3] = -v.restitution * y[3]
            else:
                y[3] = 0.0
                self.mode, self.held_at = _HELD, 'open' if at_open else 'closed'
        elif k == _EV_STICK:
            y[3] = 0.0
            f = m.drive_force(y[0], y[2])
            if abs(f) <= v.breakaway_n:
                self.mode, self.held_at = _HELD, 'mid'
            else:
                y[3] = 1e-9 * math.copysign(1.0, f)
        elif k == _EV_ZERO:
            self._zero(t)
        else:
            self.drv.threshold_reached(t, self.current(t, y))


def electronics_of(circuit: DriveCircuit | DriveElectronics) -> DriveElectronics:
    """The driver in the family's form (a :class:`DriveCircuit` converted)."""
    return circuit.electronics() if isinstance(circuit, DriveCircuit) else circuit


def simulate_operation(valve: TruthValve, schedule: PwmSchedule, duration_s: float, *,
                       circuit: DriveCircuit | DriveElectronics = DriveCircuit(),
                       supply_pa: float = 4e5, sample_rate_hz: float = 1000.0,
                       step_s: float = 25e-6) -> OperationTrace:
    """Run the truth valve through the generator's drive electronics.

    Parameters
    ----------
    valve : TruthValve
        The valve instance (effects as its fields say).
    schedule : PwmSchedule
        Main PWM periods.
    duration_s : float
        Length of the record [s]; telemetry samples at ``n / sample_rate_hz``, n >= 1.
    circuit : DriveCircuit or DriveElectronics
        The drive electronics (their forms and constants).
    supply_pa : float
        Supply pressure, gauge [Pa].
    sample_rate_hz : float
        Telemetry rate [Hz]; its period must be a whole number of steps.
    step_s : float
        Integration step [s]; the driver's clock periods must be whole numbers of steps.

    Returns
    -------
    OperationTrace
    """
    start = time.perf_counter()
    electronics = electronics_of(circuit)
    per_sample = int(round(1.0 / (sample_rate_hz * step_s)))
    if abs(per_sample * step_s * sample_rate_hz - 1.0) > 1e-9:
        raise ValueError('the sample period must be a whole number of steps')
    drv = Drive(electronics, valve.eddy_resistance_ohm, step_s)
    sim = _Integrator(valve, supply_pa, drv)
    n_steps = int(round(duration_s / step_s))
    edges = schedule.edges(n_steps * step_s)
    e_idx = 0
    t_out = np.empty(n_steps + 1)
    i_out = np.empty(n_steps + 1)
    x_out = np.empty(n_steps + 1)
    v_out = np.empty(n_steps + 1)
    high = np.zeros(n_steps + 1, dtype=bool)
    ph_out: list[str] = [drv.phase]
    t_out[0], i_out[0], x_out[0], v_out[0] = 0.0, 0.0, 0.0, 0.0
    means = np.empty(n_steps // per_sample)
    v_means = np.empty(n_steps // per_sample)
    i_quad = np.empty(n_steps // per_sample)
    acc = 0.0
    i_prev = 0.0
    t = 0.0
    pwm_high = False
    for n in range(1, n_steps + 1):
        t_grid = n * step_s
        # main PWM edges and the driver's own switching instants inside the step split it
        # (the current stays continuous across them)
        while True:
            te_main = edges[e_idx][0] if e_idx < len(edges) else math.inf
            te = min(te_main, drv.pending_s)
            if not te < t_grid - 1e-12:
                break
            if te > t:
                i_e = sim.advance(t, te - t)
                acc += 0.5 * (i_prev + i_e) * (te - t)
                i_prev, t = i_e, te
            if te_main <= drv.pending_s:
                kind = edges[e_idx][1]
                (drv.rise if kind == 'rise' else drv.fall)(t)
                pwm_high = kind == 'rise'
                e_idx += 1
            else:
                drv.switch(t, sim.current(t, sim.y))
            # the terminal current may jump with the voltage (eddy path)
            i_prev = sim.current(t, sim.y)
        i1 = sim.advance(t, t_grid - t)
        acc += 0.5 * (i_prev + i1) * (t_grid - t)
        t = t_grid
        if drv.pending_s <= t_grid + 1e-12:
            drv.switch(t, i1)
        drv.on_grid(n, t, i1)
        # value after the switching decisions, for the next step's trapezoid
        i_prev = sim.current(t, sim.y)
        t_out[n], i_out[n], x_out[n] = t, i1, sim.y[2]
        v_out[n] = drv.voltage(t, sim.y)
        high[n] = pwm_high
        ph_out.append(drv.phase)
        if n % per_sample == 0:
            means[n // per_sample - 1] = acc * sample_rate_hz
            v_means[n // per_sample - 1] = sim.v_int * sample_rate_hz
            i_quad[n // per_sample - 1] = sim.i_int * sample_rate_hz
            acc = 0.0
            sim.v_int = sim.i_int = 0.0
    sample_t = np.arange(1, means.size + 1) / sample_rate_hz
    return OperationTrace(
        t_s=t_out, current_a=i_out, position_m=np.clip(x_out, 0.0, valve.stroke_m),
        coil_voltage_v=v_out, phase=np.array(ph_out), sample_t_s=sample_t,
        interval_mean_current_a=means, interval_mean_coil_voltage_v=v_means,
        interval_mean_current_rk4_a=i_quad,
        main_pwm_high=high, boost_ends_s=drv.boost_ends,
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
                           circuit: DriveCircuit | DriveElectronics = DriveCircuit(),
                           schedule: PwmSchedule | None = None, supply_pa: float = 4e5,
                           step_s: float = 25e-6, coil_voltage_mean: bool = False,
                           lsb_a: float = 0.0, adc_bits: int = 8) -> dict[str, object]:
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
        One of :data:`OPERATION_EFFECTS`, at the size of :func:`.generate.effect_changes`.
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
    coil_voltage_mean : bool
        Add the column ``coil_voltage_mean``: the exact interval means of the voltage the
        driver applied to the coil terminals [V].
    lsb_a, adc_bits : float, int
        Quantise the current to ``lsb_a`` [A] steps over ``[0, (2^adc_bits - 1) lsb_a]``
        after the noise (0: no quantisation).

    Returns
    -------
    dict
        The truth JSON content: file, effect, valve, circuit, noise, timing and checks.
    """
    if effect not in OPERATION_EFFECTS:
        raise ValueError(f'effect {effect!r} not offered for operation records; choose from '
                         f'{", ".join(OPERATION_EFFECTS)}')
    rng = np.random.default_rng(seed)
    if valve is None:
        valve = _valve(seed, effect, spread)
    if schedule is None:
        schedule = default_schedule(duration_s, rng)
    electronics = electronics_of(circuit)
    tr = simulate_operation(valve, schedule, duration_s, circuit=circuit, supply_pa=supply_pa,
                            step_s=step_s)
    current = bench_current(tr.interval_mean_current_a, rng, noise_a, lsb_a, adc_bits)
    duty, freq = schedule.in_force(tr.sample_t_s)
    columns = {'t': tr.sample_t_s, 'duty': duty, 'pwm_frequency_hz': freq, 'current': current,
               'supply_pressure': np.full(tr.sample_t_s.size, supply_pa),
               'output_pressure': np.zeros(tr.sample_t_s.size)}
    if coil_voltage_mean:
        columns['coil_voltage_mean'] = tr.interval_mean_coil_voltage_v
    out = Path(out_dir)
    path = write_table(out / f'{name}.csv', {
        'experiment': 'operation',
        'valve': f'generated valve ({effect}, seed {seed})',
        'supply_voltage_v': electronics.supply_voltage_v,
        'sample_rate_hz': 1000,
        'current_averaging': 'interval_mean',
        'supply_pressure_pa': supply_pa,
        'output_pressure_pa': 0,
        'generator': 'tests.datagen.operation (truth valve, own drive electronics)',
    }, columns)
    truth = {
        'file': str(path), 'effect': effect, 'declared_effect': effect_name(effect),
        'seed': seed, 'spread': spread, 'valve': valve.as_dict(),
        'circuit': asdict(circuit) if isinstance(circuit, DriveCircuit) else
        electronics.describe(),
        'electronics': electronics.describe(), 'electronics_summary': electronics.summary(),
        'noise_std_a': noise_a, 'lsb_a': lsb_a, 'coil_voltage_mean': coil_voltage_mean,
        'duration_s': duration_s, 'supply_pressure_pa': supply_pa,
        'step_s': step_s, 'generation_wall_time_s': tr.wall_time_s,
        'boosts_ended': len(tr.boost_ends_s),
        'rising_edges': sum(1 for e in schedule.edges(duration_s) if e[1] == 'rise'),
    }
    (out / f'{name}.truth.json').write_text(json.dumps(truth, indent=2), encoding='utf-8')
    return truth
