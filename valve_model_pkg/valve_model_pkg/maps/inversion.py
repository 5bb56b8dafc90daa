"""Flow -> duty: the orifice equation solved for the opening, then the static map inverted.

Given a demanded mass flow and the present supply and output pressures, the
:class:`FlowToDutyInverter`

1. computes the averaged opening the orifice equation (eq. 12) needs:
   ``x_avg = q / K(p_sup, p_out)`` with ``K`` the flow per metre of opening, choked or
   subsonic by the ratio of the ABSOLUTE pressures (the inputs are gauge; the atmospheric
   pressure is added);
2. inverts the static duty map at the present supply pressure. Between two grid pressures
   each neighbouring curve is inverted for the needed opening and the two duties are
   interpolated linearly in pressure (horizontal interpolation: the paper's Fig. 8 shows the
   supply pressure shifting the curve along the duty axis, so duties interpolate better than
   openings). Outside the grid the nearest curve is used and the result says so;
3. saturates: a flow beyond reach gives duty 1 (status ``SATURATED_HIGH``), zero flow
   gives duty 0 (``SATURATED_LOW``); no forward pressure difference gives duty 0
   (``NO_PRESSURE``).

Dead-band rule (explicit): the map says the valve leaves its closed stop first at the
*opening duty* ``d_open`` (the first grid duty with a non-zero average opening; between grid
pressures the pressure interpolation of the neighbours' opening duties). A positive flow
whose needed opening ``r`` is below the opening at ``d_open`` (``r_open``) is never given a
duty between 0 and ``d_open``, where the coil would be driven without opening the valve:
it is sent as duty 0 (``SATURATED_LOW``) if ``r < zero_fraction * r_open``, else as
``d_open`` (``DEAD_BAND_LIFTED``). ``zero_fraction = 0.5`` (the default) picks whichever of
the two flows is nearer to the demand; 0 always lifts, 1 always closes.

The computation is plain Python on precomputed lists (no numpy per call) so that one
command costs a few microseconds.
"""
from __future__ import annotations

import bisect
import enum
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..model.constants import ATMOSPHERIC_PRESSURE_PA
from .curves import monotone_envelope
from .dutymap import DutyMap

__all__ = ['ATMOSPHERIC_PRESSURE_PA', 'FlowStatus', 'FlowToDutyResult', 'OrificeConstants',
           'FlowToDutyInverter', 'flow_per_opening', 'invalid_flow_reason']

#: Standard atmosphere [Pa], added to gauge pressures for eq. (12).
#: Relative slack before a demand counts as above the largest reachable opening.
_SATURATION_SLACK = 1e-9


class FlowStatus(enum.IntEnum):
    """Outcome of one flow command (equal to valve_msgs/FlowToDutyStatus STATUS_*)."""

    OK = 0
    SATURATED_HIGH = 1
    SATURATED_LOW = 2
    DEAD_BAND_LIFTED = 3
    REJECTED = 4
    NO_PRESSURE = 5


@dataclass(frozen=True)
class OrificeConstants:
    """The constants of eq. (12) and the stroke, from a valve parameter set.

    Attributes
    ----------
    discharge_coefficient : float
        C_d [1].
    orifice_area_gradient_m : float
        C_A, orifice area per metre of opening [m^2/m].
    supply_temperature_k : float
        T [K].
    gas_constant_j_per_kg_k : float
        R [J/(kg K)].
    heat_capacity_ratio : float
        gamma [1].
    stroke_m : float
        x_max [m].
    """

    discharge_coefficient: float
    orifice_area_gradient_m: float
    supply_temperature_k: float
    gas_constant_j_per_kg_k: float
    heat_capacity_ratio: float
    stroke_m: float

    @classmethod
    def from_parameters(cls, params: Any) -> OrificeConstants:
        """From a ValveParameters or its nested/flat dict."""
        if isinstance(params, dict):
            flat: dict[str, Any] = {}
            for v in params.values():
                if isinstance(v, dict):
                    flat.update(v)
            flat.update({k: v for k, v in params.items() if not isinstance(v, dict)})
            get = flat.__getitem__
        else:
            def get(name: str) -> Any:
                return getattr(params, name)
        return cls(*(float(get(n)) for n in (
            'discharge_coefficient', 'orifice_area_gradient_m', 'supply_temperature_k',
            'gas_constant_j_per_kg_k', 'heat_capacity_ratio', 'stroke_m')))


