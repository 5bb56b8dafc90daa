"""Peak-and-hold drive electronics of the test-data generator, in a family of forms.

Written from how real peak-and-hold solenoid and injector drivers work (the data sheets of
TI DRV110/DRV120, ST L9369-class drivers, hysteretic and PWM hold controllers), and
independently of the suite's ``valve_model_pkg.model.electronics`` / ``kernel`` (this
module imports nothing of the suite). Each rising edge of the main PWM starts a *peak*
phase at the full supply voltage; a *hold* phase keeps a lower current while the main PWM
is high; at the falling edge a *release* takes the current out of the coil. Each part is a
choice with its own constants (SI units):

===========  ===================  ==========================================================
part         form                 what it does
===========  ===================  ==========================================================
peak end     :class:`TimerPeak`   a fixed time after the rising edge
             :class:`ThresholdPeak`  the current reaches a threshold (analogue comparator:
                                  the instant of the crossing)
             :class:`DipPeak`     the current falls ``dip_a`` below its running peak (the
                                  spool moves)
             :class:`DipRisePeak` the dip, then a rise ``rise_a`` above the running minimum
                                  (the end of stroke)
hold         :class:`PiChopperHold`  a PI controller sets the duty of a fixed-frequency
                                  chopper at each period start; off part at
                                  ``off_voltage_v``: 0 V or a diode drop (slow decay),
                                  minus the supply (fast decay)
             :class:`HysteresisHold`  a clocked comparator switches on below the band and
                                  off above it
             :class:`ReducedPwmHold`  open loop: a fixed chopper duty (a lower mean voltage)
release      :class:`CapacitorRelease`  a capacitor applied reversed, discharging with a
                                  first-order decay; charged while idle, during the peak
                                  phase only, or while the main PWM is high
             :class:`ZenerRelease`  ``-clamp_v`` until the current reaches zero
             :class:`FreewheelRelease`  a freewheel diode: ``-diode_drop_v`` until zero
reverse      ``reverse_blocking`` a diode keeps the terminal current from going negative
===========  ===================  ==========================================================

A Zener clamp and a freewheel diode conduct one way only: their release always ends when
the current reaches zero. With ``reverse_blocking`` the terminal opens whenever a negative
voltage has driven the current to zero (end of a capacitor pulse, the off part of a
fast-decay chopper); without it a capacitor stays connected until the next rising edge and
drives the current negative.

:class:`Drive` is the state machine the integrator of :mod:`.operation` runs: the applied
voltage at any instant, the switching instants inside an integration step (timer end,
chopper turn-off), the decisions on the integration grid (detectors, hold clocks) and the
events at a current crossing (threshold, zero).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Union

__all__ = ['TimerPeak', 'ThresholdPeak', 'DipPeak', 'DipRisePeak', 'HysteresisHold',
           'PiChopperHold', 'ReducedPwmHold', 'CapacitorRelease', 'ZenerRelease',
           'FreewheelRelease', 'DriveElectronics', 'DriveCircuit', 'Drive', 'FORMS',
           'form_of', 'PHASES']

# Electronics phases.
BOOST, HOLD, RELEASE, BLOCKED = 'boost', 'hold', 'release', 'blocked'
PHASES = (BOOST, HOLD, RELEASE, BLOCKED)


# --- peak-phase end ------------------------------------------------------------------------
@dataclass(frozen=True)
class TimerPeak:
    """The peak phase lasts ``duration_s`` from each rising edge [s]."""

    duration_s: float = 5.0e-3


@dataclass(frozen=True)
class ThresholdPeak:
    """The peak phase ends when the current reaches ``current_a`` [A], at the latest after
    ``max_s`` [s]."""

    current_a: float = 0.8
    max_s: float = 10.0e-3


@dataclass(frozen=True)
class DipPeak:
    """The peak phase ends when the current has fallen ``dip_a`` [A] below its running peak.

    ``clock_hz``: the detector samples the current at this rate [Hz]; ``None`` samples it at
    every integration step (an analogue detector). ``max_s`` [s] bounds the peak phase.
    """

    dip_a: float = 0.01
    max_s: float = 10.0e-3
    clock_hz: float | None = None


@dataclass(frozen=True)
class DipRisePeak:
    """The dip arms the detector; the peak phase ends when the current has risen ``rise_a``
    [A] above its running minimum since (the end of stroke).

    ``clock_hz`` and ``max_s`` as for :class:`DipPeak`.
    """

    dip_a: float = 0.01
    rise_a: float = 0.002
    max_s: float = 10.0e-3
    clock_hz: float | None = None


# --- hold -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class HysteresisHold:
    """Bang-bang hold: a comparator sampled at ``clock_hz`` [Hz] switches the supply on
    below ``current_a - band_a/2`` and off (``off_voltage_v``) above ``current_a +
    band_a/2`` [A], keeping its state in between."""

    current_a: float = 0.5
    band_a: float = 0.02
    clock_hz: float = 20_000.0
    off_voltage_v: float = 0.0


@dataclass(frozen=True)
class PiChopperHold:
    """A chopper at ``frequency_hz`` [Hz] whose duty a discrete PI controller sets at each
    period start from the sampled current.

    ``duty = kp e + z``, ``e = current_a - i``, clipped to [0, 1]; the supply is on for
    ``duty T``, then ``off_voltage_v`` [V] for the rest of the period (0 V or a diode drop:
    slow decay; minus the supply: fast decay). The integrator ``z`` starts at the
    feed-forward duty that makes the mean voltage ``feedforward_resistance_ohm *
    current_a``; each period it adds ``ki e T`` and is clipped to [0, 1]. ``anti_windup``:
    ``conditional`` integrates only while the duty is not saturated (or the error leads it
    back), ``clamp`` always (the integrator then unwinds to 0 while the current falls from
    the peak to the set point and climbs back with the time constant kp/ki).
    """

    current_a: float = 0.5
    frequency_hz: float = 20_000.0
    kp_per_a: float = 11.0
    ki_per_a_s: float = 1000.0
    off_voltage_v: float = 0.0
    feedforward_resistance_ohm: float = 13.0
    anti_windup: str = 'conditional'

    def __post_init__(self) -> None:
        if self.anti_windup not in ('conditional', 'clamp'):
            raise ValueError(f'PiChopperHold.anti_windup {self.anti_windup!r}: choose '
                             'conditional or clamp')


@dataclass(frozen=True)
class ReducedPwmHold:
    """Open-loop hold: the supply on for ``duty`` of each period of ``frequency_hz`` [Hz],
    ``off_voltage_v`` [V] for the rest."""

    duty: float = 0.3
    frequency_hz: float = 20_000.0
    off_voltage_v: float = 0.0


# --- release --------------------------------------------------------------------------------
#: When a release capacitor charges: whenever it is not connected, in the peak phase only,
#: or while the main PWM is high (peak and hold).
CAPACITOR_CHARGING = ('idle', 'peak', 'high')


@dataclass(frozen=True)
class CapacitorRelease:
    """A capacitor charging towards ``voltage_v`` [V] (first order, ``charge_time_s``) as
    ``charging`` says, holding its voltage otherwise; at the falling edge it is applied
    reversed and discharges as a first-order decay (``discharge_time_s``). It starts at
    ``initial_voltage_v`` [V]."""

    voltage_v: float = 24.0
    charge_time_s: float = 1.0e-3
    discharge_time_s: float = 0.5e-3
    charging: str = 'idle'
    initial_voltage_v: float = 24.0

    def __post_init__(self) -> None:
        if self.charging not in CAPACITOR_CHARGING:
            raise ValueError(f'CapacitorRelease.charging {self.charging!r}: choose from '
                             f'{", ".join(CAPACITOR_CHARGING)}')


@dataclass(frozen=True)
class ZenerRelease:
    """A Zener clamp: ``-clamp_v`` [V] on the coil until its current reaches zero."""

    clamp_v: float = 36.0


@dataclass(frozen=True)
class FreewheelRelease:
    """A freewheel diode: ``-diode_drop_v`` [V] until the current reaches zero (slow)."""

    diode_drop_v: float = 0.7


PeakEnd = Union[TimerPeak, ThresholdPeak, DipPeak, DipRisePeak]
Hold = Union[HysteresisHold, PiChopperHold, ReducedPwmHold]
Release = Union[CapacitorRelease, ZenerRelease, FreewheelRelease]

_FORM_NAMES = {TimerPeak: 'timer', ThresholdPeak: 'threshold', DipPeak: 'dip',
               DipRisePeak: 'dip_and_rise', HysteresisHold: 'hysteresis',
               PiChopperHold: 'pi_chopper', ReducedPwmHold: 'reduced_pwm',
               CapacitorRelease: 'capacitor', ZenerRelease: 'zener',
               FreewheelRelease: 'freewheel_diode'}


def form_of(part: object) -> str:
    """Name of a part's form (``timer``, ``pi_chopper``, ``zener``, ...)."""
    return _FORM_NAMES[type(part)]


