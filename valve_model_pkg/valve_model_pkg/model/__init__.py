"""ROS-free valve model core (Taghizadeh et al. 2009): physics, electronics, integration.

Public API (see docs/architecture.md, "Model core API"):

- :class:`ValveParameters`, :func:`load_parameters`, :func:`default_parameters_path`,
  :data:`EFFECTS` (optional physical effects with neutral values and bounds)
- :class:`ElectronicsConfig` (boost, PI current chopper, negative-voltage capacitor)
- :class:`ValveStepper`, :class:`ValveSample` (streaming, real time)
- :func:`simulate_step`, :func:`simulate_pwm`, :class:`SimulationResult`,
  :func:`step_metrics` (offline traces)
- :func:`simulate_step_batch`, :func:`simulate_pwm_batch` (parallel batches)
- :func:`orifice_mass_flow` (eq. 12), :func:`moving_average`, :class:`PeriodAverager`
"""
from .averaging import PeriodAverager, moving_average, period_averages
from .electronics import ElectronicsConfig
from .magnetics import inductance, magnetic_force
from .orifice import orifice_mass_flow
from .parameters import (
    EFFECTS, PARAMETER_FIELDS, EffectSpec, ParameterError, ValveParameters,
    default_parameters_path, load_parameters,
)
from .simulation import (
    DEFAULT_SUPPLY_PRESSURE_PA, PwmBatchResult, SimulationResult, StepBatchResult,
    StepMetrics, closing_time, simulate_pwm, simulate_pwm_batch, simulate_step,
    simulate_step_batch, step_metrics,
)
from .stepper import ValveSample, ValveStepper

__all__ = [
    'DEFAULT_SUPPLY_PRESSURE_PA',
    'EFFECTS',
    'EffectSpec',
    'ElectronicsConfig',
    'PARAMETER_FIELDS',
    'ParameterError',
    'PeriodAverager',
    'PwmBatchResult',
    'SimulationResult',
    'StepBatchResult',
    'StepMetrics',
    'ValveParameters',
    'ValveSample',
    'ValveStepper',
    'closing_time',
    'default_parameters_path',
    'inductance',
    'load_parameters',
    'magnetic_force',
    'moving_average',
    'orifice_mass_flow',
    'period_averages',
    'simulate_pwm',
    'simulate_pwm_batch',
    'simulate_step',
    'simulate_step_batch',
    'step_metrics',
]
