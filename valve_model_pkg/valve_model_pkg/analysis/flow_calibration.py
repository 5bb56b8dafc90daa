"""The flow scale of an identified parameter set, calibrated on a run's chamber.

The coil current sees the spool's stroke and spring pretension only weakly, so an
identified ``stroke_m`` and ``spring_pretension_m`` (hence the map's absolute opening
x_avg(d)) can be off by tens of per cent while the current fits well; ``flow_to_duty``
would then command a flow scale the valve does not deliver. The chamber's mass balance
(C2) measures the flow the valve delivers: with the opening the identified map gives at
the recorded duty commands, :func:`identify_from_chamber` fits C_d C_A (C_d kept, C_A
scaled), so the product C_d C_A x_map(d), which ``flow_to_duty`` inverts, matches the
valve. The map's curves do not depend on C_d, C_A.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..maps import DutyMap
from ..maps.flow_check import map_flow_position
from ..maps.flow_identification import identify_from_chamber
from ..model import ValveParameters
from ..pneumatics.cylinder import CylinderParameters
from .chamber import RunChamber

__all__ = ['FLOW_CALIBRATION_WINDOW_S', 'FlowCalibration', 'calibrate_flow_scale',
           'full_opening_area_m2', 'map_opening_m']

#: Integration window of the chamber mass balance [s]: several 50 Hz PWM periods, so that
#: the static map's period-mean opening stands for the spool's motion within each window.
FLOW_CALIBRATION_WINDOW_S = 0.25

#: Duty grid on which the map's opening is evaluated before interpolation.
_DUTY_GRID = np.linspace(0.0, 1.0, 401)


def full_opening_area_m2(params: ValveParameters) -> float:
    """C_d C_A x_max [m^2]: the flow area at full opening that ``flow_to_duty`` relies on.

    The product C_d C_A alone absorbs an identified stroke's error; this area compares
    parameter sets whatever their stroke.
    """
    return params.discharge_coefficient * params.orifice_area_gradient_m * params.stroke_m


def map_opening_m(duty_map: DutyMap, params: ValveParameters, duty: np.ndarray,
                  pwm_frequency_hz: float, supply_pressure_pa: float) -> np.ndarray:
    """The period-mean spool opening the map gives at each duty [m].

    Parameters
    ----------
    duty_map : DutyMap
        The static map (x_avg / x_max against duty).
    params : ValveParameters
        Its stroke x_max scales the map's fraction.
    duty : numpy.ndarray, shape (n,)
        Duty [1].
    pwm_frequency_hz, supply_pressure_pa : float
        Where the map is read [Hz], [Pa gauge] (pressures between the map's interpolated).

    Returns
    -------
    numpy.ndarray, shape (n,)
        The map on a 401-point duty grid, interpolated linearly at ``duty``.
    """
    x_grid = params.stroke_m * np.array([
        map_flow_position(duty_map, float(g), pwm_frequency_hz, supply_pressure_pa)
        for g in _DUTY_GRID])
    return np.interp(duty, _DUTY_GRID, x_grid)


@dataclass(frozen=True)
class FlowCalibration:
    """The flow scale C_d C_A, calibrated on a chamber's mass balance.

    Attributes
    ----------
    product_m, prior_product_m : float
        C_d C_A [m] calibrated, and of the set before.
    interval_m : tuple of float
        Its confidence interval [m].
    params : ValveParameters
        The set with the calibrated C_A (C_d kept).
    window_s : float
        Integration window [s].
    windows : int
        Windows of the fit.
    balance_error_before_pct, balance_error_after_pct : float
        RMS of the windowed mass balance with the prior and the calibrated product, in %
        of the largest windowed valve flow.
    cylinder : CylinderParameters
        The cylinder the balance assumed.
    """

    product_m: float
    prior_product_m: float
    interval_m: tuple[float, float]
    params: ValveParameters
    window_s: float
    windows: int
    balance_error_before_pct: float
    balance_error_after_pct: float
    cylinder: CylinderParameters = field(default_factory=CylinderParameters)

    @property
    def ratio(self) -> float:
        """Calibrated / prior product [1]."""
        return self.product_m / self.prior_product_m

    def to_json(self) -> dict:
        """``loop.json`` ``flow_calibration`` (without the files it was written to)."""
        cyl = self.cylinder
        return {'source': 'chamber mass balance of the before run (eq. C2), opening from the '
                          'identified map at the recorded duty commands',
                'product_m': self.product_m, 'prior_product_m': self.prior_product_m,
                'ratio': self.ratio, 'interval_m': list(self.interval_m),
                'discharge_coefficient': self.params.discharge_coefficient,
                'orifice_area_gradient_m': self.params.orifice_area_gradient_m,
                'full_opening_area_m2': full_opening_area_m2(self.params),
                'window_s': self.window_s, 'windows': self.windows,
                'balance_error_pct': {'before': self.balance_error_before_pct,
                                      'after': self.balance_error_after_pct},
                'cylinder': {'bore_diameter_m': cyl.bore_diameter_m,
                             'dead_volume_m3': cyl.dead_volume_m3,
                             'bleed_discharge_area_m2': cyl.bleed_discharge_area_m2,
                             'polytropic_exponent': cyl.polytropic_exponent}}


def calibrate_flow_scale(chamber: RunChamber, opening_m: np.ndarray, params: ValveParameters,
                         cylinder: CylinderParameters | None = None,
                         window_s: float = FLOW_CALIBRATION_WINDOW_S) -> FlowCalibration:
    """Fit C_d C_A so that the valve's flow at ``opening_m`` closes the chamber's balance.

    Parameters
    ----------
    chamber : RunChamber
        The run's chamber (:func:`run_chamber`).
    opening_m : numpy.ndarray, shape (n,)
        The opening the calibrated set stands for at each tick [m], e.g.
        :func:`map_opening_m` of the identified map at ``chamber.duty``.
    params : ValveParameters
        The set to calibrate (C_d kept, C_A scaled).
    cylinder : CylinderParameters, optional
        The suite's cylinder as the demo runs it (default: ``CylinderParameters()``): bore,
        dead volume, bleed and polytropic exponent of the balance (C1-C3).
    window_s : float
        Integration window [s].

    Returns
    -------
    FlowCalibration

    Raises
    ------
    FlowIdentificationError
        The valve never opens against a pressure difference, or too few windows.
    """
    cyl = CylinderParameters() if cylinder is None else cylinder
    res = identify_from_chamber(chamber.chamber_record(cyl, opening_m, from_zero=True), params,
                                polytropic_exponent=cyl.polytropic_exponent,
                                bleed_discharge_area_m2=cyl.bleed_discharge_area_m2,
                                window_s=window_s)
    est = res.estimate
    return FlowCalibration(product_m=est.product_m, prior_product_m=est.prior_product_m,
                           interval_m=tuple(est.interval_m), params=res.params,
                           window_s=res.window_s, windows=int(est.n_points),
                           balance_error_before_pct=res.error_before_pct,
                           balance_error_after_pct=res.error_after_pct, cylinder=cyl)