@dataclass(frozen=True)
class DriveElectronics:
    """One peak-and-hold driver: the supply and a form for each part."""

    supply_voltage_v: float = 24.0
    peak: PeakEnd = field(default_factory=DipRisePeak)
    hold: Hold = field(default_factory=HysteresisHold)
    release: Release = field(default_factory=CapacitorRelease)
    reverse_blocking: bool = True

    def describe(self) -> dict[str, object]:
        """Forms and constants as a plain dict (for truth JSON)."""
        out: dict[str, object] = {'supply_voltage_v': self.supply_voltage_v,
                                  'reverse_blocking': self.reverse_blocking}
        for name in ('peak', 'hold', 'release'):
            part = getattr(self, name)
            out[name] = {'form': form_of(part), **asdict(part)}
        return out

    def summary(self) -> str:
        """One line: the forms and their main constants."""
        p, h, r = self.peak, self.hold, self.release
        peak = {TimerPeak: lambda: f'timer {1e3 * p.duration_s:g} ms',
                ThresholdPeak: lambda: f'threshold {p.current_a:g} A',
                DipPeak: lambda: f'dip {1e3 * p.dip_a:g} mA',
                DipRisePeak: lambda: f'dip {1e3 * p.dip_a:g} mA + rise '
                                     f'{1e3 * p.rise_a:g} mA'}[type(p)]()
        hold = {HysteresisHold: lambda: f'hysteresis {h.current_a:g} A +-'
                                        f'{500 * h.band_a:g} mA',
                PiChopperHold: lambda: f'PI {h.frequency_hz / 1e3:g} kHz {h.current_a:g} A, '
                                       f'off {h.off_voltage_v:g} V',
                ReducedPwmHold: lambda: f'PWM {h.frequency_hz / 1e3:g} kHz duty {h.duty:g}, '
                                        f'off {h.off_voltage_v:g} V'}[type(h)]()
        rel = {CapacitorRelease: lambda: f'capacitor {r.voltage_v:g} V ({r.charging}), '
                                         f'{1e3 * r.discharge_time_s:g} ms',
               ZenerRelease: lambda: f'Zener {r.clamp_v:g} V',
               FreewheelRelease: lambda: f'freewheel {r.diode_drop_v:g} V'}[type(r)]()
        return f'{peak}; {hold}; {rel}; reverse {"blocked" if self.reverse_blocking else "open"}'


