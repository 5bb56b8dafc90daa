"""A richer truth model of the valve, written independently of the suite's model.

Only the test-data generator uses it. It shares no code with ``valve_model_pkg``: the
equations are written out again here from the paper (eqs. 1-11) and integrated with
:func:`scipy.integrate.solve_ivp` (LSODA, tight tolerances, restarted at every event), so
a bug in the suite's model cannot hide itself in the data it is tested on.

On top of the paper's model it holds every effect the identification declares, each in a
form of its own (the identification's candidate forms may differ, as a real valve's would):

==================  ========================================================================
effect              truth form
==================  ========================================================================
magnetic_saturation flux linkage ``psi = L(x) i_s u / sqrt(1 + u^2)``, ``u = i_m / i_s``;
                    force from the co-energy ``L'(x) i_s^2 (sqrt(1 + u^2) - 1)``
eddy_current        eddy-current path as a resistance ``R_e`` across the magnetising branch
                    (the coil current is the magnetising current plus ``e / R_e``)
coulomb_friction    dry friction ``F_c`` against the motion; a spool at rest (at a stop or
                    stuck) moves only when the net force exceeds the breakaway force
                    ``max(F_c, F_s)`` (stiction ``F_s``; static = kinetic by default), and a
                    spool whose velocity reaches zero sticks while the net force is below it
coil_heating        ``R = R_0 (1 + alpha (T - T_0))``, ``C_th dT/dt = R i^2 - (T - T_0)/R_th``
leakage_inductance  a constant series inductance ``L_s`` that makes no force
end_stop_bounce     Newtonian impact with restitution ``e`` at both end stops
==================  ========================================================================

and two effects outside that list:

==================  ========================================================================
supply_ripple       the bench supply carries a ripple (100 Hz, 8 % in the generated case) and
                    sags with the current through a source resistance; the CSV's voltage
                    column logs the commanded voltage, so the model never sees it
diode_drop          a diode-like drop in the driver path (the switch while on, the freewheel
                    diode while off):
                    ``V_d (1 - exp(-|i| / i_k)) sign(i)`` against the current, at all times
==================  ========================================================================
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np
from scipy.integrate import solve_ivp

MU0 = 4e-7 * math.pi
ALPHA_COPPER_PER_K = 0.0039


@dataclass(frozen=True)
class TruthValve:
    """Parameters of one simulated valve (SI units), effects off by default."""

    # Table 1 (directly measured, known to the identification)
    spool_mass_kg: float = 0.027
    spring_n_m: float = 10_000.0
    turns: float = 1250.0
    area1_m2: float = 26.57e-6
    area2_m2: float = 35.25e-6
    # Table 2 (identified values of the paper)
    core_length_m: float = 0.115
    resistance_ohm: float = 13.0
    stroke_m: float = 0.33e-3
    flux_area_m2: float = 0.8e-4
    pretension_m: float = 1.1e-3
    total_gap_m: float = 0.4e-3
    damping_n_s_m: float = 0.2
    mu_r: float = 120.0
    # effects the identification declares (neutral values switch them off)
    saturation_current_a: float = math.inf
    eddy_resistance_ohm: float = math.inf
    friction_n: float = 0.0
    #: static friction (stiction) [N]; below ``friction_n`` it changes nothing
    stiction_n: float = 0.0
    thermal_capacity_j_k: float = math.inf
    thermal_resistance_k_w: float = 20.0
    leakage_inductance_h: float = 0.0
    restitution: float = 0.0
    # the effect outside the list
    ripple_fraction: float = 0.0
    ripple_hz: float = 100.0
    source_resistance_ohm: float = 0.0
    # a second effect outside the list (a diode-like drop with a knee current)
    diode_drop_v: float = 0.0
    diode_knee_a: float = 0.02

    @property
    def breakaway_n(self) -> float:
        """Net force a spool at rest must exceed to move [N]."""
        return max(self.friction_n, self.stiction_n)

    def inductance(self, x: float) -> float:
        """Position-dependent inductance of eq. (4) [H]."""
        leq = self.core_length_m + 2.0 * self.mu_r * (self.total_gap_m - x)
        return self.turns ** 2 * self.flux_area_m2 * MU0 * self.mu_r / leq

    def as_dict(self) -> dict[str, float]:
        """All fields as a plain dict (inf as a string for YAML/JSON)."""
        return {k: (v if math.isfinite(v) else 'inf') for k, v in asdict(self).items()}


@dataclass
class TruthTrace:
    """Output of :func:`simulate_truth` on the requested sample times."""

    t_s: np.ndarray
    voltage_cmd_v: np.ndarray
    current_a: np.ndarray
    position_m: np.ndarray
    temperature_rise_k: np.ndarray


# Mechanical modes: the spool is either free or held (at a stop or stuck by friction).
_FREE, _HELD = 0, 1
_V_STICK = 1e-4          # m/s: below this speed after an impact the spool stays at the stop
_ATOL = np.array([1e-7, 1e-7, 1e-10, 1e-7, 1e-6])


class _Truth:
    """Right-hand side and event functions for one valve and one voltage segment."""

    def __init__(self, valve: TruthValve, supply_pa: float) -> None:
        self.v = valve
        self.p_force = (valve.area1_m2 - valve.area2_m2) * supply_pa
        self.sat = math.isfinite(valve.saturation_current_a)
        self.eddy = math.isfinite(valve.eddy_resistance_ohm)
        self.leak = valve.leakage_inductance_h > 0.0
        self.heat = math.isfinite(valve.thermal_capacity_j_k)
        self.kf = valve.turns ** 2 * valve.flux_area_m2 * MU0

    # flux linkage of the magnetising branch and its partial derivatives
    def psi(self, im: float, x: float) -> tuple[float, float, float]:
        """Return (psi, dpsi/di, dpsi/dx) of the magnetising branch."""
        L = self.v.inductance(x)
        dL = 2.0 * L * L / self.kf
        if not self.sat:
            return L * im, L, dL * im
        s = self.v.saturation_current_a
        u = im / s
        root = math.sqrt(1.0 + u * u)
        return L * s * u / root, L / root ** 3, dL * s * u / root

    def force(self, im: float, x: float) -> float:
        """Magnetic force from the co-energy [N]."""
        L = self.v.inductance(x)
        dL = 2.0 * L * L / self.kf
        if not self.sat:
            return 0.5 * dL * im * im
        s = self.v.saturation_current_a
        return dL * s * s * (math.sqrt(1.0 + (im / s) ** 2) - 1.0)

    def resistance(self, temp_rise: float) -> float:
        return self.v.resistance_ohm * (1.0 + ALPHA_COPPER_PER_K * temp_rise)

    def supply(self, t: float, v_cmd: float, i: float) -> float:
        """Voltage that really reaches the coil (the outside-the-list effect)."""
        v = self.v
        drop = 0.0
        if v.diode_drop_v:
            drop = math.copysign(v.diode_drop_v * -math.expm1(-abs(i) / v.diode_knee_a), i)
        if v.ripple_fraction == 0.0 and v.source_resistance_ohm == 0.0:
            return v_cmd - drop
        ripple = 1.0 + v.ripple_fraction * math.sin(2.0 * math.pi * v.ripple_hz * t)
        # The sag only exists while the supply drives the coil (not in freewheel at 0 V).
        sag = v.source_resistance_ohm * i if v_cmd != 0.0 else 0.0
        return v_cmd * ripple - sag - drop

    def electrical(self, t: float, y: np.ndarray, v_cmd: float, vel: float
                   ) -> tuple[float, float, float]:
        """Return (coil current, d i_m/dt, d i/dt) for state y = [i_m, i, x, v, T]."""
        im, i_state, x, _, temp = y
        R = self.resistance(temp)
        _, dpsi_di, dpsi_dx = self.psi(im, x)
        if self.leak:
            i = i_state
            e = (i - im) * self.v.eddy_resistance_ohm if self.eddy else None
            if e is None:
                # Without eddy path i == i_m; the two inductances add.
                V = self.supply(t, v_cmd, im)
                di = (V - R * im - dpsi_dx * vel) / (dpsi_di + self.v.leakage_inductance_h)
                return im, di, di
            V = self.supply(t, v_cmd, i)
            di = (V - R * i - e) / self.v.leakage_inductance_h
        else:
            if self.eddy:
                Re = self.v.eddy_resistance_ohm
                # V = R i + e and i = i_m + e/Re, solved for i (the supply sag is linear
                # in i, handled by iterating once: it is tiny against R).
                V = self.supply(t, v_cmd, im)
                i = (V + Re * im) / (R + Re)
                V = self.supply(t, v_cmd, i)
                i = (V + Re * im) / (R + Re)
                e = V - R * i
            else:
                V = self.supply(t, v_cmd, im)
                i = im
                e = V - R * im
            di = 0.0
        dim = (e - dpsi_dx * vel) / dpsi_di
        return i, dim, di

    def drive_force(self, im: float, x: float) -> float:
        """Net force without damping and friction, positive towards open [N]."""
        v = self.v
        return self.force(im, x) - v.spring_n_m * (x + v.pretension_m) + self.p_force

    def rhs(self, t: float, y: np.ndarray, v_cmd: float, mode: int) -> np.ndarray:
        im, _, x, vel, temp = y
        if mode == _HELD:
            vel = 0.0
        i, dim, di = self.electrical(t, y, v_cmd, vel)
        if mode == _HELD:
            acc = 0.0
        else:
            v = self.v
            fric = v.friction_n * math.copysign(1.0, vel) if vel != 0.0 else 0.0
            acc = (self.drive_force(im, x) - v.damping_n_s_m * vel - fric) / v.spool_mass_kg
        dtemp = 0.0
        if self.heat:
            R = self.resistance(temp)
            dtemp = (R * i * i - temp / self.v.thermal_resistance_k_w) / \
                self.v.thermal_capacity_j_k
        return np.array([dim, di, vel, acc, dtemp])


def _events(model: _Truth, mode: int, held_at: str, moving_sign: float):
    """Event functions ending the current integration piece."""
    v = model.v
    if mode == _HELD:
        fc = v.breakaway_n

        def release(t, y, *_):
            f = model.drive_force(y[0], y[2])
            if held_at == 'closed':
                return f - fc
            if held_at == 'open':
                return -f - fc
            return abs(f) - fc
        release.terminal = True
        release.direction = 1
        return [release]

    def hit_open(t, y, *_):
        return y[2] - v.stroke_m
    hit_open.terminal = True
    hit_open.direction = 1

    def hit_closed(t, y, *_):
        return y[2]
    hit_closed.terminal = True
    hit_closed.direction = -1
    evs = [hit_open, hit_closed]
    if v.breakaway_n > 0.0:
        def stop(t, y, *_):
            return y[3]
        stop.terminal = True
        # Only the reversal of the present motion counts (v starts at 0 after a release).
        stop.direction = -moving_sign
        evs.append(stop)
    return evs


def simulate_truth(valve: TruthValve, segments: list[tuple[float, float]], t_end_s: float,
                   t_samples: np.ndarray, supply_pa: float) -> TruthTrace:
    """Simulate the truth model under a piecewise-constant commanded voltage.

    Parameters
    ----------
    valve : TruthValve
        The valve instance.
    segments : list of (start time [s], voltage [V])
        Commanded voltage from each start time on; the first starts at 0.
    t_end_s : float
        End of the simulation [s].
    t_samples : numpy.ndarray
        Times at which to report the state [s], within [0, t_end_s].
    supply_pa : float
        Supply pressure, gauge [Pa].

    Returns
    -------
    TruthTrace
    """
    model = _Truth(valve, supply_pa)
    y = np.zeros(5)
    mode, held_at = _HELD, 'closed'
    ts_out: list[np.ndarray] = []
    ys_out: list[np.ndarray] = []
    modes_out: list[int] = []
    bounds = [s[0] for s in segments[1:]] + [t_end_s]
    t = 0.0
    pieces = 0
    for (t0, v_cmd), t1 in zip(segments, bounds):
        t = max(t, t0)
        while t < t1 - 1e-15:
            pieces += 1
            if pieces > 10_000:
                raise RuntimeError(f'truth model stuck in events near t = {t:.9g} s')
            if mode == _FREE:
                moving_sign = math.copysign(1.0, y[3]) if y[3] != 0.0 else math.copysign(
                    1.0, model.drive_force(y[0], y[2]))
            else:
                moving_sign = 1.0
            events = _events(model, mode, held_at, moving_sign)
            sel = (t_samples >= t) & (t_samples <= t1)
            sol = solve_ivp(model.rhs, (t, t1), y, method='LSODA', args=(v_cmd, mode),
                            events=events, dense_output=True, rtol=1e-8, atol=_ATOL,
                            max_step=2e-4 if valve.ripple_fraction else 5e-4,
                            first_step=1e-8)
            if sol.status < 0:
                raise RuntimeError(f'truth model failed: {sol.message}')
            t_stop = float(sol.t[-1])
            ts = t_samples[sel & (t_samples < t_stop)] if sol.status == 1 else t_samples[sel]
            if ts.size:
                ts_out.append(ts)
                ys_out.append(sol.sol(ts).T)
                modes_out.extend([mode] * ts.size)
            t_prev = t
            y = sol.y[:, -1].copy()
            t = t_stop
            if sol.status != 1:
                break
            # Which event ended the piece decides the next mode.
            fired = [k for k, te in enumerate(sol.t_events) if te.size]
            k = fired[0]
            if mode == _HELD:
                # Leave the stop (or the stuck point) moving the way the force pushes, so
                # kinetic friction and the stop events see a definite direction.
                mode = _FREE
                direction = {'closed': 1.0, 'open': -1.0}.get(
                    held_at, math.copysign(1.0, model.drive_force(y[0], y[2])))
                y[3] = 1e-9 * direction
                continue
            if k in (0, 1):
                at_open = k == 0
                y[2] = valve.stroke_m if at_open else 0.0
                if valve.restitution > 0.0 and abs(y[3]) * valve.restitution > _V_STICK * 100:
                    y[3] = -valve.restitution * y[3]
                else:
                    y[3] = 0.0
                    mode, held_at = _HELD, 'open' if at_open else 'closed'
            else:
                # Velocity crossed zero under friction: stick if the force cannot break free.
                y[3] = 0.0
                f = model.drive_force(y[0], y[2])
                if abs(f) <= valve.breakaway_n:
                    mode, held_at = _HELD, 'mid'
            if t - t_prev < 1e-12:
                # Guard against event chatter at the same instant.
                t += 1e-9
    t_all = np.concatenate(ts_out) if ts_out else np.empty(0)
    y_all = np.concatenate(ys_out) if ys_out else np.empty((0, 5))
    order = np.argsort(t_all, kind='stable')
    t_all, y_all = t_all[order], y_all[order]
    # A sample on a voltage edge belongs to the piece after it (the voltage column shows
    # the new level there): keep the last of duplicate times.
    rev = t_all[::-1]
    _, last_rev = np.unique(rev, return_index=True)
    first = t_all.size - 1 - last_rev
    t_all, y_all = t_all[first], y_all[first]
    if t_all.size != t_samples.size:
        raise RuntimeError(f'truth model covered {t_all.size} of {t_samples.size} samples')
    modes = np.array(modes_out)[order][first]
    v_cmd = np.interp(t_all, [s[0] for s in segments], [s[1] for s in segments])
    v_cmd = np.array([_segment_voltage(segments, tt) for tt in t_all])
    cur = np.empty(t_all.size)
    for n in range(t_all.size):
        vel = 0.0 if modes[n] == _HELD else y_all[n, 3]
        cur[n] = model.electrical(t_all[n], y_all[n], v_cmd[n], vel)[0]
    pos = np.clip(y_all[:, 2], 0.0, valve.stroke_m)
    return TruthTrace(t_s=t_all, voltage_cmd_v=v_cmd, current_a=cur, position_m=pos,
                      temperature_rise_k=y_all[:, 4])


def _segment_voltage(segments: list[tuple[float, float]], t: float) -> float:
    v = segments[0][1]
    for t0, vv in segments:
        if t >= t0:
            v = vv
    return v


def perturbed(valve: TruthValve, rng: np.random.Generator, spread: float = 0.12
              ) -> TruthValve:
    """A valve instance whose Table 2 parameters differ from the paper's by up to ``spread``.

    The instance must still open at 15 V and 24 V and release at 0 V; the caller checks
    that on the simulated traces.
    """
    names = ['core_length_m', 'resistance_ohm', 'stroke_m', 'flux_area_m2', 'pretension_m',
             'total_gap_m', 'damping_n_s_m', 'mu_r']
    changes = {n: getattr(valve, n) * (1.0 + rng.uniform(-spread, spread)) for n in names}
    # x_t must stay larger than the stroke (a holding gap remains).
    changes['total_gap_m'] = max(changes['total_gap_m'], changes['stroke_m'] + 0.04e-3)
    return replace(valve, **changes)