def flow_per_opening(supply_pressure_pa: float, output_pressure_pa: float,
                     c: OrificeConstants, supply_temperature_k: float | None = None,
                     atmospheric_pressure_pa: float = ATMOSPHERIC_PRESSURE_PA
                     ) -> tuple[float, bool]:
    """Mass flow per metre of averaged opening, eq. (12) divided by x_avg.

    Parameters
    ----------
    supply_pressure_pa, output_pressure_pa : float
        Gauge pressures [Pa]; eq. (12) uses the absolute ones (atmosphere added).
    c : OrificeConstants
    supply_temperature_k : float, optional
        Overrides ``c.supply_temperature_k``.
    atmospheric_pressure_pa : float

    Returns
    -------
    tuple
        (K in kg/(s m), choked). K is 0 when the flow would not go from supply to output.
    """
    p_up = supply_pressure_pa + atmospheric_pressure_pa
    p_down = output_pressure_pa + atmospheric_pressure_pa
    if p_up <= 0.0 or p_down >= p_up:
        return 0.0, False
    gamma = c.heat_capacity_ratio
    temp = c.supply_temperature_k if supply_temperature_k is None else supply_temperature_k
    base = c.discharge_coefficient * c.orifice_area_gradient_m * p_up / math.sqrt(temp)
    ratio = max(p_down, 0.0) / p_up
    crit = (2.0 / (gamma + 1.0)) ** (gamma / (gamma - 1.0))
    if ratio <= crit:
        choke = math.sqrt(gamma / c.gas_constant_j_per_kg_k
                          * (2.0 / (gamma + 1.0)) ** ((gamma + 1.0) / (gamma - 1.0)))
        return choke * base, True
    term = ratio ** (2.0 / gamma) - ratio ** ((gamma + 1.0) / gamma)
    return base * math.sqrt(max(0.0, 2.0 * gamma / (c.gas_constant_j_per_kg_k
                                                    * (gamma - 1.0)) * term)), False


def invalid_flow_reason(mass_flow_kg_s: float) -> str | None:
    """Why a flow command is unusable (NaN, infinite, negative), or None if it is valid."""
    if isinstance(mass_flow_kg_s, bool) or not isinstance(mass_flow_kg_s, (int, float)):
        return f'mass_flow {mass_flow_kg_s!r} is not a number'
    if math.isnan(mass_flow_kg_s):
        return 'mass_flow is NaN'
    if math.isinf(mass_flow_kg_s):
        return f'mass_flow is {mass_flow_kg_s!r} (infinite)'
    if mass_flow_kg_s < 0.0:
        return f'mass_flow {mass_flow_kg_s!r} kg/s is negative (the valve cannot reverse it)'
    return None


@dataclass(slots=True)
class FlowToDutyResult:
    """Answer to one flow command (fields as in valve_msgs/FlowToDutyStatus).

    Attributes
    ----------
    requested_mass_flow : float
        Flow asked for [kg/s].
    achievable_mass_flow : float
        Flow the chosen duty should give at steady state, per the map [kg/s].
    max_mass_flow : float
        Flow at 100 % duty at these pressures [kg/s].
    position_fraction : float
        x_avg / x_max that eq. (12) needs for the requested flow [1] (may exceed 1).
    duty : float
        Duty to send [1].
    pwm_frequency_hz : float
    supply_pressure_pa, output_pressure_pa : float
        Gauge pressures used [Pa].
    choked : bool
    status : FlowStatus
    message : str
    """

    requested_mass_flow: float
    achievable_mass_flow: float
    max_mass_flow: float
    position_fraction: float
    duty: float
    pwm_frequency_hz: float
    supply_pressure_pa: float
    output_pressure_pa: float
    choked: bool
    status: FlowStatus
    message: str


class _Curve:
    """One map curve prepared for inversion (plain Python lists, monotone envelope)."""

    __slots__ = ('duty', 'frac', 'open_idx', 'r_open', 'r_max', 'jump_after')

    def __init__(self, duty: list[float], frac: list[float], stop_tolerance: float,
                 jumps: list[tuple[float, float, float, float]]) -> None:
        self.duty = duty
        self.frac = frac
        n = len(frac)
        self.open_idx = next((k for k in range(n) if frac[k] > stop_tolerance), n)
        self.r_open = frac[self.open_idx] if self.open_idx < n else math.inf
        self.r_max = frac[-1]
        # indices k whose segment (k, k + 1) is a jump of the curve
        starts = {round(j[0], 12) for j in jumps}
        self.jump_after = frozenset(k for k in range(n - 1) if round(duty[k], 12) in starts)

    def opening_duty(self) -> float:
        return self.duty[self.open_idx] if self.open_idx < len(self.duty) else 1.0

    def invert(self, r: float) -> tuple[float, float]:
        """(lowest duty giving opening r, opening reached) for r_open <= r <= r_max.

        Linear between points; inside a jump of the curve the nearer side is taken.
        """
        frac, duty = self.frac, self.duty
        k = bisect.bisect_left(frac, r, self.open_idx)
        if k <= self.open_idx:
            return duty[self.open_idx], frac[self.open_idx]
        if k >= len(frac):
            return duty[-1], frac[-1]
        f0, f1 = frac[k - 1], frac[k]
        if k - 1 in self.jump_after and r < f1:
            return (duty[k - 1], f0) if r - f0 <= f1 - r else (duty[k], f1)
        return duty[k - 1] + (r - f0) / (f1 - f0) * (duty[k] - duty[k - 1]), r