@dataclass(frozen=True)
class DriveCircuit:
    """The generator's first (default) driver with its constants as flat fields (SI units):
    dip-and-rise peak end at every integration step, a clocked hysteresis hold with 0 V
    free-wheeling, a capacitor release charged whenever idle, reverse current blocked."""

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

    def electronics(self) -> DriveElectronics:
        """The same driver in the family's form."""
        return DriveElectronics(
            supply_voltage_v=self.supply_voltage_v,
            peak=DipRisePeak(self.dip_threshold_a, self.valley_rise_a, self.max_boost_s),
            hold=HysteresisHold(self.hold_current_a, self.hysteresis_band_a,
                                self.comparator_clock_hz),
            release=CapacitorRelease(self.capacitor_voltage_v, self.capacitor_charge_time_s,
                                     self.capacitor_discharge_time_s, 'idle',
                                     self.capacitor_voltage_v))


def _pi_gains(crossover_hz: float, supply_span_v: float, inductance_h: float = 0.143,
              resistance_ohm: float = 13.0) -> tuple[float, float]:
    """PI gains for a chopper whose duty moves the mean voltage by ``supply_span_v`` [V]:
    crossover at ``crossover_hz`` on the open valve's inductance, PI zero on the coil pole
    R/L. Returns (kp [1/A], ki [1/(A s)])."""
    kp = 2.0 * math.pi * crossover_hz * inductance_h / supply_span_v
    return kp, kp * resistance_ohm / inductance_h


