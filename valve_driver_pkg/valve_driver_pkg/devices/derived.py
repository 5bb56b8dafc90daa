"""The spool's period-mean position derived from the duty in force (the static duty map).

A device that reports no spool position (a CiA 401 module with current feedback only, a
J1939 auxiliary valve) still leaves the suite one honest estimate of the opening: the
valve's periodic steady state at the duty in force, read from the suite's static duty map
(paper Section 5, :mod:`valve_model_pkg.maps`). The driver publishes it as
``spool_position`` and ``spool_position_avg`` with ``position_measured = false`` and the
mass flow from it (eq. 12); the driver's README marks these fields "derived".

The map holds steady states only: after a duty change the derived position takes the new
value at once, where the valve takes a few PWM periods to get there, and it carries no
ripple within a period.
"""
from __future__ import annotations

import math
from functools import lru_cache

from valve_driver_pkg.errors import MappingError
from valve_model_pkg.errors import MapError
from valve_model_pkg.maps import DutyMap, FlowToDutyInverter, load_map

__all__ = ['DerivedOpening', 'derived_opening_for']

#: Duties and pressures are rounded this far before the map is read (cache keys).
_DUTY_STEP = 1e-4
_PRESSURE_STEP_PA = 100.0


class DerivedOpening:
    """x_avg [m] of the valve at periodic steady state for a duty, frequency and pressure.

    Parameters
    ----------
    duty_map : DutyMap
        The valve's static duty map (its parameters must be the valve's).
    map_path : str
        Where the map came from (messages).
    """

    def __init__(self, duty_map: DutyMap, map_path: str = '<map>') -> None:
        self.map = duty_map
        self.map_path = map_path
        self.frequencies_hz = tuple(float(f) for f in duty_map.pwm_frequencies_hz)
        self._inverters: dict[float, FlowToDutyInverter] = {}
        self._position = lru_cache(maxsize=4096)(self._position_uncached)

    @classmethod
    def load(cls, map_file: str, params: object, params_source: str) -> DerivedOpening:
        """Read the map (``''``: the suite's shipped map) and check it fits ``params``.

        Raises
        ------
        MappingError
            The map cannot be read or was made for other valve parameters (named).
        """
        try:
            duty_map = load_map(map_file or None)
            path = map_file or 'the suite\'s duty map'
            duty_map.check_parameters(params, path, params_source)
        except (MapError, OSError) as err:
            raise MappingError(f'derived position and flow need the valve\'s duty map '
                               f'(duty_map_file): {err}') from err
        return cls(duty_map, map_file or 'valve_model_pkg config/valve_map.json')

    def covers(self, pwm_frequency_hz: float) -> bool:
        """True if the map holds a curve for this PWM frequency."""
        return any(math.isclose(pwm_frequency_hz, f, rel_tol=1e-9) for f in self.frequencies_hz)

    def position_avg_m(self, duty: float, pwm_frequency_hz: float,
                       supply_pressure_pa: float) -> float:
        """x_avg [m] at ``duty`` [1], ``pwm_frequency_hz`` [Hz] and gauge supply [Pa].

        NaN if the frequency has no curve in the map or an input is not finite; the supply
        pressure is clamped to the map's range (its nearest curve outside it).
        """
        if not (math.isfinite(duty) and math.isfinite(supply_pressure_pa)) \
                or not self.covers(pwm_frequency_hz):
            return math.nan
        duty = min(max(duty, 0.0), 1.0)
        return self._position(round(duty / _DUTY_STEP) * _DUTY_STEP, float(pwm_frequency_hz),
                              round(supply_pressure_pa / _PRESSURE_STEP_PA) * _PRESSURE_STEP_PA)

    def _position_uncached(self, duty: float, pwm_frequency_hz: float, supply_pa: float) -> float:
        inverter = self._inverters.get(pwm_frequency_hz)
        if inverter is None:
            inverter = self._inverters[pwm_frequency_hz] = FlowToDutyInverter(
                self.map, pwm_frequency_hz)
        fraction = inverter.duty_to_position(duty, supply_pa)
        return fraction * inverter.constants.stroke_m


def derived_opening_for(measures_position: bool, map_file: str, params: object,
                        params_source: str, pwm_frequency_hz: float) -> DerivedOpening | None:
    """The derivation a device needs: None if it reports its position, else the duty map.

    Raises
    ------
    MappingError
        The map cannot be read, was made for other valve parameters, or has no curve at
        ``pwm_frequency_hz`` (the device's PWM frequency); each named.
    """
    if measures_position:
        return None
    derived = DerivedOpening.load(map_file, params, params_source)
    if not derived.covers(pwm_frequency_hz):
        raise MappingError(
            f'pwm_frequency_hz {pwm_frequency_hz:g} (the device\'s PWM frequency) has no '
            f'curve in the duty map {derived.map_path} '
            f'({", ".join(f"{f:g}" for f in derived.frequencies_hz)} Hz)')
    return derived