class FlowToDutyInverter:
    """Flow command -> duty for one PWM frequency of a duty map (ROS-free, fast).

    Parameters
    ----------
    duty_map : DutyMap
    pwm_frequency_hz : float
        Must be one of the map's frequencies.
    supply_temperature_k : float, optional
        T of eq. (12) (default: the map's parameter set).
    zero_fraction : float
        Dead-band rule threshold in [0, 1] (see the module docstring).
    atmospheric_pressure_pa : float

    Raises
    ------
    KeyError
        If the frequency is not in the map.
    ValueError
        On a bad ``zero_fraction`` or temperature.
    """

    def __init__(self, duty_map: DutyMap, pwm_frequency_hz: float, *,
                 supply_temperature_k: float | None = None, zero_fraction: float = 0.5,
                 atmospheric_pressure_pa: float = ATMOSPHERIC_PRESSURE_PA) -> None:
        i_f = duty_map.frequency_index(pwm_frequency_hz)
        if not 0.0 <= zero_fraction <= 1.0:
            raise ValueError(f'zero_fraction must lie in [0, 1], got {zero_fraction!r}')
        self.map = duty_map
        self.pwm_frequency_hz = float(duty_map.pwm_frequencies_hz[i_f])
        self.constants = OrificeConstants.from_parameters(duty_map.parameters)
        temp = self.constants.supply_temperature_k if supply_temperature_k is None \
            else float(supply_temperature_k)
        if not (math.isfinite(temp) and temp > 0.0):
            raise ValueError(f'supply_temperature_k must be positive, got {temp!r}')
        self.supply_temperature_k = temp
        self.zero_fraction = float(zero_fraction)
        self.atmospheric_pressure_pa = float(atmospheric_pressure_pa)
        self._curves = []
        for j in range(duty_map.supply_pressures_pa.size):
            d, x = duty_map.curve_points(i_f, j)
            self._curves.append(_Curve([float(v) for v in d],
                                       [float(v) for v in monotone_envelope(x)],
                                       duty_map.stop_tolerance, duty_map.jumps(i_f, j)))
        self._pressures = [float(p) for p in duty_map.supply_pressures_pa]

    # --- pieces ---------------------------------------------------------------------------
    def _bracket(self, supply_pa: float) -> tuple[int, float, str]:
        """(index of the lower curve, weight of the upper one, note) for a supply pressure."""
        ps = self._pressures
        if supply_pa <= ps[0]:
            note = '' if supply_pa >= ps[0] - 1e-6 else \
                f'; supply {supply_pa:.6g} Pa below the map, using its {ps[0]:.6g} Pa curve'
            return 0, 0.0, note
        if supply_pa >= ps[-1]:
            note = '' if supply_pa <= ps[-1] + 1e-6 else \
                f'; supply {supply_pa:.6g} Pa above the map, using its {ps[-1]:.6g} Pa curve'
            return len(ps) - 1, 0.0, note
        j = bisect.bisect_right(ps, supply_pa) - 1
        return j, (supply_pa - ps[j]) / (ps[j + 1] - ps[j]), ''

    def opening_duty(self, supply_pressure_pa: float) -> float:
        """Lowest duty the rule ever sends for a positive flow at this supply pressure."""
        j, w, _ = self._bracket(supply_pressure_pa)
        a = self._curves[j]
        if w == 0.0:
            return a.opening_duty()
        b = self._curves[j + 1]
        return a.opening_duty() + w * (b.opening_duty() - a.opening_duty())

    def position_to_duty(self, r: float, supply_pressure_pa: float) -> tuple[float, float]:
        """Invert the map for opening ``r`` (r_open <= r <= r_max): (duty, opening reached)."""
        j, w, _ = self._bracket(supply_pressure_pa)
        a = self._curves[j]
        if w == 0.0:
            return a.invert(min(max(r, a.r_open), a.r_max))
        b = self._curves[j + 1]
        r_open = a.r_open + w * (b.r_open - a.r_open)
        r_max = a.r_max + w * (b.r_max - a.r_max)
        rr = min(max(r, r_open), r_max)
        da, ra = a.invert(min(max(rr, a.r_open), a.r_max))
        db, rb = b.invert(min(max(rr, b.r_open), b.r_max))
        return da + w * (db - da), ra + w * (rb - ra)

    # --- the whole computation ------------------------------------------------------------
    def compute(self, mass_flow_kg_s: float, supply_pressure_pa: float,
                output_pressure_pa: float = 0.0) -> FlowToDutyResult:
        """Duty for a flow command at the given gauge pressures.

        The flow must be valid (see :func:`invalid_flow_reason`); the caller rejects bad
        commands. Pressures must be finite.
        """
        q = float(mass_flow_kg_s)
        p_s = float(supply_pressure_pa)
        p_o = float(output_pressure_pa)
        freq = self.pwm_frequency_hz
        k_flow, choked = flow_per_opening(p_s, p_o, self.constants, self.supply_temperature_k,
                                          self.atmospheric_pressure_pa)
        if k_flow <= 0.0:
            return FlowToDutyResult(q, 0.0, 0.0, math.inf if q > 0.0 else 0.0, 0.0, freq, p_s,
                                    p_o, False, FlowStatus.NO_PRESSURE,
                                    f'no flow from supply {p_s:.6g} Pa to output {p_o:.6g} Pa '
                                    '(gauge): duty 0')
        per_fraction = k_flow * self.constants.stroke_m   # flow at x_avg = x_max
        r = q / per_fraction
        j, w, note = self._bracket(p_s)
        a = self._curves[j]
        if w == 0.0:
            r_open, r_max = a.r_open, a.r_max
        else:
            b = self._curves[j + 1]
            r_open = a.r_open + w * (b.r_open - a.r_open)
            r_max = a.r_max + w * (b.r_max - a.r_max)
        q_max = r_max * per_fraction
        if q <= 0.0:
            return FlowToDutyResult(q, 0.0, q_max, 0.0, 0.0, freq, p_s, p_o, choked,
                                    FlowStatus.SATURATED_LOW, 'zero flow: duty 0' + note)
        if r > r_max * (1.0 + _SATURATION_SLACK) or math.isinf(r_open):
            return FlowToDutyResult(q, q_max, q_max, r, 1.0, freq, p_s, p_o, choked,
                                    FlowStatus.SATURATED_HIGH,
                                    f'flow {q:.6g} kg/s beyond reach (max {q_max:.6g} kg/s): '
                                    'duty 100 %' + note)
        if r < r_open:
            q_open = r_open * per_fraction
            if r < self.zero_fraction * r_open:
                return FlowToDutyResult(q, 0.0, q_max, r, 0.0, freq, p_s, p_o, choked,
                                        FlowStatus.SATURATED_LOW,
                                        f'flow {q:.6g} kg/s below {self.zero_fraction:g} x the '
                                        f'smallest deliverable {q_open:.6g} kg/s: duty 0'
                                        + note)
            duty, _ = self.position_to_duty(r_open, p_s)
            return FlowToDutyResult(q, q_open, q_max, r, duty, freq, p_s, p_o, choked,
                                    FlowStatus.DEAD_BAND_LIFTED,
                                    f'flow {q:.6g} kg/s lifted out of the dead band to the '
                                    f'opening duty {duty:.4g} ({q_open:.6g} kg/s)' + note)
        duty, rr = self.position_to_duty(r, p_s)
        if abs(rr - r) > 1e-9 * max(r, 1.0):
            note = (f'; flow {q:.6g} kg/s falls in a jump of the map, nearest reachable '
                    f'{rr * per_fraction:.6g} kg/s') + note
        return FlowToDutyResult(q, rr * per_fraction, q_max, r, duty, freq, p_s, p_o, choked,
                                FlowStatus.OK, 'ok' + note)

    # --- forward direction (for tests and tools) ------------------------------------------
    def duty_to_position(self, duty: float, supply_pressure_pa: float) -> float:
        """x_avg / x_max of the map at a duty, pressures interpolated horizontally."""
        j, w, _ = self._bracket(supply_pressure_pa)
        a = self._curves[j]
        fa = float(np.interp(duty, a.duty, a.frac)) if duty >= a.opening_duty() else 0.0
        if w == 0.0:
            return fa
        b = self._curves[j + 1]
        # horizontal interpolation: the opening whose interpolated inverse is `duty`
        lo, hi = 0.0, max(a.r_max, b.r_max)
        if duty <= self.opening_duty(supply_pressure_pa) - 1e-12:
            return 0.0
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            d_mid, _ = self.position_to_duty(mid, supply_pressure_pa)
            if d_mid < duty:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)