_KP_FAST, _KI_FAST = _pi_gains(400.0, 48.0)
_KP_SLOW, _KI_SLOW = _pi_gains(300.0, 24.7)

#: Named drivers (the matrix and the tests use them by name).
FORMS: dict[str, DriveElectronics] = {
    # the generator's first driver, as DriveCircuit() gives it
    'generator_default': DriveCircuit().electronics(),
    # close to the suite's own driver as its documentation describes it: dip and rise sampled
    # at the 20 kHz chopper rate, a PI chopper with 0 V free-wheeling, a capacitor charged
    # while the main PWM is high and empty at the start
    'suite_like': DriveElectronics(
        peak=DipRisePeak(dip_a=0.01, rise_a=0.0, max_s=0.010, clock_hz=20_000.0),
        hold=PiChopperHold(current_a=0.5, frequency_hz=20_000.0, kp_per_a=20.0,
                           ki_per_a_s=2000.0, off_voltage_v=0.0, anti_windup='clamp'),
        release=CapacitorRelease(voltage_v=24.0, charge_time_s=1e-3, discharge_time_s=0.5e-3,
                                 charging='high', initial_voltage_v=0.0)),
    # dip and rise, a 20 kHz PI chopper with fast decay (-24 V), a capacitor charged only
    # during the peak phase and decaying in 2.5 ms
    'dip_rise_pi_fast_cap_peak': DriveElectronics(
        peak=DipRisePeak(dip_a=0.01, rise_a=0.002, max_s=0.010),
        hold=PiChopperHold(current_a=0.5, frequency_hz=20_000.0, kp_per_a=_KP_FAST,
                           ki_per_a_s=_KI_FAST, off_voltage_v=-24.0),
        release=CapacitorRelease(voltage_v=30.0, charge_time_s=1.5e-3,
                                 discharge_time_s=2.5e-3, charging='peak',
                                 initial_voltage_v=0.0)),
    # a fixed peak time, a hysteresis band with diode free-wheeling, a Zener clamp
    'timer_hysteresis_zener': DriveElectronics(
        peak=TimerPeak(duration_s=5.0e-3),
        hold=HysteresisHold(current_a=0.55, band_a=0.06, clock_hz=40_000.0,
                            off_voltage_v=-0.7),
        release=ZenerRelease(clamp_v=36.0)),
    # a peak current threshold, a reduced-voltage PWM hold, a freewheel diode release
    'threshold_pwm_freewheel': DriveElectronics(
        peak=ThresholdPeak(current_a=0.8, max_s=0.010),
        hold=ReducedPwmHold(duty=0.3, frequency_hz=20_000.0, off_voltage_v=-0.7),
        release=FreewheelRelease(diode_drop_v=0.7)),
    # the dip alone, a PI chopper with diode free-wheeling, a strong capacitor (48 V, 2 ms)
    # charged while idle, and no reverse blocking: the capacitor drives the current negative
    'dip_pi_slow_cap_unblocked': DriveElectronics(
        peak=DipPeak(dip_a=0.02, max_s=0.010),
        hold=PiChopperHold(current_a=0.45, frequency_hz=20_000.0, kp_per_a=_KP_SLOW,
                           ki_per_a_s=_KI_SLOW, off_voltage_v=-0.7),
        release=CapacitorRelease(voltage_v=48.0, charge_time_s=1e-3, discharge_time_s=2e-3,
                                 charging='idle', initial_voltage_v=48.0),
        reverse_blocking=False),
}


def _per_step(rate_hz: float, step_s: float, what: str) -> int:
    """Integration steps per period of a clock; the period must be a whole number."""
    k = int(round(1.0 / (rate_hz * step_s)))
    if k < 1 or abs(k * step_s * rate_hz - 1.0) > 1e-9:
        raise ValueError(f'{what} period (1/{rate_hz:g} Hz) is not a whole number of '
                         f'integration steps of {step_s:g} s')
    return k


