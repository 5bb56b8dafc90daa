"""ROS-free valve model core (Taghizadeh et al. 2009): physics, electronics, integration.

Public API (see docs/architecture.md, "Model core API"):

- :class:`ValveParameters`, :func:`load_parameters`, :func:`default_parameters_path`,
  :data:`EFFECTS` (optional physical effects with neutral values and bounds)
- :class:`ElectronicsConfig`, :func:`load_electronics`: the drive electronics, a family of
  peak-and-hold drivers (peak end, hold, release), and their YAML description file
- :class:`ValveStepper`, :class:`ValveSample` (streaming, real time);
  :class:`ValveBank` (N valves advanced together in one compiled call)
- :func:`simulate_trace_batch`, :class:`InputTrace`: the one simulation entry, many
  parameter sets under any input (a bare-coil voltage trace, main PWM commands through
  the electronics, or the paper's voltage step), sampled instantaneously or as interval
  means, with the exact per-period position means on request; :func:`simulate_step`,
  :func:`simulate_pwm` are the paper's experiments as one run of it. Every simulation
  returns a :class:`SimulationResult`; :func:`step_metrics`, :func:`closing_time` read it
- :func:`orifice_mass_flow` (eq. 12), :func:`orifice_mass_flow_scalar`
- the moving average of the suite, :func:`last_period_mean` (its definition: the mean over
  the last complete main PWM period); :class:`PeriodAverager` (streaming, same
  definition), :func:`period_averages`; :func:`moving_average` is a trailing window

Everything else (``kernel``, names starting with ``_``) is internal: code outside this
package uses only the names above (a test checks it).

Every entry runs on the kernel compiled ahead of time when it is built, else on the numba
jit, with the same numbers; ``valve_model_pkg.model.aot.backend()`` tells which (the nodes
report it).
"""
from __future__ import annotations

import importlib

# The names are loaded on first use (PEP 562): a process imports only the submodules whose
# names it uses. Only kernel_jit.py imports numba, and only when the ahead-of-time kernel
# is missing (model/aot.py), so a process that simulates on that kernel never imports
# numba or llvmlite (~130 MB, most of a cold start).
_HOME = {
    'PeriodAverager': 'averaging', 'last_period_mean': 'averaging',
    'moving_average': 'averaging', 'period_averages': 'averaging',
    'ValveBank': 'bank',
    'ElectronicsConfig': 'electronics', 'load_electronics': 'electronics',
    'inductance': 'magnetics', 'magnetic_force': 'magnetics',
    'DEFAULT_H_FREE_S': 'kernel', 'DEFAULT_H_STOP_S': 'kernel', 'batch_threads': 'kernel',
    'orifice_mass_flow': 'orifice', 'orifice_mass_flow_scalar': 'orifice',
    'EFFECTS': 'parameters', 'PARAMETER_FIELDS': 'parameters', 'EffectSpec': 'parameters',
    'ParameterError': 'parameters', 'ValveParameters': 'parameters',
    'default_parameters_path': 'parameters', 'load_parameters': 'parameters',
    'DEFAULT_SUPPLY_PRESSURE_PA': 'simulation', 'PARALLEL_MIN_BATCH': 'simulation',
    'SAMPLING_MODES': 'simulation', 'simulate_pwm': 'simulation',
    'simulate_step': 'simulation', 'simulate_trace_batch': 'simulation',
    'SimulationResult': 'result', 'StepMetrics': 'result', 'closing_time': 'result',
    'step_metrics': 'result',
    'ValveSample': 'stepper', 'ValveStepper': 'stepper',
    'InputTrace': 'trace',
}
# the step defaults are plain numbers: served from kernel.py's source, without numba
_LAYOUT_NAMES = ('DEFAULT_H_FREE_S', 'DEFAULT_H_STOP_S')
_SUBMODULES = frozenset(_HOME.values()) | {'constants', 'electrical', 'mechanics', 'sample'}


def __getattr__(name: str):
    """Load a public name from its submodule on first use (then it is a plain global)."""
    home = _HOME.get(name)
    if home is None:
        if name in _SUBMODULES:  # ``model.kernel`` etc., as when __init__ imported them all
            return importlib.import_module(f'{__name__}.{name}')
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    if name in _LAYOUT_NAMES:
        from .aot import layout
        value = layout()[name]
    else:
        value = getattr(importlib.import_module(f'{__name__}.{home}'), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


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
    'SAMPLING_MODES',
    'SimulationResult',
    'StepMetrics',
    'ValveBank',
    'ValveParameters',
    'ValveSample',
    'ValveStepper',
    'batch_threads',
    'closing_time',
    'default_parameters_path',
    'inductance',
    'last_period_mean',
    'load_electronics',
    'load_parameters',
    'magnetic_force',
    'moving_average',
    'orifice_mass_flow',
    'orifice_mass_flow_scalar',
    'period_averages',
    'simulate_pwm',
    'simulate_step',
    'simulate_trace_batch',
    'step_metrics',
]
