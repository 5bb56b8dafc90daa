"""ROS-free valve model core (Taghizadeh et al. 2009): physics, electronics, integration.

Public API (see docs/architecture.md, "Model core API"):

- :class:`ValveParameters`, :func:`load_parameters`, :func:`default_parameters_path`,
  :data:`EFFECTS` (optional physical effects with neutral values and bounds)
- :class:`ElectronicsConfig` (boost, PI current chopper, negative-voltage capacitor)
- :class:`ValveStepper`, :class:`ValveSample` (streaming, real time);
  :class:`ValveBank` (N valves advanced together in one compiled call)
- :func:`simulate_step`, :func:`simulate_pwm`, :class:`SimulationResult`,
  :func:`step_metrics` (offline traces)
- :func:`simulate_step_batch`, :func:`simulate_pwm_batch` (parallel batches)
- :func:`simulate_trace_batch`, :class:`InputTrace`, :class:`TraceBatchResult`: the general
  entry point, many parameter sets under any input (a bare-coil voltage trace or main PWM
  commands through the electronics), sampled instantaneously or as interval means
- :func:`orifice_mass_flow` (eq. 12), :func:`orifice_mass_flow_scalar`
- the moving average of the suite, :func:`last_period_mean` (its definition: the mean over
  the last complete main PWM period); :class:`PeriodAverager` (streaming, same
  definition), :func:`period_averages`; :func:`moving_average` is a trailing window

Everything else (``kernel``, names starting with ``_``) is internal: code outside this
package uses only the names above (a test checks it).
"""
from .averaging import PeriodAverager, last_period_mean, moving_average, period_averages
from .bank import ValveBank
from .electronics import ElectronicsConfig
from .magnetics import inductance, magnetic_force
from .kernel import DEFAULT_H_FREE_S, DEFAULT_H_STOP_S
from .orifice import orifice_mass_flow, orifice_mass_flow_scalar
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
from .trace import (
    PARALLEL_MIN_BATCH, SAMPLING_MODES, InputTrace, TraceBatchResult, simulate_trace_batch,
)

__all__ = [
    'DEFAULT_H_FREE_S',
    'DEFAULT_H_STOP_S',
    'DEFAULT_SUPPLY_PRESSURE_PA',
    'EFFECTS',
    'EffectSpec',
    'ElectronicsConfig',
    'InputTrace',
    'PARALLEL_MIN_BATCH',
    'PARAMETER_FIELDS',
    'ParameterError',
    'PeriodAverager',
    'PwmBatchResult',
    'SAMPLING_MODES',
    'SimulationResult',
    'StepBatchResult',
    'StepMetrics',
    'TraceBatchResult',
    'ValveBank',
    'ValveParameters',
    'ValveSample',
    'ValveStepper',
    'closing_time',
    'default_parameters_path',
    'inductance',
    'last_period_mean',
    'load_parameters',
    'magnetic_force',
    'moving_average',
    'orifice_mass_flow',
    'orifice_mass_flow_scalar',
    'period_averages',
    'simulate_pwm',
    'simulate_pwm_batch',
    'simulate_step',
    'simulate_step_batch',
    'simulate_trace_batch',
    'step_metrics',
]