class Drive:
    """State of one driver while the integrator runs (see the module text).

    Parameters
    ----------
    electronics : DriveElectronics
        The driver.
    eddy_ohm : float
        Eddy-current resistance of the valve [ohm] (``inf``: none); it sets the voltage of
        an open terminal.
    step_s : float
        Integration step [s]; every clock period must be a whole number of steps.
    """

    def __init__(self, electronics: DriveElectronics, eddy_ohm: float, step_s: float) -> None:
        e = self.e = electronics
        self.eddy_ohm = eddy_ohm
        clock = getattr(e.peak, 'clock_hz', None)
        self.per_detect = 1 if clock is None else _per_step(clock, step_s, 'peak detector')
        hold_hz = e.hold.clock_hz if isinstance(e.hold, HysteresisHold) else \
            e.hold.frequency_hz
        self.per_hold = _per_step(hold_hz, step_s, 'hold clock')
        self.hold_period_s = 1.0 / hold_hz
        self.phase = BLOCKED
        self.switch_on = False
        self.open_circuit = False       # hold: the off part drove the current to zero
        self.pending_s = math.inf       # next switching instant inside a step
        self.boost_start = 0.0
        self.peak_i, self.valley, self.armed = -math.inf, math.inf, False
        self.integ = 0.0
        self.boost_ends: list[float] = []
        rel = e.release
        self.cap = isinstance(rel, CapacitorRelease)
        self.cap_ref_v = rel.initial_voltage_v if self.cap else 0.0
        self.cap_ref_t = 0.0
        self.cap_state = 'charge' if self.cap and rel.charging == 'idle' else 'hold'

    # --- capacitor ------------------------------------------------------------------------
    def capacitor_v(self, t: float) -> float:
        """Capacitor voltage at ``t`` [V]."""
        rel = self.e.release
        dt = t - self.cap_ref_t
        if self.cap_state == 'charge':
            return rel.voltage_v + (self.cap_ref_v - rel.voltage_v) * math.exp(
                -dt / rel.charge_time_s)
        if self.cap_state == 'discharge':
            return self.cap_ref_v * math.exp(-dt / rel.discharge_time_s)
        return self.cap_ref_v

    def _cap_to(self, t: float, state: str) -> None:
        if not self.cap or state == self.cap_state:
            return
        self.cap_ref_v = self.capacitor_v(t)
        self.cap_ref_t = t
        self.cap_state = state

    def _cap_idle(self, t: float) -> None:
        """The capacitor is disconnected from the coil and the peak phase is over."""
        if self.cap:
            charging = self.e.release.charging == 'idle' or (
                self.e.release.charging == 'high' and self.phase == HOLD)
            self._cap_to(t, 'charge' if charging else 'hold')

    # --- applied voltage ------------------------------------------------------------------
    def open_voltage(self, y: list[float]) -> float:
        """Terminal voltage of an open circuit: the one that keeps the terminal current at
        zero (the eddy path still carries the magnetising current) [V]."""
        return -self.eddy_ohm * y[0] if math.isfinite(self.eddy_ohm) else 0.0

    def voltage(self, t: float, y: list[float]) -> float:
        """Voltage the driver puts on the coil terminals [V]."""
        if self.phase == BOOST:
            return self.e.supply_voltage_v
        if self.phase == HOLD:
            if self.switch_on:
                return self.e.supply_voltage_v
            return self.open_voltage(y) if self.open_circuit else self.e.hold.off_voltage_v
        if self.phase == RELEASE:
            rel = self.e.release
            if self.cap:
                return -self.capacitor_v(t)
            return -rel.clamp_v if isinstance(rel, ZenerRelease) else -rel.diode_drop_v
        return self.open_voltage(y)

    # --- main PWM edges -------------------------------------------------------------------
    def rise(self, t: float) -> None:
        """Rising edge of the main PWM: the peak phase begins."""
        self.phase = BOOST
        self.switch_on, self.open_circuit = True, False
        self.boost_start = t
        self.peak_i, self.valley, self.armed = -math.inf, math.inf, False
        self.pending_s = t + self.e.peak.duration_s if isinstance(self.e.peak, TimerPeak) \
            else math.inf
        self._cap_to(t, 'charge')

    def fall(self, t: float) -> None:
        """Falling edge of the main PWM: the release begins."""
        if self.phase in (BOOST, HOLD):
            self.phase = RELEASE
            self.pending_s = math.inf
            self._cap_to(t, 'discharge')

    # --- inside a step --------------------------------------------------------------------
    def switch(self, t: float, i: float) -> None:
        """The pending switching instant ``t`` has come (timer end, chopper turn-off)."""
        self.pending_s = math.inf
        if self.phase == BOOST:
            self._end_peak(t, i)
        elif self.phase == HOLD:
            self.switch_on = False

    def watch_zero(self) -> bool:
        """Whether a negative voltage drives the current towards a zero the driver stops at."""
        if self.phase == RELEASE:
            return self.e.reverse_blocking or not self.cap
        return (self.phase == HOLD and not self.switch_on and not self.open_circuit
                and self.e.hold.off_voltage_v < 0.0 and self.e.reverse_blocking)

    def zero_reached(self, t: float) -> None:
        """The terminal current has reached zero under :meth:`watch_zero`: the circuit opens."""
        if self.phase == RELEASE:
            self.phase = BLOCKED
            self._cap_idle(t)
        else:
            self.open_circuit = True

    def threshold_a(self) -> float | None:
        """The current whose crossing ends the peak phase now, if any [A]."""
        if self.phase == BOOST and isinstance(self.e.peak, ThresholdPeak):
            return self.e.peak.current_a
        return None

    def threshold_reached(self, t: float, i: float) -> None:
        self._end_peak(t, i)

    # --- on the integration grid ----------------------------------------------------------
    def on_grid(self, n: int, t: float, i: float) -> None:
        """Decisions at the end of integration step ``n`` (time ``t``, current ``i``)."""
        if self.phase == BOOST and n % self.per_detect == 0:
            self._detect(t, i)
        if self.phase == HOLD and n % self.per_hold == 0:
            self._hold_tick(t, i)

    def _detect(self, t: float, i: float) -> None:
        p = self.e.peak
        if isinstance(p, (DipPeak, DipRisePeak)):
            if not self.armed:
                self.peak_i = max(self.peak_i, i)
                self.armed = i < self.peak_i - p.dip_a
                self.valley = i
            else:
                self.valley = min(self.valley, i)
            if isinstance(p, DipPeak):
                detected = self.armed
            else:
                detected = self.armed and i > self.valley + p.rise_a
        else:
            detected = False
        limit = getattr(p, 'max_s', math.inf)
        if detected or t - self.boost_start >= limit - 1e-12:
            self._end_peak(t, i)

    def _end_peak(self, t: float, i: float) -> None:
        h = self.e.hold
        self.phase = HOLD
        self.boost_ends.append(t)
        self.pending_s = math.inf
        self.open_circuit = False
        if isinstance(h, HysteresisHold):
            self.switch_on = i < h.current_a - 0.5 * h.band_a
        else:
            # the chopper starts at its next period start
            self.switch_on = False
            if isinstance(h, PiChopperHold):
                vs = self.e.supply_voltage_v
                ff = (h.feedforward_resistance_ohm * h.current_a - h.off_voltage_v) / \
                    (vs - h.off_voltage_v)
                self.integ = min(max(ff, 0.0), 1.0)
        if self.cap and self.e.release.charging == 'peak':
            self._cap_to(t, 'hold')

    def _hold_tick(self, t: float, i: float) -> None:
        h = self.e.hold
        if isinstance(h, HysteresisHold):
            half = 0.5 * h.band_a
            if i < h.current_a - half:
                self.switch_on = True
                self.open_circuit = False
            elif i > h.current_a + half:
                self.switch_on = False
            return
        if isinstance(h, PiChopperHold):
            err = h.current_a - i
            raw = h.kp_per_a * err + self.integ
            if h.anti_windup == 'clamp' or 0.0 < raw < 1.0 or (raw <= 0.0) == (err > 0.0):
                self.integ = min(max(self.integ + h.ki_per_a_s * err * self.hold_period_s,
                                     0.0), 1.0)
            duty = min(max(h.kp_per_a * err + self.integ, 0.0), 1.0)
        else:
            duty = h.duty
        self.switch_on = duty > 0.0
        if self.switch_on:
            self.open_circuit = False
        self.pending_s = t + duty * self.hold_period_s if 0.0 < duty < 1.0 else math.inf
